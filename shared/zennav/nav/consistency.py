"""Filter consistency monitoring and the adaptive fading factor of one aiding source (issue 18, item 5).

Every gated update of a source hands its innovation nu (predicted minus observed, dimension m), its predicted part
H P H' and its R to the monitor before the update. The monitor keeps the last ``window`` of them and tests the
normalised innovation squared (NIS) of the window against its chi-square expectation (Bar-Shalom, Li &
Kirubarajan 2001, "Estimation with applications to tracking and navigation", sec. 5.4: the time-average NIS
test): with a consistent filter, n * mean(NIS) ~ chi2(n * m), so

    overconfident  <=>  sum of the window's NIS > chi2_quantile(test_probability, n * m).

An overconfident filter whose gate throws away good measurements must recover its consistency instead of
trapping. When the window is overconfident AND its innovations are small in absolute terms (every |nu| at most
``max_innovation``, in the source's unit) AND consistent with each other (the newest differs from the one before
by at most ``max_innovation``: no step, i.e. not a jump), the predicted covariance is scaled by the adaptive fading
factor, the covariance-matching estimate of Xia, Rao, Ying & Shen 1994 ("Adaptive fading Kalman filter with an
application", Automatica 30(8)):

    lambda = max(1, tr(C_bar - R) / tr(H P H')),   C_bar = the window's mean of nu nu',   P <- min(lambda,
    max_factor) * P,

i.e. a fading-memory filter (Sorenson & Sacks 1971, "Recursive fading memory filtering", Information Sciences 3)
whose forgetting is set by Mehra's innovation-based covariance matching (Mehra 1972, "Approaches to adaptive
filtering", IEEE TAC 17(5)): the filter's own predicted uncertainty is grown until its innovations are as large
as it predicts, so good measurements pass the gate and are fused. The process noise Q itself is not changed:
the factor acts on the covariance at the update, which is where Q's deficit has accumulated.

A genuine jump or a spoofed fix is still rejected: a 1 km jump exceeds max_innovation (and the source's jump test
rejects it before the update); a drag faster than max_innovation per fix interval makes every innovation too large
or a step; such windows never inflate, their measurements meet the normal gate. The limit: a drag slower than
max_innovation per update is, from innovations alone, indistinguishable from a slowly drifting INS.
"""
from __future__ import annotations

import functools
from collections import deque

import numpy as np

from .eskf import chi2_quantile, small_inverse


class ConsistencyMonitor:
    """NIS window and adaptive fading factor of one aiding source of dimension dim (see the module docstring).

    window: n [updates]; test_probability: chi-square quantile of the window's NIS test; max_innovation: largest
    |nu| [unit of the measurement] an inflating window may hold, and largest step between its last two; max_factor:
    largest lambda of one update."""

    def __init__(self, dim: int, window: int = 10, test_probability: float = 0.999, max_innovation: float = 1.0,
                 max_factor: float = 100.0):
        if not (window >= 2 and 0.0 < test_probability < 1.0 and max_innovation > 0.0 and max_factor >= 1.0):
            raise ValueError("consistency monitor needs window >= 2, 0 < test_probability < 1, max_innovation > 0 "
                             "and max_factor >= 1")
        self.dim = dim
        self.window = int(window)
        self.max_innovation = float(max_innovation)
        self.max_factor = float(max_factor)
        self.test_probability = float(test_probability)
        self._nu: deque[np.ndarray] = deque(maxlen=self.window)
        self._nis: deque[float] = deque(maxlen=self.window)
        self._C_minus_R: deque[np.ndarray] = deque(maxlen=self.window)
        self.last_factor = 1.0
        self.counts = {"updates": 0, "overconfident": 0, "inflated": 0, "held": 0}

    @functools.cached_property
    def threshold(self) -> float:
        """The chi-square quantile the window's NIS sum is tested against (at first use: scipy.special loads then,
        not when the engine is built)."""
        return chi2_quantile(self.test_probability, self.window * self.dim)

    def factor(self, nu: np.ndarray, HPHt: np.ndarray, R: np.ndarray) -> float:
        """Fold one innovation nu (predicted minus observed) with its predicted H P H' and R into the window and
        return the factor lambda >= 1 to scale P by before this update (1: leave P alone)."""
        nu = np.array(nu, dtype=float)
        self._nu.append(nu)
        self._nis.append(float(nu @ (small_inverse(HPHt + R) @ nu)))
        self._C_minus_R.append(nu[:, None] * nu - R)
        self.counts["updates"] += 1
        self.last_factor = 1.0
        if len(self._nis) < self.window or sum(self._nis) <= self.threshold:
            return 1.0
        self.counts["overconfident"] += 1
        norms = [float(np.linalg.norm(v)) for v in self._nu]
        step = float(np.linalg.norm(self._nu[-1] - self._nu[-2]))
        if max(norms) > self.max_innovation or step > self.max_innovation:
            self.counts["held"] += 1  # too large or a step: a jump or a drag, left to the gate
            return 1.0
        C_bar_minus_R = sum(self._C_minus_R) / len(self._C_minus_R)
        lam = float(np.trace(C_bar_minus_R)) / max(float(np.trace(HPHt)), 1e-300)
        self.last_factor = min(max(lam, 1.0), self.max_factor)
        if self.last_factor > 1.0:
            self.counts["inflated"] += 1
        return self.last_factor

    def nis_mean(self) -> float | None:
        """Mean NIS of the window divided by its expectation dim (1: consistent), None before the first update."""
        return float(np.mean(self._nis)) / self.dim if self._nis else None

    def status(self) -> dict:
        """Live figures for nav/status: counts, the window's NIS ratio and the last factor."""
        return {**self.counts, "nis_ratio": self.nis_mean(), "last_factor": self.last_factor}

    def get_state(self) -> dict:
        return {"nu": [v.tolist() for v in self._nu], "nis": list(self._nis),
                "C_minus_R": [c.tolist() for c in self._C_minus_R], "last_factor": self.last_factor,
                "counts": dict(self.counts)}

    def set_state(self, st: dict) -> None:
        self._nu = deque((np.array(v, dtype=float) for v in st["nu"]), maxlen=self.window)
        self._nis = deque((float(x) for x in st["nis"]), maxlen=self.window)
        self._C_minus_R = deque((np.array(c, dtype=float) for c in st["C_minus_R"]), maxlen=self.window)
        self.last_factor = float(st["last_factor"])
        self.counts = {k: int(v) for k, v in st["counts"].items()}
