"""Innovation-based adaptive measurement noise R (seed 001), one estimator per aiding source.

The seed's steps, in the standard literature forms (its formulas were lost):

- innovation nu(k) = z(k) - H x(k/k-1) (closed-loop filter: x(k/k-1) = 0, so nu = z), its second moment
  C(k) = nu nu' (the one-sample estimate of E[nu nu']);
- test (seed step 6, "C(k) against H P(k/k-1) H' + R(k-1), and k against the window m"): the normalised
  innovation d2 = nu' (H P H' + R(k-1))^-1 nu exceeds the chi-square quantile chi2(p, dim), i.e. C(k) is
  larger than the predicted innovation covariance (Mehra 1972, "Approaches to adaptive filtering", IEEE TAC
  17(5), innovation whiteness/consistency test), and at least m innovations are in the window;
- passed: windowed mean C_bar(k) = (1/m) sum_{j=k-m+1..k} C(j) (Mohamed & Schwarz 1999, "Adaptive Kalman
  filtering for INS/GPS", J. Geodesy 73, eq. 20, innovation-based adaptive estimation, IAE), the adaptive
  factor alpha = max(0, tr(C_bar - H P H' - R(k-1)) / tr(R(k-1))) (the trace ratio of the IAE estimate
  R_IAE = C_bar - H P H' to the current R, as the trace-based scale factors of Ding, Wang, Rizos &
  Kinlyside 2007, "Improving adaptive Kalman estimation in GPS/INS integration", J. Navigation 60(3)),
  and R(k) = (1 + alpha) R(k-1): a fast inflation that keeps the shape of R;
- otherwise: fading-memory weight beta(k) = (1 - b) / (1 - b^(k+1)) with forgetting factor b and the
  Sage-Husa estimate R(k) = (1 - beta(k)) R(k-1) + beta(k) (nu nu' - H P H') (Sage & Husa 1969, "Adaptive
  filtering with unknown prior statistics", JACC; the seed calls this branch Allan-variance based).

Everything is done in coordinates normalised by the reported R (R_rep = L L', nu~ = L^-1 nu, and the same
for H P H'): the estimator's state is the scale matrix R~ = L^-1 R L^-T, 1 (identity) when the receiver's
sigmas are right, so a change of the reported sigmas is honoured at once and the traces weigh each axis by
its reported variance. After every step R~ is symmetrised and its eigenvalues clipped into
[floor, ceiling]: R = L R~ L' stays symmetric positive definite and between floor * R_rep and
ceiling * R_rep. k counts the innovations seen, starting at ``prior_count``: the reported R counts as that
many earlier innovations, by default one fading-memory length 1/(1-b). The classic start k = 0 (beta(0) = 1,
the seed's example) replaces R by the first innovation alone; after a large initial position error that
inflates R and doubled the early position error in simulation.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from .eskf import chi2_quantile


class AdaptiveR:
    """Adaptive R of one aiding source of dimension dim (see the module docstring).

    window: m [innovations]; forgetting: b in (0, 1); test_probability: chi-square quantile of the inflation
    test; floor / ceiling: bounds of R relative to the reported R (variance ratios); prior_count: k at start
    (None: round(1 / (1 - forgetting))).
    """

    def __init__(self, dim: int, window: int = 5, forgetting: float = 0.95, test_probability: float = 0.99,
                 floor: float = 1.0, ceiling: float = 400.0, prior_count: int | None = None):
        if not (window >= 1 and 0.0 < forgetting < 1.0 and 0.0 < test_probability < 1.0 and 0.0 < floor <= 1.0
                <= ceiling):
            raise ValueError("adaptive R needs window >= 1, 0 < forgetting < 1, 0 < test_probability < 1 and "
                             "0 < floor <= 1 <= ceiling")
        self.dim = dim
        self.window = int(window)
        self.forgetting = float(forgetting)
        self.floor, self.ceiling = float(floor), float(ceiling)
        self.threshold = chi2_quantile(test_probability, dim)
        self.k = round(1.0 / (1.0 - forgetting)) if prior_count is None else int(prior_count)
        self.scale = np.eye(dim)  # R~ = L^-1 R L^-T
        self._C: deque[np.ndarray] = deque(maxlen=self.window)
        self.R = np.zeros((dim, dim))  # last R returned [unit^2 of the measurement]
        self.branch = ""  # "inflate" or "fading": the seed's branch taken last
        self.counts = {"inflate": 0, "fading": 0}

    def update(self, nu: np.ndarray, HPHt: np.ndarray, R_rep: np.ndarray) -> np.ndarray:
        """Fold the innovation nu (predicted minus observed) with its predicted part H P(k/k-1) H' and the reported
        R_rep into the estimate, and return R(k) to use in this update."""
        L = np.linalg.cholesky(R_rep)
        nu_n = np.linalg.solve(L, nu)
        M = np.linalg.solve(L, np.linalg.solve(L, HPHt).T)  # L^-1 HPH' L^-T (symmetric)
        C = np.outer(nu_n, nu_n)
        self._C.append(C)
        S_prev = M + self.scale
        d2 = float(nu_n @ np.linalg.solve(S_prev, nu_n))
        if len(self._C) >= self.window and d2 > self.threshold:
            C_bar = sum(self._C) / len(self._C)
            alpha = max(0.0, float(np.trace(C_bar - S_prev)) / float(np.trace(self.scale)))
            new = (1.0 + alpha) * self.scale
            self.branch = "inflate"
        else:
            b = self.forgetting
            beta = (1.0 - b) / (1.0 - b ** (self.k + 1))
            new = (1.0 - beta) * self.scale + beta * (C - M)
            self.branch = "fading"
        self.counts[self.branch] += 1
        self.k += 1
        w, V = np.linalg.eigh(0.5 * (new + new.T))
        self.scale = (V * np.clip(w, self.floor, self.ceiling)) @ V.T
        self.scale = 0.5 * (self.scale + self.scale.T)
        R = L @ self.scale @ L.T
        self.R = 0.5 * (R + R.T)
        return self.R

    def get_state(self) -> dict:
        """The estimator's evolving state (plain, msgpack-safe); the settings come from the constructor."""
        return {"k": int(self.k), "scale": self.scale.tolist(), "C": [c.tolist() for c in self._C],
                "R": self.R.tolist(), "branch": self.branch, "counts": dict(self.counts)}

    def set_state(self, st: dict) -> None:
        self.k, self.scale, self.R = int(st["k"]), np.array(st["scale"], dtype=float), np.array(st["R"], dtype=float)
        self._C = deque((np.array(c, dtype=float) for c in st["C"]), maxlen=self.window)
        self.branch, self.counts = st["branch"], {k: int(v) for k, v in st["counts"].items()}

    def status(self) -> dict:
        """Live estimate for nav/status: R [unit^2], its ratio to the reported R (diagonal of R~), k, last branch."""
        return {"R": self.R.tolist(), "scale_diag": np.diag(self.scale).tolist(), "k": self.k, "branch": self.branch,
                "inflate": self.counts["inflate"], "fading": self.counts["fading"]}
