"""Zero-velocity (ZUPT) and zero-angular-rate (ZARU) updates with automatic standstill detection.

Detector (after every IMU sample, on the measured specific force, which no update can bend, and the bias-corrected
body rate): over the last zupt_window_s,
the RMS deviation of the specific force f_b from its window mean (the moving-variance detector) and the RMS of the
body rate (the angular-rate-energy detector) of Skog et al., "Zero-velocity detection - an algorithm evaluation",
IEEE Trans. Biomed. Eng. 57(11), 2010, each below its threshold; the vehicle's own acceleration, seen as the
horizontal part of the window-mean specific force in n, below zupt_accel_mps2 (tolerant of the tilt error: 0.1 m/s^2
is 0.6 deg) and, from the start of a standstill until a motion test below fails, as the change of the window-mean
f_b since that start (free of tilt errors) below zupt_accel_change_mps2 (a car braking or pulling away smoothly
passes both variance tests; the magnitude |f|, which SHOE watches, barely moves); where present, the GNSS speed of
the last second below zupt_gnss_speed_mps; and the INS's own speed below zupt_ins_speed_mps (a car that stands was
seen to brake: a smooth cruise, which no IMU can tell from rest, is not taken for a stop). Hysteresis: the vehicle
is still once the test has passed for zupt_enter_s, and moving at the first sample that fails it.

While still, every zupt_every_s: the velocity is zero, z = v_n_hat, H = [0, I, 0, 0, 0] (1-sigma zupt_std_mps), and
with zaru the body rate averaged since the last update equals the earth rate, z = mean(omega_ib_b_hat) -
C_bn omega_ie_n with omega_ib_b_hat = omega_ib_b - dbg and C_bn_hat = C_bn (I + [phi x]):
H = [0, 0, C_bn [omega_ie_n x], -I, 0] (1-sigma zaru_std), which calibrates the gyro bias (Groves 2013, section
15.3). One gated update of both, reported on nav/aid/zupt; counters zupt_standstills (detections), zupt_fused,
zupt_gate. Not in coarse alignment.

Not caught: a stop of about a second after hard braking. On the rtklibexplorer drive the car brakes at 2.5 m/s^2
into a 1.0 s stop (397-398 s after the start): the body rocks on its suspension through the whole stop (over the
0.5 s window, specific-force RMS deviation 0.2-1.1 m/s^2 and rate RMS 0.4-1.7 deg/s, against 0.01-0.05 m/s^2 and
0.2 deg/s at the drive's long stops); thresholds loose enough to pass its quietest 0.17 s (0.22 m/s^2 and
0.5 deg/s) also pass 31 % of the 0.5 s windows of crawling at 0.05-0.5 m/s (true speed), which a ZUPT would pin to
zero. The forward-speed error of 2.3 m/s measured there came from the non-holonomic constraint
(zennav.nav.aid.constraints), not from the missed stop.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from .. import earth
from ..eskf import ATT, BG, VEL
from ..rotation import skew
from ..types import NS, AlignState, NavConfig
from .base import AidSource, Measurement
from .gnss import FixContext

GNSS_SPEED_MAX_AGE_NS = NS  # a GNSS velocity counts for the detector this long [ns]


class ZeroVelocity(AidSource):
    """ZUPT and ZARU at detected standstills (module docstring); name zupt. still: the detector's state."""

    inputs = ("gnss",)  # the GNSS speed for the detector (it fuses nothing from a fix)

    def __init__(self, config: NavConfig, t0_ns: int):
        super().__init__("zupt")
        self.window_ns = int(round(config.zupt_window_s * NS))
        self.enter_ns = int(round(config.zupt_enter_s * NS))
        self.every_ns = int(round(config.zupt_every_s * NS))
        self.max_accel_var = config.zupt_accel_std_mps2**2
        self.max_gyro_ms = config.zupt_gyro_rms**2
        self.max_accel2 = config.zupt_accel_mps2**2
        self.max_accel_change2 = config.zupt_accel_change_mps2**2
        self.gnss_speed_mps = config.zupt_gnss_speed_mps
        self.ins_speed_mps = config.zupt_ins_speed_mps
        self.zaru = config.zaru
        std = [config.zupt_std_mps] * 3 + ([config.zaru_std] * 3 if config.zaru else [])
        self.R = np.diag(np.square(std))
        # detector window: (t_ns, measured f_b, |corrected omega|^2) per sample; running sums of f, |f|^2, |omega|^2
        self.window: deque = deque()
        self.sums = [0.0] * 5
        self.gnss_t_ns, self.gnss_speed = -1, 0.0
        self.still = False
        self.passing_since_ns: int | None = None
        # window-mean measured specific force when the last standstill began [m/s^2], until a motion test fails
        self.f_ref_b: np.ndarray | None = None
        self.next_ns = 0
        self.rate_sum, self.rate_dt = [0.0, 0.0, 0.0], 0.0  # bias-corrected angle since the last update [rad, s]

    def on_input(self, nav, ctx: FixContext) -> bool:
        fix = ctx.fix
        if fix.v_n is not None:
            self.gnss_t_ns, self.gnss_speed = int(fix.t_ns), math.hypot(fix.v_n[0], fix.v_n[1])
        return False

    def _add(self, t_ns: int, f_b: np.ndarray, omega_ib_b: np.ndarray) -> None:
        fx, fy, fz = (float(x) for x in f_b)
        w2 = float(omega_ib_b @ omega_ib_b)
        self.window.append((t_ns, fx, fy, fz, w2))
        s = self.sums
        s[0] += fx
        s[1] += fy
        s[2] += fz
        s[3] += fx * fx + fy * fy + fz * fz
        s[4] += w2
        while self.window[0][0] <= t_ns - self.window_ns:
            _, fx, fy, fz, w2 = self.window.popleft()
            s[0] -= fx
            s[1] -= fy
            s[2] -= fz
            s[3] -= fx * fx + fy * fy + fz * fz
            s[4] -= w2

    def test(self, nav) -> bool:
        """The detector's test at the engine's time (without the hysteresis)."""
        n = len(self.window)
        if self.window[-1][0] - self.window[0][0] < self.window_ns // 2:
            return False  # too few samples yet
        s = self.sums
        f_b = np.array(s[0:3]) / n
        if not self._moving_free(nav, f_b):
            self.f_ref_b = None
            return False
        if self.f_ref_b is not None and float(np.sum(np.square(f_b - self.f_ref_b))) > self.max_accel_change2:
            return False
        f_n = nav.state.C_nb @ f_b
        return f_n[0] * f_n[0] + f_n[1] * f_n[1] <= self.max_accel2

    def _moving_free(self, nav, f_b: np.ndarray) -> bool:
        """The tests that motion fails: window variance of f_b, RMS rate, INS speed, GNSS speed."""
        s, n = self.sums, len(self.window)
        if s[3] / n - float(f_b @ f_b) > self.max_accel_var or s[4] / n > self.max_gyro_ms:
            return False
        v = nav.state
        if math.sqrt(v.vn * v.vn + v.ve * v.ve + v.vd * v.vd) > self.ins_speed_mps:
            return False
        return not (self.gnss_t_ns >= 0 and nav.t_ns - self.gnss_t_ns <= GNSS_SPEED_MAX_AGE_NS
                    and self.gnss_speed > self.gnss_speed_mps)

    def on_step(self, nav) -> None:
        omega_ib_b, _, dt = nav.imu_rates()
        t_ns = nav.t_ns
        self._add(t_ns, nav.imu_rates(corrected=False)[1], omega_ib_b)
        if nav.align_state == AlignState.COARSE or not self.test(nav):
            self.still, self.passing_since_ns = False, None
            self.rate_sum, self.rate_dt = [0.0, 0.0, 0.0], 0.0
            return
        self.rate_sum = [a + w * dt for a, w in zip(self.rate_sum, omega_ib_b.tolist())]
        self.rate_dt += dt
        if self.passing_since_ns is None:
            self.passing_since_ns = t_ns
        if not self.still:
            if t_ns - self.passing_since_ns < self.enter_ns:
                return
            self.still, self.next_ns = True, t_ns
            self.f_ref_b = np.array(self.sums[0:3]) / len(self.window)
            nav.counters["zupt_standstills"] += 1
        if t_ns >= self.next_ns:
            self.next_ns = t_ns + self.every_ns
            self._update(nav)

    def _update(self, nav) -> None:
        nav.propagate_covariance()
        s = nav.state
        H = np.zeros((6 if self.zaru else 3, nav.n_states))
        H[0:3, VEL] = np.eye(3)
        z = s.v_n
        observation = [0.0, 0.0, 0.0]
        if self.zaru:
            C_bn = s.C_nb.T
            omega_ie_n = earth.omega_ie_n(s.lat)
            rate = np.array(self.rate_sum) / self.rate_dt
            z = np.concatenate([z, rate - C_bn @ omega_ie_n])
            H[3:6, ATT] = C_bn @ skew(omega_ie_n)
            H[3:6, BG] = -np.eye(3)
            observation += (C_bn @ omega_ie_n).tolist()
            self.rate_sum, self.rate_dt = [0.0, 0.0, 0.0], 0.0
        nav.update(self, Measurement(nav.t_ns, np.array(observation), z, H, self.R))

    def get_state(self) -> dict:
        return {**super().get_state(), "window": [list(w) for w in self.window], "sums": list(self.sums),
                "gnss": [int(self.gnss_t_ns), float(self.gnss_speed)], "still": bool(self.still),
                "passing_since_ns": self.passing_since_ns, "next_ns": int(self.next_ns),
                "f_ref_b": None if self.f_ref_b is None else self.f_ref_b.tolist(),
                "rate": [list(self.rate_sum), float(self.rate_dt)]}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.window = deque((int(w[0]), *(float(x) for x in w[1:])) for w in state["window"])
        self.sums = [float(x) for x in state["sums"]]
        self.gnss_t_ns, self.gnss_speed = int(state["gnss"][0]), float(state["gnss"][1])
        self.still = bool(state["still"])
        p = state["passing_since_ns"]
        self.passing_since_ns = None if p is None else int(p)
        self.next_ns = int(state["next_ns"])
        self.f_ref_b = None if state["f_ref_b"] is None else np.array(state["f_ref_b"], dtype=float)
        self.rate_sum, self.rate_dt = [float(x) for x in state["rate"][0]], float(state["rate"][1])
