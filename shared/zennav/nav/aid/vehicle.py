"""The vehicle frame v of a land vehicle (forward-right-down of its body) and the velocity of its constraint point
(the rear axle centre, where a car neither slides sideways nor leaves the road and where its odometer measures),
shared by the non-holonomic constraint (constraints.py) and the odometer (odometer.py).

With the mounting C_bv (roll, pitch, yaw of v in the IMU body frame b) and the lever arm l_b from the IMU to the
constraint point, the velocity of that point in v is (Shin 2005, "Estimation techniques for low-cost inertial
navigation", University of Calgary, section 5.2; Niu et al., "KF-GINS", GPS Solutions 29, 2025, ODO/NHC update):
    v_v = C_vb (C_bn v_n + omega_nb_b x l_b),  omega_nb_b = omega_ib_b - C_bn omega_in_n.
Error model (eskf.py: C_bn_hat = C_bn (I + [phi x]), v_hat = v + dv, omega_ib_b_hat = omega_ib_b - dbg):
    omega_nb_b_hat = omega_nb_b - dbg + C_bn [omega_in_n x] phi,
    v_v_hat ~ v_v + C_vb C_bn dv - C_vb (C_bn [v_n x] + [l_b x] C_bn [omega_in_n x]) phi + C_vb [l_b x] dbg
so H = [0, C_vb C_bn, -C_vb (C_bn [v_n x] + [l_b x] C_bn [omega_in_n x]), C_vb [l_b x], 0]. The mounting and the
lever arm are configured (NavConfig vehicle_mount_euler, vehicle_lever_b), not estimated.
"""
from __future__ import annotations

import numpy as np

from .. import earth
from ..eskf import ATT, BG, VEL
from ..rotation import euler_to_dcm, skew
from ..strapdown import NavState
from ..types import NavConfig


class VehicleFrame:
    """C_vb [-] and l_b [m, FRD] of a configuration (see the module docstring); mount_euler [rad] / lever_b [m]:
    another frame and point instead of the vehicle's (a DVL's frame d and lever arm: v_d and its Jacobian,
    zennav.nav.aid.dvl)."""

    def __init__(self, config: NavConfig, mount_euler=None, lever_b=None):
        mount = config.vehicle_mount_euler if mount_euler is None else mount_euler
        self.C_vb = euler_to_dcm(np.asarray(mount, dtype=float)).T
        self.lever_b = np.asarray(config.vehicle_lever_b if lever_b is None else lever_b, dtype=float)

    def velocity(self, s: NavState, omega_ib_b: np.ndarray, n_states: int) -> tuple[np.ndarray, np.ndarray]:
        """v_v [m/s] of the constraint point at the state s with the bias-corrected body rate omega_ib_b [rad/s],
        and its Jacobian H (3 x n_states) with respect to the error state."""
        C_bn = s.C_nb.T
        omega_in_n = earth.omega_ie_n(s.lat) + earth.omega_en_n(s.lat, s.h, (s.vn, s.ve, s.vd))
        omega_nb_b = omega_ib_b - C_bn @ omega_in_n
        C_vn = self.C_vb @ C_bn
        v_n = s.v_n
        v_v = C_vn @ v_n + self.C_vb @ np.cross(omega_nb_b, self.lever_b)
        H = np.zeros((3, n_states))
        H[:, VEL] = C_vn
        H[:, ATT] = -C_vn @ skew(v_n) - self.C_vb @ skew(self.lever_b) @ C_bn @ skew(omega_in_n)
        H[:, BG] = self.C_vb @ skew(self.lever_b)
        return v_v, H
