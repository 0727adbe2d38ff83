"""The 1-sigma that the navigation filter gives a learned model's answers, from the model's out-of-sample residuals.

Answers come once per query interval (about a second) and a model's errors on neighbouring answers are alike
(a learned speed that is 2 m/s off stays off for a while), whereas the Kalman filter takes each answer as
independent. The RMS residual per output is therefore inflated by the AR(1) variance factor of its lag-1
autocorrelation rho: (1 + rho) / (1 - rho) is the ratio of the variance of a mean of AR(1) errors to that of
independent ones (effective sample size n (1 - rho) / (1 + rho); e.g. Bartlett 1946, von Storch and Zwiers,
"Statistical Analysis in Climate Research", 1999, sec. 17.1), so n correlated answers weigh about as much as
their n_eff independent ones. rho is clipped to [0, RHO_MAX].
"""
from __future__ import annotations

import numpy as np

RHO_MAX = 0.95  # at most a factor sqrt(39) ~ 6.2 on the RMS


def answer_sigma(residuals: np.ndarray, floor: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N, n_out) in time order (physical units) -> (sigma (n_out,), rho (n_out,)): the RMS inflated by
    sqrt((1 + rho) / (1 - rho)) and floored at `floor`, and the clipped lag-1 autocorrelation."""
    r = np.asarray(residuals, dtype=float)
    rms = np.sqrt(np.mean(r**2, axis=0))
    rho = np.zeros(r.shape[1])
    if len(r) >= 3:
        c = r - r.mean(axis=0)
        den = np.sum(c**2, axis=0)
        ok = den > 0
        rho[ok] = np.sum(c[1:] * c[:-1], axis=0)[ok] / den[ok]
    rho = np.clip(rho, 0.0, RHO_MAX)
    return np.maximum(rms * np.sqrt((1.0 + rho) / (1.0 - rho)), floor), rho
