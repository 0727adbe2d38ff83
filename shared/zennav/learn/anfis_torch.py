"""ANFIS in torch and its trainers (trainer side only; the edge runs anfis_numpy).

Hybrid learning (J.-S. R. Jang, IEEE Trans. SMC 23(3) 1993, sec. IV; seed 000): a forward pass with the
premises fixed solves the consequents by regularised least squares (lse.ridge_lstsq), a backward pass with
the consequents fixed moves the premises by Fletcher-Reeves CG (fr_cg, strong Wolfe line search, restarts;
the CG starts from steepest descent each epoch, its first trial step from the previous epoch's last step).
By default (cg_projected) every CG function evaluation is such a forward + backward pass, so the CG
minimises the loss with the consequents at their least-squares optimum (variable projection); with
cg_projected=False the LSE runs once per epoch and the CG sees fixed consequents (Jang's alternation).
For comparison: the same with plain gradient descent on the premises (Jang's fixed step length k:
dp = -k g / |g|), Adam on all parameters from zero consequents (D. P. Kingma, J. Ba, ICLR 2015, written
out here; torch.optim is not used), and PSO on the premises with least-squares consequents (seed 003): "pso"
with TrainConfig.pso (constant Clerc-Kennedy coefficients by default), "ipso" with seed 003's improved schedule
(zennav.learn.pso.IMPROVED: inertia 0.9 -> 0.4, c1 2.5 -> 0.5, c2 0.5 -> 2.5 over the epochs).
Epoch 0 of a training history is the initial model (consequents zero unless given).

torch serves as the tensor library and autograd supplies the premise gradients. The premises are held as
p = (log a, log b, c) so that a, b stay positive; the forward pass matches anfis_numpy.forward.
The loss is the mean squared error over samples and outputs in normalised units; with ridge r the
least-squares step minimises N*m*MSE + r*N*|theta|^2, so J = MSE + r |theta|^2 / m never increases in a
hybrid epoch.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from . import anfis_numpy
from .fr_cg import fr_cg
from .lse import ridge_lstsq
from .pso import IMPROVED, PSOConfig, Swarm
from .sigma import answer_lag, answer_sigma

METHODS = ("hybrid_cg", "hybrid_gd", "adam", "pso", "ipso")


def default_device() -> torch.device:
    """The first CUDA device when torch sees one, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


