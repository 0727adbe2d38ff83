"""Pressure depth aiding with a depth-bias state (seed 003: the depth sensor's X_PS), name "depth".

The sensor reports its depth, positive down, below the water surface at height h_surface (NavConfig
depth_surface_h_m, in the dataset's heights): d = h_surface - h + b_ps + noise (1-sigma depth_std_m), b_ps its bias,
an augmented state of the engine ("depth_bias": first-order Gauss-Markov, NavConfig depth_bias_*; value estimate minus
truth). The sensor sits at the IMU (no lever arm: a depth sensor metres from the IMU on a pitching AUV sees the
pitch times the lever arm; not modelled). With the error state's down position error dr_D = -(h_hat - h):
    z = h_surface - h_hat + b_hat - d,   H = [1 in dr_D's column, 1 in b_ps's column]
(Groves 2013, "Principles of GNSS, inertial, and multisensor integrated navigation systems", section 16.2 on pressure
depth and height aiding). Samples come through ``Navigator.on_aid("depth", DepthSample)`` and are fused at the
engine's time; input checks as the odometer's: non-finite (depth_nonfinite), not after the last
(depth_out_of_order), older than depth_max_age_s (depth_stale); gated; not in coarse alignment (depth_coarse).
"""
from __future__ import annotations

import math

import numpy as np

from ..eskf import POS
from ..types import NS, AlignState, DepthSample, NavConfig
from .base import AidSource, Measurement


class Depth(AidSource):
    """The depth source with its bias state (module docstring)."""

    inputs = ("depth",)

    def __init__(self, config: NavConfig):
        super().__init__("depth")
        self.config = config
        self.R = np.array([[config.depth_std_m**2]])
        self.max_age_ns = int(round(config.depth_max_age_s * NS))
        self.last_t_ns = -1
        self.bias: slice | None = None

    def attach(self, nav) -> None:
        cfg = self.config
        self.bias = nav.add_states("depth_bias", np.array([cfg.depth_bias_std_m]), np.array([cfg.depth_bias_psd]),
                                   cfg.depth_bias_tau_s)

    def admit(self, nav, sample: DepthSample) -> bool:
        t_ns, depth = int(sample.t_ns), float(sample.depth_m)
        reason = ""
        if not math.isfinite(depth):
            reason = "depth_nonfinite"
        elif t_ns <= self.last_t_ns:
            reason = "depth_out_of_order"
        elif nav.t_ns - t_ns > self.max_age_ns:
            reason = "depth_stale"
        if reason:
            self.reject(nav, t_ns, reason, f"depth {depth!r}", [depth], faults=(reason[6:],))
            return False
        self.last_t_ns = t_ns
        return True

    def on_input(self, nav, sample: DepthSample) -> bool:
        if nav.align_state == AlignState.COARSE:
            nav.counters["depth_coarse"] += 1
            return False
        assert self.bias is not None  # attached by Navigator.add_source
        nav.propagate_covariance()
        b = float(nav.aug_value(self.bias)[0])
        depth = float(sample.depth_m)
        H = np.zeros((1, nav.n_states))
        H[0, POS.start + 2] = 1.0
        H[0, self.bias] = 1.0
        z = np.array([self.config.depth_surface_h_m - nav.state.h + b - depth])
        return nav.update(self, Measurement(int(sample.t_ns), np.array([depth]), z, H, self.R))

    def get_state(self) -> dict:
        return {**super().get_state(), "last_t_ns": int(self.last_t_ns)}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.last_t_ns = int(state["last_t_ns"])


def depth_source(config: NavConfig) -> Depth | None:
    """The depth source where it is on and the data has depth samples, else None."""
    return Depth(config) if config.depth and config.has_depth else None
