"""Vehicle-motion constraints as aiding sources.

NonHolonomic (NHC): a land vehicle neither slides sideways nor leaves the road surface, so the velocity of its body
frame has zero lateral and vertical components, v_b[1:3] = (C_bn v_n)[1:3] = 0 with white noise of 1-sigma
nhc_std_mps covering sideslip, suspension motion and vibration (Shin 2001, "Accuracy Improvement of Low Cost
INS/GPS for Land Applications", University of Calgary, section 4.4; Dissanayake et al., IEEE TRA 17(5) 2001). Its
measurement is rows 2 and 3 of the body-velocity model (zennav.nav.aiding.body_velocity_model). It is fused every
nhc_every_s of data time once the heading is known (not in coarse alignment), with GNSS or without, gated like
GNSS. Assumed here: the IMU body frame is the vehicle frame (no mounting angles) and the IMU sits near the
constraint point (the rear axle; no lever arm). Estimating the mounting and the lever arm is not done yet.
"""
from __future__ import annotations

import numpy as np

from ..aiding import body_velocity_model
from ..types import NS, AlignState, NavConfig
from .base import AidSource, Measurement


class NonHolonomic(AidSource):
    """The non-holonomic constraint (module docstring); name nhc."""

    inputs = ()  # no input: it acts on the engine's own state after IMU samples (on_step)

    def __init__(self, config: NavConfig, t0_ns: int):
        super().__init__("nhc")
        self.every_ns = int(round(config.nhc_every_s * NS))
        self.R = np.diag(np.full(2, config.nhc_std_mps**2))
        self.next_ns = int(t0_ns) + self.every_ns

    def on_input(self, nav, data) -> bool:
        raise TypeError("the non-holonomic constraint takes no input")

    def on_step(self, nav) -> None:
        if nav.t_ns < self.next_ns or nav.align_state == AlignState.COARSE:
            return
        self.next_ns = nav.t_ns + self.every_ns
        nav.propagate_covariance()
        z, H = body_velocity_model(nav.state, np.zeros(3))
        nav.update(self, Measurement(nav.t_ns, np.zeros(2), z[1:3], H[1:3], self.R))

    def get_state(self) -> dict:
        return {**super().get_state(), "next_ns": int(self.next_ns)}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.next_ns = int(state["next_ns"])