class TorchAnfis:
    """ANFIS with premise vector p = (log a, log b, c).ravel() and consequents theta (n_rules*(n_in+1), n_out).

    Built from the arrays of anfis_numpy (consequents optional: zeros with n_out outputs).
    """

    def __init__(self, arrays: dict, *, n_out: int | None = None, device=None, dtype=torch.float64):
        self.device, self.dtype = torch.device(device or "cpu"), dtype
        t = dict(device=self.device, dtype=dtype)
        a, b, c = (np.asarray(arrays[k], dtype=float) for k in ("a", "b", "c"))
        self.n_in, self.n_mf = a.shape
        self.rules = np.asarray(arrays["rules"], dtype=np.int64)
        self.n_rules = len(self.rules)
        self.p = torch.as_tensor(np.concatenate([np.log(a).ravel(), np.log(b).ravel(), c.ravel()]), **t)
        cons = arrays.get("consequents")
        if cons is None:
            cons = np.zeros((self.n_rules, self.n_in + 1, n_out))
        self.n_out = cons.shape[-1]
        self.theta = torch.as_tensor(np.asarray(cons, dtype=float).reshape(-1, self.n_out), **t)
        # one-hot selection: log w = log mu (N, n_in * n_mf) @ select_t, a gather whose backward is a matmul
        select = np.zeros((self.n_rules, self.n_in, self.n_mf))
        select[np.arange(self.n_rules)[:, None], np.arange(self.n_in), self.rules] = 1.0
        self._select_t = torch.as_tensor(select.reshape(self.n_rules, -1).T, **t)
        self._zero = torch.zeros((), **t)

    def premises(self, p: torch.Tensor):
        """(a, b, c), each (n_in, n_mf), from a premise vector."""
        k = self.n_in * self.n_mf
        shape = (self.n_in, self.n_mf)
        return p[:k].exp().reshape(shape), p[k:2 * k].exp().reshape(shape), p[2 * k:].reshape(shape)

    def firing(self, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """Layers 1-3: normalised firing strengths (N, n_rules), differentiable in p.

        log z2 is taken of z2 + 1e-300: no change where z2 > 1e-284, and at an MF centre (z2 = 0, where
        anfis_numpy takes log 0 = -inf) mu = 1 / (1 + 1e-300^b), 1 to 1e-30 for b >= 0.1, with a finite
        gradient.
        """
        a, b, c = self.premises(p)
        z2 = ((x[:, :, None] - c) / a) ** 2
        logmu = -torch.logaddexp(self._zero, b * torch.log(z2 + 1e-300))
        return torch.softmax(logmu.reshape(x.shape[0], -1) @ self._select_t, dim=1)

    def design(self, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """Layer-4 regressors (N, n_rules*(n_in+1)): the output is design(x, p) @ theta."""
        xe = torch.cat([x, torch.ones_like(x[:, :1])], dim=1)
        return (self.firing(x, p)[:, :, None] * xe[:, None, :]).reshape(x.shape[0], -1)

    def forward(self, x, p=None, theta=None) -> torch.Tensor:
        """Layers 1-5 in normalised units, (N, n_in) -> (N, n_out)."""
        p = self.p if p is None else p
        theta = self.theta if theta is None else theta
        return self.design(self.tensor(x), p) @ theta

    def tensor(self, v) -> torch.Tensor:
        return torch.as_tensor(v, dtype=self.dtype, device=self.device)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Arrays for anfis_numpy / paramset (float64 numpy on the CPU)."""
        a, b, c = (v.detach().cpu().numpy().astype(np.float64) for v in self.premises(self.p))
        cons = self.theta.detach().cpu().numpy().reshape(self.n_rules, self.n_in + 1, self.n_out)
        return dict(a=a, b=b, c=c, rules=self.rules.copy(), consequents=cons.astype(np.float64))


@dataclass(frozen=True)
class TrainConfig:
    """Trainer settings; the RMSE is in normalised output units. An epoch is one LSE + premise pass
    (hybrid), one pass over the data in mini-batches (adam) or one swarm iteration (pso)."""

    method: str = "hybrid_cg"
    max_epochs: int = 100
    goal_rmse: float = 0.0  # stop once the training RMSE is <= goal_rmse
    tol: float = 1e-4  # ... or once the best training RMSE improved by < tol (relative) for `patience` epochs
    patience: int = 3
    val_patience: int = 0  # with a validation set: stop once its RMSE has not improved for this many epochs and
    # keep the best epoch's model (early stopping; 0: off)
    ridge: float = 1e-8  # Tikhonov weight per sample in the least-squares step
    cg_iters: int = 20  # FR-CG iterations on the premises per hybrid epoch
    cg_projected: bool = True  # hybrid_cg: LSE consequents at every CG evaluation (variable projection) ...
    # ... or, False, consequents fixed from the epoch's LSE during the CG (Jang's alternation)
    cg_restart_every: int | None = None  # None: n = number of premise parameters
    cg_c2: float = 0.1
    gd_step: float = 0.05  # hybrid_gd: premise step length per gradient step
    gd_steps: int = 1
    adam_lr: float = 0.01
    adam_betas: tuple[float, float] = (0.9, 0.999)
    adam_eps: float = 1e-8
    batch_size: int = 256  # adam; 0 = full batch
    pso: PSOConfig = field(default_factory=PSOConfig)
    pso_log_span: float = math.log(4.0)  # PSO box: a and b within a factor 4 of their initial values ...
    pso_c_span: float = 1.0  # ... centres within +- pso_c_span (normalised input units)
    seed: int = 0


@dataclass
class TrainResult:
    history: list[dict]  # per epoch (0 = start): epoch, rmse, val_rmse (None without validation), wall_s
    stop_reason: str  # "goal", "tol", "val" (early stopping) or "max_epochs"
    best_epoch: int | None = None  # with val_patience: the epoch of the lowest validation RMSE, the model kept

    @property
    def epochs(self) -> int:
        return self.history[-1]["epoch"]

    @property
    def rmse(self) -> float:
        return self.history[-1]["rmse"]

    @property
    def wall_s(self) -> float:
        return self.history[-1]["wall_s"]


def _mse(model: TorchAnfis, x, y, p, theta) -> torch.Tensor:
    return ((model.design(x, p) @ theta - y) ** 2).mean()


def _lse(model: TorchAnfis, x, y, p, ridge: float) -> torch.Tensor:
    with torch.no_grad():
        return ridge_lstsq(model.design(x, p), y, ridge * x.shape[0])


def _premise_grad(model: TorchAnfis, x, y, p, theta):
    p = p.detach().requires_grad_(True)
    loss = _mse(model, x, y, p, theta)
    (g,) = torch.autograd.grad(loss, p)
    return loss.detach(), g


def _projected_grad(model: TorchAnfis, x, y, p, ridge: float):
    """J(p) = min over theta of MSE + ridge |theta|^2 / m, and dJ/dp: the consequents by LSE at p, then the
    premise gradient at those fixed consequents, which is the exact gradient of J(p) since dJ/dtheta = 0
    there (variable projection: G. H. Golub, V. Pereyra, SIAM J. Numer. Anal. 10 (1973) 413-432; L.
    Kaufman, BIT 15 (1975) 49-57). One design matrix serves the solve and the gradient."""
    p = p.detach().requires_grad_(True)
    A = model.design(x, p)
    theta = ridge_lstsq(A.detach(), y, ridge * x.shape[0])
    loss = ((A @ theta - y) ** 2).mean() + ridge * (theta**2).sum() / y.shape[1]
    (g,) = torch.autograd.grad(loss, p)
    return loss.detach(), g


def epoch_stepper(model: TorchAnfis, x: torch.Tensor, y: torch.Tensor, config: TrainConfig) -> Callable[[], None]:
    """The one-epoch step of config.method on tensors x (N, n_in), y (N, n_out) (normalised units).

    Each call of the returned function trains model in place by one epoch (see TrainConfig); train() runs
    it with its stopping rules, a benchmark can run it under a time budget. Set-up work is done here (PSO
    evaluates its initial swarm), and state carried between epochs (Adam's moments, the CG step size, the
    swarm) lives in the closure.
    """
    if config.method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, not {config.method!r}")
    return _EPOCHS[config.method](model, x, y, config)


def train(model: TorchAnfis, x, y, config: TrainConfig = TrainConfig(), x_val=None, y_val=None) -> TrainResult:
    """Fit model in place on normalised data x (N, n_in), y (N, n_out); optional validation set."""
    x, y = model.tensor(x), model.tensor(y).reshape(len(x), -1)
    val = None if x_val is None else (model.tensor(x_val), model.tensor(y_val).reshape(len(x_val), -1))
    epoch_fn = epoch_stepper(model, x, y, config)
    t0 = time.perf_counter()
    history: list[dict] = []

    def record(epoch: int):
        with torch.no_grad():
            rmse = math.sqrt(float(_mse(model, x, y, model.p, model.theta)))
            vr = None if val is None else math.sqrt(float(_mse(model, *val, model.p, model.theta)))
        history.append(dict(epoch=epoch, rmse=rmse, val_rmse=vr, wall_s=time.perf_counter() - t0))
        return rmse

    best, stale, stop = record(0), 0, "max_epochs"
    early = config.val_patience > 0 and val is not None
    best_epoch, kept = 0, (model.p.clone(), model.theta.clone()) if early else None
    for epoch in range(1, config.max_epochs + 1):
        epoch_fn()
        rmse = record(epoch)
        if early:
            if history[-1]["val_rmse"] < history[best_epoch]["val_rmse"]:
                best_epoch, kept = epoch, (model.p.clone(), model.theta.clone())
            elif epoch - best_epoch >= config.val_patience:
                stop = "val"
                break
        if rmse <= config.goal_rmse:
            stop = "goal"
            break
        stale = stale + 1 if rmse > best * (1.0 - config.tol) else 0
        best = min(best, rmse)
        if stale >= config.patience:
            stop = "tol"
            break
    if kept is None:
        return TrainResult(history, stop)
    model.p, model.theta = kept
    return TrainResult(history, stop, best_epoch)


def _hybrid_cg(model, x, y, cfg):
    decrease = None  # first-order decrease of the last CG step: the next epoch's first trial step

    def fun(p):
        if cfg.cg_projected:
            return _projected_grad(model, x, y, p, cfg.ridge)
        return _premise_grad(model, x, y, p, model.theta)

    def epoch():
        nonlocal decrease
        if not cfg.cg_projected:
            model.theta = _lse(model, x, y, model.p, cfg.ridge)
        res = fr_cg(fun, model.p, max_iter=cfg.cg_iters, gtol=0.0, restart_every=cfg.cg_restart_every,
                    c2=cfg.cg_c2, first_decrease=decrease)
        model.p, decrease = res.x.detach(), res.last_decrease
        if cfg.cg_projected:
            model.theta = _lse(model, x, y, model.p, cfg.ridge)
    return epoch


def _hybrid_gd(model, x, y, cfg):
    def epoch():
        model.theta = _lse(model, x, y, model.p, cfg.ridge)
        for _ in range(cfg.gd_steps):
            _, g = _premise_grad(model, x, y, model.p, model.theta)
            model.p = model.p - cfg.gd_step * g / g.norm().clamp_min(1e-300)
    return epoch


def _adam(model, x, y, cfg):
    b1, b2 = cfg.adam_betas
    m = [torch.zeros_like(w) for w in (model.p, model.theta)]  # first and second moment estimates
    v = [torch.zeros_like(w) for w in (model.p, model.theta)]
    gen = torch.Generator(device="cpu").manual_seed(cfg.seed)
    step = 0

    def epoch():
        nonlocal step
        n = x.shape[0]
        bs = n if cfg.batch_size <= 0 else cfg.batch_size
        order = torch.randperm(n, generator=gen).to(model.device)
        for i in range(0, n, bs):
            idx = order[i:i + bs]
            p, theta = (w.detach().requires_grad_(True) for w in (model.p, model.theta))
            grads = torch.autograd.grad(_mse(model, x[idx], y[idx], p, theta), (p, theta))
            step += 1
            new = []
            for j, (w, g) in enumerate(zip((p, theta), grads)):
                m[j] = b1 * m[j] + (1 - b1) * g
                v[j] = b2 * v[j] + (1 - b2) * g * g
                m_hat, v_hat = m[j] / (1 - b1**step), v[j] / (1 - b2**step)
                new.append(w.detach() - cfg.adam_lr * m_hat / (v_hat.sqrt() + cfg.adam_eps))
            model.p, model.theta = new
    return epoch


def _pso(model, x, y, cfg):
    k = model.n_in * model.n_mf
    span = np.concatenate([np.full(2 * k, cfg.pso_log_span), np.full(k, cfg.pso_c_span)])
    p0 = model.p.cpu().numpy()

    def cost(ps: np.ndarray) -> np.ndarray:
        out = []
        for p in model.tensor(ps):
            theta = _lse(model, x, y, p, cfg.ridge)
            out.append(float(_mse(model, x, y, p, theta)))
        return np.array(out)

    base = IMPROVED if cfg.method == "ipso" else cfg.pso
    pso_cfg = replace(base, n_particles=cfg.pso.n_particles, vmax_frac=cfg.pso.vmax_frac,
                      init_spread=cfg.pso.init_spread, max_iter=cfg.max_epochs)  # the schedules span the epochs
    swarm = Swarm(cost, p0 - span, p0 + span, pso_cfg, x0=p0, seed=cfg.seed)

    def epoch():
        swarm.step()
        model.p = model.tensor(swarm.best_x)
        model.theta = _lse(model, x, y, model.p, cfg.ridge)
    return epoch


_EPOCHS = dict(hybrid_cg=_hybrid_cg, hybrid_gd=_hybrid_gd, adam=_adam, pso=_pso, ipso=_pso)


@dataclass
class FitResult:
    arrays: dict[str, np.ndarray]  # anfis_numpy model arrays
    norm: dict[str, np.ndarray]
    train: TrainResult
    metrics: dict  # for the parameter set: rmse per output in physical units, epochs, wall time, method


def fit_anfis(x, y, *, n_rules: int | None = None, n_mf: int | None = None, config: TrainConfig = TrainConfig(),
              x_val=None, y_val=None, device=None, minmax=()) -> FitResult:
    """Normalise, build the rule base (k-means with n_rules rules, or a grid with n_mf MFs per input), train.

    x, y in physical units, (N, n_in) and (N,) or (N, n_out). Exactly one of n_rules / n_mf. minmax: input
    columns scaled to [0, 1] instead of z-scored (anfis_numpy.fit_normalization).
    """
    if (n_rules is None) == (n_mf is None):
        raise ValueError("give exactly one of n_rules (clusters) and n_mf (grid)")
    x, y = _as_xy(x, y)
    norm = anfis_numpy.fit_normalization(x, y, minmax=minmax)
    xn, yn = (x - norm["x_mean"]) / norm["x_std"], (y - norm["y_mean"]) / norm["y_std"]
    if n_rules is not None:
        rb = anfis_numpy.cluster_rulebase(xn, n_rules, seed=config.seed)
    else:
        assert n_mf is not None  # exactly one of the two (checked above)
        rb = anfis_numpy.grid_rulebase(xn, n_mf)
    model = TorchAnfis(rb, n_out=y.shape[1], device=device or default_device())
    val = (None, None)
    if x_val is not None:
        x_val, y_val = _as_xy(x_val, y_val)
        val = ((x_val - norm["x_mean"]) / norm["x_std"], (y_val - norm["y_mean"]) / norm["y_std"])
    result = train(model, xn, yn, config, *val)
    arrays = model.to_arrays()

    def rmse(xs, ys):
        return np.sqrt(np.mean((anfis_numpy.predict(arrays, norm, xs) - ys) ** 2, axis=0)).tolist()

    metrics = dict(method=config.method, epochs=result.epochs, wall_s=result.wall_s,
                   stop_reason=result.stop_reason, train_rmse=rmse(x, y))
    if x_val is not None:
        metrics["val_rmse"] = rmse(x_val, y_val)
    return FitResult(arrays, norm, result, metrics)


def fit_anfis_sigma(x, y, *, max_rules: int, config: TrainConfig = TrainConfig(), holdout: float = 0.25,
                    t_ns=None, answer_period_s: float = 0.0, device=None, minmax=()) -> FitResult:
    """fit_anfis with a k-means rule base on all of x, y (rows in time order, newest last) plus the 1-sigma of its
    answers. Rules: rule_count of all the rows (max_rules, fewer while samples are few), so that the fit does not
    interpolate its samples. Validation: a first fit on the oldest (1 - holdout) predicts the newest holdout.
    Epochs: with config.val_patience > 0 (and a method of EPOCH_SELECTABLE), the number select_epochs chooses on
    the oldest (1 - holdout) alone (the held-out rows stay unseen), for both fits (metrics["probe_epochs"]: the
    epochs that choice ran); else config.max_epochs. Per output, the model with the lower held-out RMS of two
    answers it: the ANFIS or the intercept-only model (the mean of the target; model selection by the validation
    error, Hastie, Tibshirani and Friedman, "The Elements of Statistical Learning", 2nd ed., 2009, sec. 7.2): an
    output whose ANFIS has no skill over its mean is answered by the mean (its consequents zero in normalised
    units), so that a model that does not know an output does not answer it with a prediction worse than the
    trivial one; metrics["skill"] (per output, 1: the ANFIS answers it). 1-sigma: metrics["sigma"] (per output,
    physical units) is zennav.learn.sigma.answer_sigma of the chosen model's held-out residuals (their RMS
    inflated for their correlation one answer apart: answer_period_s over the held-out rows' spacing in t_ns,
    sample times [ns]; no t_ns: the next row), at least the final model's training RMSE; metrics["holdout_rmse"]
    (the ANFIS's), ["baseline_rmse"] (the mean's) and ["holdout_rho"] keep the parts. minmax: as in fit_anfis."""
    x, y = _as_xy(x, y)
    n = int(round(len(x) * (1.0 - holdout)))
    if not 0 < n < len(x):
        raise ValueError(f"holdout {holdout} leaves no training or no held-out row of {len(x)}")
    n_rules = rule_count(len(x), x.shape[1], max_rules)
    probe_epochs = None
    if config.val_patience > 0 and config.method in EPOCH_SELECTABLE:
        epochs, probe_epochs = select_epochs(x[:n], y[:n], max_rules=max_rules, config=config, holdout=holdout,
                                             device=device, minmax=minmax)
        config = replace(config, max_epochs=epochs, val_patience=0)
    first = fit_anfis(x[:n], y[:n], n_rules=n_rules, config=config, device=device, minmax=minmax)
    residuals = anfis_numpy.predict(first.arrays, first.norm, x[n:]) - y[n:]
    baseline = y[:n].mean(axis=0) - y[n:]
    holdout_rmse, baseline_rmse = (np.sqrt(np.mean(r**2, axis=0)) for r in (residuals, baseline))
    skill = holdout_rmse < baseline_rmse
    lag = 1 if t_ns is None else answer_lag(np.asarray(t_ns)[n:], answer_period_s)
    sigma, rho = answer_sigma(np.where(skill, residuals, baseline), lag=lag)
    fit = fit_anfis(x, y, n_rules=n_rules, config=config, device=device, minmax=minmax)
    fit.arrays["consequents"][:, :, ~skill] = 0.0  # the mean of y (normalised y is zero-mean)
    train_rmse = np.sqrt(np.mean((anfis_numpy.predict(fit.arrays, fit.norm, x) - y) ** 2, axis=0))
    fit.metrics["train_rmse"] = train_rmse.tolist()
    fit.metrics["holdout_rmse"] = holdout_rmse.tolist()
    fit.metrics["baseline_rmse"] = baseline_rmse.tolist()
    fit.metrics["holdout_rho"] = rho.tolist()
    fit.metrics["skill"] = skill.astype(int).tolist()
    fit.metrics["sigma"] = np.maximum(sigma, train_rmse).tolist()
    if probe_epochs is not None:
        fit.metrics["probe_epochs"] = probe_epochs
    return fit


# the gradient trainers: each epoch moves the model down its training loss, so a validation RMSE that has not fallen
# for val_patience epochs marks overfitting; a swarm's best stands still for many iterations between jumps (on the
# ANSFL flights early stopping raised anfis-pso's 30 s median from 35.5 to 41.8 m), and the improved swarm's schedule
# spans max_epochs
EPOCH_SELECTABLE = ("hybrid_cg", "hybrid_gd", "adam")


def rule_count(n_rows: int, n_in: int, max_rules: int) -> int:
    """Rules of a fit on n_rows samples of n_in inputs: max_rules, fewer while samples are few (at most one
    consequent parameter per 4 samples per output, n_rules * (n_in + 1) <= n_rows / 4), at least one."""
    return max(1, min(max_rules, n_rows // (4 * (n_in + 1))))


def select_epochs(x, y, *, max_rules: int, config: TrainConfig, holdout: float, device=None,
                  minmax=()) -> tuple[int, int]:
    """The number of epochs to train on x, y (rows in time order) by early stopping: a fit on the oldest
    (1 - holdout), its rules by rule_count of those rows, validated on the newest holdout stops
    config.val_patience epochs after its lowest validation RMSE; that epoch (0: the initial model, which answers
    the target's mean) is the choice, and a fit on more of the same data then runs as many (L. Prechelt, "Early
    stopping - but when?", in "Neural Networks: Tricks of the Trade", 1998; I. Goodfellow, Y. Bengio, A.
    Courville, "Deep Learning", 2016, sec. 7.8, algorithm 7.2). Returns (chosen epochs, epochs the probe ran);
    (config.max_epochs, 0) where the split leaves no rows."""
    m = int(round(len(x) * (1.0 - holdout)))
    if not 0 < m < len(x):
        return config.max_epochs, 0
    probe = fit_anfis(x[:m], y[:m], n_rules=rule_count(m, x.shape[1], max_rules), config=config, x_val=x[m:],
                      y_val=y[m:], device=device, minmax=minmax)
    assert probe.train.best_epoch is not None  # val_patience > 0 with a validation set
    return probe.train.best_epoch, probe.train.epochs


def _as_xy(x, y) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    return x, np.asarray(y, dtype=float).reshape(len(x), -1)
