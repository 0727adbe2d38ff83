"""First-order Takagi-Sugeno ANFIS in numpy: the edge predictor's forward pass and the rule-base builders.

J.-S. R. Jang, "ANFIS: adaptive-network-based fuzzy inference system", IEEE Trans. SMC 23(3), 1993; the
five layers of seed 000:
  1 fuzzification   mu_jm(x_j) = 1 / (1 + |(x_j - c_jm) / a_jm|^(2 b_jm))   (generalised bell)
  2 rule firing     w_r = prod_j mu_{j, rules[r, j]}(x_j)                      (product T-norm)
  3 normalisation   wbar_r = w_r / sum_s w_s
  4 consequent      wbar_r * f_r(x),  f_r(x) = x . P_r + q_r                   (first order, per output)
  5 sum             y = sum_r wbar_r f_r(x)
Layers 2-3 are evaluated in the log domain (sum of log-memberships, then a shifted softmax): the same
numbers where the product is representable, and no 0/0 when ten small memberships underflow; far from
every rule the output follows the rule that fires most instead of turning NaN.

Model arrays (float64, `rules` int64), in normalised input/output units:
  a, b, c       (n_in, n_mf)             bell width (> 0), slope (> 0), centre of MF m of input j
  rules         (n_rules, n_in)          index of the MF that input j uses in rule r
  consequents   (n_rules, n_in + 1, n_out)  rows 0..n_in-1 P_r, last row q_r
Normalisation (`norm`): x_mean, x_std, x_min, x_max (n_in,), y_mean, y_std (n_out,); x_n = (x - x_mean) / x_std,
y = y_n * y_std + y_mean. By default z-scores; a min-max column (fit_normalization's minmax, seed 003 step 3.1)
has x_mean = its minimum and x_std = its range, so x_n falls in [0, 1] over the training samples.
x_min, x_max: the training inputs' range, the model's domain: a first-order TS model
extrapolates linearly (and without bound) outside it, so predictors refuse inputs beyond it (`domain_excess`).

Rule bases: `grid_rulebase` (every combination of n_mf MFs per input: n_mf ** n_in rules, for a few
inputs) and `cluster_rulebase` (k-means, one rule per cluster with its own MF on every input: the rule
count is the configured number of clusters whatever n_in is; as in scatter partitioning, Jang, Sun,
Mizutani, "Neuro-Fuzzy and Soft Computing", 1997, sec. 12.5, and Chiu 1994, with k-means++ seeding,
Arthur and Vassilvitskii 2007, in place of subtractive clustering).
"""
from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

ARRAY_NAMES = ("a", "b", "c", "rules", "consequents")
NORM_NAMES = ("x_mean", "x_std", "x_min", "x_max", "y_mean", "y_std")


