"""What every aiding source shares with the engine: the measurement it hands over for the engine's one update,
the status record of each attempt (AidReport) and the AidSource base class with its registry by name.

A source owns its input checks, its control (when to fuse, start, stop, reset) and its measurement model; the
engine (zennav.nav.navigator) owns mechanization, covariance propagation, the one update (Joseph form,
chi-square gate, adaptive R where the source has an estimator) and the feedback. A new source (non-holonomic
constraint, zero velocity, odometer, DVL, depth) is a new subclass added to zennav.nav.aid.build_sources; the
engine keeps its sources by name, routes each input to the sources whose ``inputs`` name its kind and calls
``on_step`` after every IMU sample where a source defines it. A source that measures at the engine's current
time calls ``nav.propagate_covariance()`` before it builds its measurement, and hands it to ``nav.update``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..adaptive_r import AdaptiveR
from ..consistency import ConsistencyMonitor
from ..vbkf import VariationalR


def ar1_variance_factor(rho):
    """(1 + rho) / (1 - rho) for a lag-one correlation rho in [0, 1) (array or float): the factor on the variance of
    one of a stream of AR(1) errors that makes the filter, which takes them as independent, weigh n of them as it
    should (the variance of their mean is that factor over n times theirs: effective sample size n (1 - rho) /
    (1 + rho); Bartlett 1946, von Storch and Zwiers, "Statistical Analysis in Climate Research", 1999, sec. 17.1)."""
    return (1.0 + rho) / (1.0 - rho)


def correlated_variance(std: float, every_s: float, corr_s: float) -> float:
    """The variance [unit^2] to fuse, every every_s [s], one sample of an error of 1-sigma std [unit] that is a
    first-order Gauss-Markov process of correlation time corr_s [s] (0: white): std^2 ar1_variance_factor(rho),
    rho = exp(-every_s / corr_s)."""
    if corr_s <= 0.0:
        return std * std
    return std * std * ar1_variance_factor(math.exp(-every_s / corr_s))


@dataclass
class AidReport:
    """One aiding attempt of a source: observation, innovation (predicted minus observed), its variance (diagonal
    of S), test ratio d2/threshold (> 1 fails the gate), fused or not, and the reason when not: a rejection
    (gnss_*, learned_*), or during coarse alignment how the fix was used instead (align_coarse: tracked;
    align_in_motion / align_gyrocompass: the fix that started the filter). last_fused_t_ns: the source's last
    fused measurement time [ns] after this attempt (-1: never); faults: flags of this attempt ("jump",
    "gate_trapped", "gate", "stale", "late", an input check's name)."""

    source: str
    t_ns: int
    observation: list
    innovation: list
    innovation_var: list
    test_ratio: float
    fused: bool
    reason: str = ""
    last_fused_t_ns: int = -1
    faults: list = field(default_factory=list)


@dataclass
class Measurement:
    """One measurement for the engine's update: z = predicted minus observed, z = H dx + v, v ~ N(0, R).

    observation: what the source observed (for the report); gated: apply the chi-square gate (and the source's
    adaptive R); gain_states: the states that may take gain (None: all; else a Schmidt update); channels: a key per
    row of z for a per-channel noise estimator (the source's vb; None: the rows 0..dim-1)."""

    t_ns: int
    observation: np.ndarray
    z: np.ndarray
    H: np.ndarray
    R: np.ndarray
    gated: bool = True
    gain_states: slice | None = None
    faults: tuple = ()
    channels: tuple | None = None


class AidSource:
    """Base of the aiding sources. name: the source name in reports, counters and the key nav/aid/<name>;
    inputs: the input kinds the engine routes to ``on_input``; adaptive: the adaptive-R estimator or None; vb: the
    variational-Bayes R estimator (zennav.nav.vbkf) or None; consistency: the consistency monitor
    (zennav.nav.consistency) or None; R_used: R of the last update [unit^2];
    last_fused_t_ns: time of the last fused measurement (-1: never)."""

    inputs: tuple[str, ...] = ()

    def __init__(self, name: str, adaptive: AdaptiveR | None = None, consistency: ConsistencyMonitor | None = None,
                 vb: VariationalR | None = None):
        self.name = name
        self.adaptive = adaptive
        self.vb = vb
        self.consistency = consistency
        self.R_used: np.ndarray | None = None
        self.last_fused_t_ns = -1

    def attach(self, nav) -> None:
        """Called by Navigator.add_source before the first IMU sample: where a source adds its own error states
        (nav.add_states)."""

    def admit(self, nav, data) -> bool:
        """Input checks as the data arrives (before it is queued to its time); False: rejected (counted, reported)."""
        return True

    def on_input(self, nav, data) -> bool:
        """Fuse one input (its kind in ``inputs``) into the engine ``nav``; returns whether a measurement was fused."""
        raise NotImplementedError

    def on_refusal(self, nav, query, reason: str) -> None:
        """The compensator refused a query this source answers (Navigator.on_refusal); by default nothing waits."""

    def on_step(self, nav) -> None:
        """After every IMU sample (e.g. a timeout); the engine calls it only where a subclass defines it."""

    def next_step_ns(self, nav) -> int | None:
        """The first IMU time [ns] at which on_step may act (None: at any sample); the engine's block loop
        (Navigator.run_imu) runs the samples before it without calling on_step."""
        return None

    def report(self, nav, t_ns: int, observation, innovation, innovation_var, test_ratio: float, fused: bool,
               reason: str = "", faults=()) -> None:
        """Append this source's status record of one attempt to the engine's reports."""
        nav.add_report(AidReport(self.name, int(t_ns), list(observation), list(innovation), list(innovation_var),
                                 test_ratio, fused, reason, int(self.last_fused_t_ns), list(faults)))

    def reject(self, nav, t_ns: int, reason: str, detail: str, observation, innovation=(), innovation_var=(),
               test_ratio: float = float("nan"), faults=()) -> None:
        """Count a rejection under reason and report it."""
        nav.count_rejection(reason, t_ns, detail)
        self.report(nav, t_ns, observation, innovation, innovation_var, test_ratio, False, reason, faults)

    def status(self) -> dict:
        """The live measurement noise for nav/status: the adaptive estimate, else the R of the last update."""
        if self.adaptive is not None:
            return self.adaptive.status()
        if self.vb is not None:
            return self.vb.status()
        assert self.R_used is not None  # asked only once an update has set it (Navigator.status)
        return {"R": self.R_used.tolist()}

    def get_state(self) -> dict:
        """Everything of this source that determines the engine's future output (plain, msgpack-safe)."""
        return {"R_used": None if self.R_used is None else self.R_used.tolist(),
                "last_fused_t_ns": int(self.last_fused_t_ns),
                "adaptive": None if self.adaptive is None else self.adaptive.get_state(),
                "consistency": None if self.consistency is None else self.consistency.get_state(),
                **({} if self.vb is None else {"vb": self.vb.get_state()})}

    def set_state(self, state: dict) -> None:
        self.R_used = None if state["R_used"] is None else np.array(state["R_used"], dtype=float)
        self.last_fused_t_ns = int(state["last_fused_t_ns"])
        if self.adaptive is not None:
            self.adaptive.set_state(state["adaptive"])
        if self.consistency is not None:
            self.consistency.set_state(state["consistency"])
        if self.vb is not None:
            self.vb.set_state(state["vb"])
