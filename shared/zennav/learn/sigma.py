"""The 1-sigma that the navigation filter gives a learned model's answers, from the model's out-of-sample residuals.

Answers come once per query interval (about a second) and a model's errors on neighbouring answers are alike
(a learned speed that is 2 m/s off stays off for a while), whereas the Kalman filter takes each answer as
independent. The RMS residual per output is therefore inflated by the AR(1) variance factor of the
autocorrelation rho of residuals one answer apart (the residuals come at the sample cadence, e.g. every GNSS fix,
and answers every `period_s`: the lag is that many residuals, see answer_lag): (1 + rho) / (1 - rho) is the
ratio of the variance of a mean of AR(1) errors to that of independent ones (effective sample size
n (1 - rho) / (1 + rho); e.g. Bartlett 1946, von Storch and Zwiers, "Statistical Analysis in Climate Research",
1999, sec. 17.1), so n correlated answers weigh about as much as their n_eff independent ones. rho is clipped to
[0, RHO_MAX].
"""
from __future__ import annotations

import numpy as np

from ..nav.aid.base import ar1_variance_factor

RHO_MAX = 0.95  # at most a factor sqrt(39) ~ 6.2 on the RMS


def answer_lag(t_ns, period_s: float) -> int:
    """Residuals one answer period apart: period_s over the median spacing of the residual times t_ns, at least 1."""
    dt = np.diff(np.asarray(t_ns, dtype=np.int64))
    dt = dt[dt > 0]
    return max(1, int(round(period_s * 1e9 / float(np.median(dt))))) if len(dt) else 1


def answer_sigma(residuals: np.ndarray, lag: int = 1, floor: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N, n_out) in time order (physical units) -> (sigma (n_out,), rho (n_out,)): the RMS inflated by
    sqrt((1 + rho) / (1 - rho)) and floored at `floor`, and the clipped autocorrelation at `lag` residuals."""
    if lag < 1:
        raise ValueError("lag must be >= 1")
    r = np.asarray(residuals, dtype=float)
    rms = np.sqrt(np.mean(r**2, axis=0))
    rho = np.zeros(r.shape[1])
    if len(r) >= lag + 2:
        c = r - r.mean(axis=0)
        den = np.sum(c**2, axis=0)
        ok = den > 0
        rho[ok] = np.sum(c[lag:] * c[:-lag], axis=0)[ok] / den[ok]
    rho = np.clip(rho, 0.0, RHO_MAX)
    return np.maximum(rms * np.sqrt(ar1_variance_factor(rho)), floor), rho
