"""Variational-Bayes adaptive measurement noise (seed 003 step 2.3): an unknown, time-varying diagonal R estimated
jointly with the state in the engine's one update, one estimator per aiding source.

We follow Särkkä & Nummenmaa, "Recursive noise adaptive Kalman filtering by variational Bayesian approximations",
IEEE TAC 54(3), 2009 (VB-AKF): each measurement channel i has its variance R_i with an inverse-Gamma posterior
IG(alpha_i, beta_i), the state a Gaussian, p(x, R | z) ~ q(x) q(R) by minimising the Kullback-Leibler divergence.
The diagonal form (rather than the inverse-Wishart of Huang, Zhang, Wu & Chambers, IEEE TAC 63(2), 2018) is chosen
because a DVL's valid beams change from one sample to the next: each beam keeps its own (alpha_i, beta_i), and a
sample updates those of the beams it has. Per update (the paper's algorithm 1, eqs. 18-25):

    predict   alpha_i^- = rho alpha_i,  beta_i^- = rho beta_i            (rho in (0, 1]: forgetting factor)
    update    alpha_i = alpha_i^- + 1/2,  beta_i^(0) = beta_i^-
    iterate   R^(j) = diag(beta^(j) / alpha)
              S = H P^- H' + R^(j),  x^(j) = P^- H' S^-1 nu,  P^(j) = P^- - P^- H' S^-1 H P^-
              beta_i^(j+1) = beta_i^- + 1/2 (nu - H x^(j))_i^2 + 1/2 (H P^(j) H')_ii
    for j = 0 .. iterations - 1; R = diag(beta / alpha) is then the R of the engine's (Joseph, gated) update.

Everything is done in measurement space: with the closed-loop filter's prior x^- = 0, H x^(j) = M S^-1 nu and
H P^(j) H' = M - M S^-1 M with M = H P^- H'. And in coordinates normalised by the source's nominal R (R_nom = L L',
nu~ = L^-1 nu, M~ = L^-1 M L^-T): the estimate is the ratio R~ = diag(beta / alpha) to the nominal R, 1 when the
nominal sigmas are right, clipped into [floor, ceiling], R = L R~ L'. The prior of a channel not seen before is the
nominal R with the weight of one forgetting length: alpha = beta = 1 / (2 (1 - rho)), the fixed point of the
alpha recursion.

Per update the estimator keeps what the learned DVL compensation (seed step 2.1) takes as features: the innovation
nu (predicted minus observed), the Mahalanobis distance lambda = nu' (H P^- H' + R)^-1 nu and diag(R) (``last``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class VbResult:
    """One VB update: channels (the key of each row), innovation nu [unit], lambda = nu' S^-1 nu [-] with
    S = H P H' + R, R (dim x dim) [unit^2] and the posterior (alpha, beta) per channel (normalised units)."""

    channels: tuple
    innovation: np.ndarray
    mahalanobis: float
    R: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray

    @property
    def R_diag(self) -> np.ndarray:
        return np.diag(self.R).copy()


