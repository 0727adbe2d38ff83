"""Vehicle-motion constraints as aiding sources.

NonHolonomic (NHC): a land vehicle neither slides sideways nor leaves the road surface, so the velocity of its
constraint point (the rear axle centre) in the vehicle frame has zero lateral and vertical components,
v_v[1:3] = 0, with noise of 1-sigma nhc_std_mps covering sideslip, suspension motion and vibration (Shin 2001,
"Accuracy Improvement of Low Cost INS/GPS for Land Applications", University of Calgary, section 4.4; Dissanayake
et al., IEEE TRA 17(5) 2001). That noise is not white: a car dives on its suspension for as long as it brakes and
slips for as long as it turns. Fused every nhc_every_s as if independent, a violation held over many updates is
taken at its full size (on the rtklibexplorer drive, GNSS withheld 390-420 s, a hard braking into a 1 s stop took
the INS forward speed 2.3 m/s below the truth through the constraint's updates, where the free INS stayed
within 0.05 m/s). The violation is therefore taken as first-order Gauss-Markov with correlation time nhc_corr_s and
each update's variance inflated by the AR(1) factor (base.correlated_variance), so that the updates within a
correlation time weigh about as much as one independent one: the simplest of the treatments of coloured
measurement noise (state augmentation or measurement differencing: Bryson and Henrikson, J. Spacecraft and
Rockets 5(6), 1968; Gelb, "Applied Optimal Estimation", 1974).
Its measurement is rows 2 and 3 of the vehicle-frame velocity model (zennav.nav.aid.vehicle: IMU-to-vehicle
mounting angles and the lever arm to the rear axle, configured). It is fused every nhc_every_s of data time once
the heading is known (not in coarse alignment), with GNSS or without, gated like GNSS.
"""
from __future__ import annotations

import numpy as np

from ..types import NS, AlignState, NavConfig
from .base import AidSource, Measurement, correlated_variance
from .vehicle import VehicleFrame


class NonHolonomic(AidSource):
    """The non-holonomic constraint (module docstring); name nhc."""

    inputs = ()  # no input: it acts on the engine's own state after IMU samples (on_step)

    def __init__(self, config: NavConfig, t0_ns: int):
        super().__init__("nhc")
        self.every_ns = int(round(config.nhc_every_s * NS))
        self.R = np.diag(np.full(2, correlated_variance(config.nhc_std_mps, config.nhc_every_s, config.nhc_corr_s)))
        self.vehicle = VehicleFrame(config)
        self.next_ns = int(t0_ns) + self.every_ns

    def on_input(self, nav, data) -> bool:
        raise TypeError("the non-holonomic constraint takes no input")

    def on_step(self, nav) -> None:
        if nav.t_ns < self.next_ns or nav.align_state == AlignState.COARSE:
            return
        self.next_ns = nav.t_ns + self.every_ns
        nav.propagate_covariance()
        omega_ib_b = nav.imu_rates()[0]
        v_v, H = self.vehicle.velocity(nav.state, omega_ib_b, nav.n_states)
        nav.update(self, Measurement(nav.t_ns, np.zeros(2), v_v[1:3], H[1:3], self.R))

    def next_step_ns(self, nav) -> int | None:
        return self.next_ns

    def get_state(self) -> dict:
        return {**super().get_state(), "next_ns": int(self.next_ns)}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.next_ns = int(state["next_ns"])