def log_bell(x: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """log mu of every MF: x (N, n_in), a/b/c (n_in, n_mf) -> (N, n_in, n_mf)."""
    z2 = ((x[:, :, None] - c) / a) ** 2
    with np.errstate(divide="ignore"):
        return -np.logaddexp(0.0, b * np.log(z2))  # log(0) = -inf gives log mu = 0 at the centre


def normalized_firing(x: np.ndarray, a, b, c, rules) -> np.ndarray:
    """Layers 1-3: normalised firing strengths wbar (N, n_rules)."""
    logmu = log_bell(x, a, b, c)
    logw = logmu[:, np.arange(x.shape[1])[None, :], rules].sum(axis=-1)  # (N, n_rules)
    w = np.exp(logw - logw.max(axis=1, keepdims=True))
    return w / w.sum(axis=1, keepdims=True)


def design_matrix(x: np.ndarray, wbar: np.ndarray) -> np.ndarray:
    """Regressors of layer 4: (N, n_rules * (n_in + 1)), linear in the flattened consequents."""
    xe = np.concatenate([x, np.ones((x.shape[0], 1))], axis=1)
    return (wbar[:, :, None] * xe[:, None, :]).reshape(x.shape[0], -1)


def forward(arrays: Mapping[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """Layers 1-5 in normalised units: x (N, n_in) -> (N, n_out)."""
    wbar = normalized_firing(x, arrays["a"], arrays["b"], arrays["c"], arrays["rules"])
    cons = arrays["consequents"]
    return design_matrix(x, wbar) @ cons.reshape(-1, cons.shape[-1])


def predict(arrays: Mapping[str, np.ndarray], norm: Mapping[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """Output in physical units for raw inputs x (n_in,) or (N, n_in); keeps the leading shape."""
    x = np.asarray(x, dtype=float)
    x2 = np.atleast_2d(x)
    y = forward(arrays, (x2 - norm["x_mean"]) / norm["x_std"]) * norm["y_std"] + norm["y_mean"]
    return y[0] if x.ndim == 1 else y


def fit_normalization(x: np.ndarray, y: np.ndarray, min_std: float = 1e-12, minmax=()) -> dict[str, np.ndarray]:
    """Per-column mean, standard deviation (floored at min_std) and range of the inputs; mean and standard
    deviation of the targets. The input columns listed in minmax are min-max scaled instead: x_mean = minimum,
    x_std = range (floored at min_std)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    y = y[:, None] if y.ndim == 1 else y
    x_mean, x_std = x.mean(axis=0), np.maximum(x.std(axis=0), min_std)
    x_min, x_max = x.min(axis=0), x.max(axis=0)
    cols = list(minmax)
    x_mean[cols], x_std[cols] = x_min[cols], np.maximum(x_max[cols] - x_min[cols], min_std)
    return dict(x_mean=x_mean, x_std=x_std, x_min=x_min, x_max=x_max, y_mean=y.mean(axis=0),
                y_std=np.maximum(y.std(axis=0), min_std))


def domain_excess(norm: Mapping[str, np.ndarray], x: np.ndarray) -> float:
    """How far x (n_in,) lies outside the training range [x_min, x_max], in units of x_std (training standard
    deviations; ranges for min-max columns) of the input that is farthest out (0.0 inside the range)."""
    x = np.asarray(x, dtype=float)
    out = np.maximum(norm["x_min"] - x, x - norm["x_max"])
    return float(max(0.0, np.max(out / norm["x_std"])))


def grid_rulebase(x: np.ndarray, n_mf: int, *, slope: float = 2.0, max_rules: int = 256) -> dict:
    """Grid partition (Jang 1993): n_mf evenly spaced bells per input over its range, all combinations.

    Neighbouring bells cross at membership 1/2. Raises ValueError when n_mf ** n_in > max_rules; use
    cluster_rulebase then.
    """
    n_in = x.shape[1]
    if n_mf < 2:
        raise ValueError("grid partition needs n_mf >= 2")
    if n_mf**n_in > max_rules:
        raise ValueError(f"grid partition gives {n_mf}**{n_in} rules > max_rules={max_rules}; "
                         "use cluster_rulebase")
    lo, hi = x.min(axis=0), x.max(axis=0)
    span = np.maximum(hi - lo, 1e-6)
    c = lo[:, None] + span[:, None] * np.linspace(0.0, 1.0, n_mf)[None, :]
    a = np.repeat((span / (2.0 * (n_mf - 1)))[:, None], n_mf, axis=1)
    rules = np.array(list(itertools.product(range(n_mf), repeat=n_in)), dtype=np.int64)
    return dict(a=a, b=np.full_like(a, slope), c=c, rules=rules)


def kmeans(x: np.ndarray, k: int, *, seed: int = 0, iters: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means with k-means++ seeding -> (centres (k, n), labels (N,)). Deterministic for a seed."""
    n = x.shape[0]
    if not 1 <= k <= n:
        raise ValueError(f"need 1 <= k <= N, got k={k}, N={n}")
    rng = np.random.default_rng(seed)
    picked = [x[rng.integers(n)]]  # k-means++ seeding
    d2 = ((x - picked[0]) ** 2).sum(axis=1)
    for _ in range(1, k):
        total = d2.sum()
        i = rng.choice(n, p=d2 / total) if total > 0 else rng.integers(n)
        picked.append(x[i])
        d2 = np.minimum(d2, ((x - x[i]) ** 2).sum(axis=1))
    centres = np.array(picked)
    labels = np.full(n, -1)
    for _ in range(iters):
        dist = (x**2).sum(1)[:, None] - 2.0 * x @ centres.T + (centres**2).sum(1)[None, :]
        new = dist.argmin(axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
        for j in range(k):
            members = x[labels == j]
            if len(members):
                centres[j] = members.mean(axis=0)
    return centres, labels


def cluster_rulebase(
    x: np.ndarray, n_rules: int, *, seed: int = 0, width: float = 1.5, min_width: float = 0.1,
    slope: float = 2.0,
) -> dict:
    """Scatter partition: one rule per k-means cluster, each with its own bell on every input.

    Centre = cluster mean; width a = width * the cluster's standard deviation along that input (floored at
    min_width, in the units of x), so the bell is 1/2 at `width` standard deviations. Rule count = n_rules.
    """
    centres, labels = kmeans(x, n_rules, seed=seed)
    spread = np.array([x[labels == r].std(axis=0) if np.any(labels == r) else np.zeros(x.shape[1])
                       for r in range(n_rules)])
    a = np.maximum(width * spread, min_width).T  # (n_in, n_rules)
    rules = np.repeat(np.arange(n_rules, dtype=np.int64)[:, None], x.shape[1], axis=1)
    return dict(a=a, b=np.full_like(a, slope), c=centres.T.copy(), rules=rules)