class VariationalR:
    """VB-AKF measurement noise of one source (module docstring): forgetting rho, iterations, bounds floor /
    ceiling of R as a variance ratio to the nominal R."""

    def __init__(self, forgetting: float = 0.97, iterations: int = 3, floor: float = 0.1, ceiling: float = 1e4):
        if not (0.0 < forgetting < 1.0 and iterations >= 1 and 0.0 < floor <= 1.0 <= ceiling):
            raise ValueError("VB R needs 0 < forgetting < 1, iterations >= 1 and 0 < floor <= 1 <= ceiling")
        self.forgetting = float(forgetting)
        self.iterations = int(iterations)
        self.floor, self.ceiling = float(floor), float(ceiling)
        self.prior = 0.5 / (1.0 - self.forgetting)
        self.params: dict[str, list[float]] = {}  # channel -> [alpha, beta] (normalised units)
        self.last: VbResult | None = None
        self.count = 0

    def solve(self, nu: np.ndarray, HPHt: np.ndarray, R_nom: np.ndarray, channels=None) -> VbResult:
        """The VB estimate for innovation nu (dim,), H P^- H' and the nominal R (dim x dim), channels the keys of the
        rows (None: 0..dim-1); does not change the estimator (``commit`` does)."""
        nu = np.asarray(nu, dtype=float)
        dim = len(nu)
        keys = tuple(range(dim)) if channels is None else tuple(channels)
        L = np.linalg.cholesky(R_nom)
        nu_n = np.linalg.solve(L, nu)
        M = np.linalg.solve(L, np.linalg.solve(L, HPHt).T)
        M = 0.5 * (M + M.T)
        rho = self.forgetting
        ab = np.array([self.params.get(str(k), [self.prior, self.prior]) for k in keys], dtype=float)
        alpha = rho * ab[:, 0] + 0.5
        beta_prior = rho * ab[:, 1]
        beta = beta_prior.copy()
        for _ in range(self.iterations):
            S = M + np.diag(self._ratio(beta, alpha))
            resid = nu_n - M @ np.linalg.solve(S, nu_n)
            HPpHt = M - M @ np.linalg.solve(S, M)
            beta = beta_prior + 0.5 * resid**2 + 0.5 * np.diag(HPpHt)
        R = L @ np.diag(self._ratio(beta, alpha)) @ L.T
        R = 0.5 * (R + R.T)
        S = HPHt + R
        lam = float(nu @ np.linalg.solve(0.5 * (S + S.T), nu))
        return VbResult(keys, nu.copy(), lam, R, alpha, beta)

    def commit(self, res: VbResult) -> None:
        """Keep a solve's posterior as the estimator's state."""
        for k, a, b in zip(res.channels, res.alpha.tolist(), res.beta.tolist()):
            self.params[str(k)] = [a, b]
        self.last = res
        self.count += 1

    def update(self, nu: np.ndarray, HPHt: np.ndarray, R_nom: np.ndarray, channels=None) -> np.ndarray:
        """Solve and commit; returns R for this update [unit^2] (the engine's call, Navigator.update)."""
        res = self.solve(nu, HPHt, R_nom, channels)
        self.commit(res)
        return res.R

    def ratio(self, channel) -> float:
        """The current estimate of a channel's R as a ratio to its nominal R (1 for a channel not seen yet)."""
        a, b = self.params.get(str(channel), [self.prior, self.prior])
        return float(np.clip(b / a, self.floor, self.ceiling))

    def _ratio(self, beta: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        return np.clip(beta / alpha, self.floor, self.ceiling)

    def get_state(self) -> dict:
        """The evolving state (plain, msgpack-safe); the settings come from the constructor."""
        last = self.last
        return {"params": {k: list(v) for k, v in self.params.items()}, "count": self.count,
                "last": None if last is None else {
                    "channels": [str(c) for c in last.channels], "innovation": last.innovation.tolist(),
                    "mahalanobis": last.mahalanobis, "R": last.R.tolist(), "alpha": last.alpha.tolist(),
                    "beta": last.beta.tolist()}}

    def set_state(self, st: dict) -> None:
        self.params = {str(k): [float(x) for x in v] for k, v in st["params"].items()}
        self.count = int(st["count"])
        last = st["last"]
        self.last = None if last is None else VbResult(
            tuple(last["channels"]), np.array(last["innovation"], dtype=float), float(last["mahalanobis"]),
            np.array(last["R"], dtype=float), np.array(last["alpha"], dtype=float), np.array(last["beta"], dtype=float))

    def status(self) -> dict:
        """Live estimate for nav/status: R of the last update [unit^2], its channels, lambda, the update count and
        the ratio beta/alpha to the nominal R per channel seen."""
        last = self.last
        return {"R": [] if last is None else last.R.tolist(),
                "channels": [] if last is None else [str(c) for c in last.channels],
                "mahalanobis": None if last is None else last.mahalanobis, "vb_updates": self.count,
                "scale": {k: b / a for k, (a, b) in self.params.items()}}


def variational_r(config, on: bool) -> VariationalR | None:
    """The configured VB estimator of a source (NavConfig vb_*), None when off."""
    if not on:
        return None
    return VariationalR(config.vb_forgetting, config.vb_iterations, config.vb_floor, config.vb_ceiling)
