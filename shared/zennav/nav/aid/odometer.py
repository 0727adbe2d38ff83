"""Odometer / wheel-speed aiding with a scale-factor state.

An odometer measures the forward speed of the vehicle at its constraint point (zennav.nav.aid.vehicle), scaled by
(1 + k) with k its scale-factor error: s = (1 + k) v_v[0] + noise (1-sigma odo_std_mps). k is an augmented state of
the engine (Navigator.add_states "odo_scale": first-order Gauss-Markov, initial 1-sigma odo_scale_std, driving PSD
odo_scale_psd, time constant odo_scale_tau_s; its value k_hat, error k_hat - k). With v_v[0] from the vehicle model:
    z = (1 + k_hat) v_v_hat[0] - s,  H = [(1 + k_hat) H_v[0], v_v_hat[0] in the k column]
(Shin 2005, section 5.2; Niu et al., KF-GINS, GPS Solutions 29, 2025). Samples come through
``Navigator.on_aid("odometer", OdometerSample)`` and are fused at the engine's time: a sample at most
odo_max_age_s older than the IMU time (else odo_stale), after the last one (else odo_out_of_order), with a finite
speed of at most odo_max_speed_mps either way (negative: reversing; else odo_malformed), each rejection counted
and reported; gated like GNSS; not in coarse alignment (odo_coarse, counted only).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..types import NS, AlignState, NavConfig
from .base import AidSource, Measurement
from .vehicle import VehicleFrame


@dataclass
class OdometerSample:
    """One odometer reading: forward speed [m/s] at t_ns."""

    t_ns: int
    speed_mps: float


class Odometer(AidSource):
    """The odometer with its scale-factor state (module docstring); name odo."""

    inputs = ("odometer",)

    def __init__(self, config: NavConfig):
        super().__init__("odo")
        self.config = config
        self.vehicle = VehicleFrame(config)
        self.R = np.array([[config.odo_std_mps**2]])
        self.max_age_ns = int(round(config.odo_max_age_s * NS))
        self.last_t_ns = -1
        self.scale: slice | None = None  # where k sits in the engine's error state (attach)

    def attach(self, nav) -> None:
        cfg = self.config
        self.scale = nav.add_states("odo_scale", np.array([cfg.odo_scale_std]), np.array([cfg.odo_scale_psd]),
                                    cfg.odo_scale_tau_s)

    def admit(self, nav, sample: OdometerSample) -> bool:
        t_ns, speed = int(sample.t_ns), float(sample.speed_mps)
        reason = ""
        if not (math.isfinite(speed) and abs(speed) <= self.config.odo_max_speed_mps):
            reason = "odo_malformed"
        elif t_ns <= self.last_t_ns:
            reason = "odo_out_of_order"
        elif nav.t_ns - t_ns > self.max_age_ns:
            reason = "odo_stale"
        if reason:
            self.reject(nav, t_ns, reason, f"speed {speed!r}", [speed], faults=(reason[4:],))
            return False
        self.last_t_ns = t_ns
        return True

    def on_input(self, nav, sample: OdometerSample) -> bool:
        if nav.align_state == AlignState.COARSE:
            nav.counters["odo_coarse"] += 1
            return False
        assert self.scale is not None  # attached by Navigator.add_source
        nav.propagate_covariance()
        k = float(nav.aug_value(self.scale)[0])
        v_v, H_v = self.vehicle.velocity(nav.state, nav.imu_rates()[0], nav.n_states)
        H = (1.0 + k) * H_v[0:1]
        H[0, self.scale] = v_v[0]
        z = np.array([(1.0 + k) * v_v[0] - float(sample.speed_mps)])
        return nav.update(self, Measurement(int(sample.t_ns), np.array([float(sample.speed_mps)]), z, H, self.R))

    def get_state(self) -> dict:
        return {**super().get_state(), "last_t_ns": int(self.last_t_ns)}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.last_t_ns = int(state["last_t_ns"])
