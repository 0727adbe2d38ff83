"""The navigation engine: strapdown mechanization + 15-state error-state Kalman filter loosely coupled
with GNSS position and velocity, with input validation, GNSS quality gates, innovation gating and
outage detection. Step-wise API (``on_imu``, ``on_gnss``), no transport: the same object serves the
ins service, replay, benchmarks and tests.

GNSS fixes are queued by ``on_gnss`` and fused when the IMU stream reaches their time: the IMU
interval that contains a fix time is split there (increments shared linearly), so the update
happens at the exact fix time. A fix older than the current IMU time is fused at once with its
position propagated by the velocity over the (sub-interval) age.
"""
from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from . import earth
from .aiding import antenna_velocity, position_model, velocity_model
from .eskf import ATT, BA, BG, N_STATES, POS, VEL, ErrorStateKF, discretize, error_model, process_noise_psd
from .rotation import euler_to_quat, quat_multiply, quat_to_euler, rotvec_to_quat
from .strapdown import NavState, mechanize
from .types import NS, GnssFix, InitialState, NavConfig

log = logging.getLogger("zennav.nav")

MAX_FIX_AGE_S = 1.0  # a fix older than this behind the IMU time is stale and not fused


@dataclass
class NavSolution:
    """Navigation solution of the IMU at t_ns: llh [rad, rad, m], v_n [m/s, NED], q_nb, euler (roll, pitch, yaw) [rad],
    bias estimates [rad/s, m/s^2, body], 1-sigma of position [m, NED], velocity [m/s] and attitude error about N, E, D [rad]."""

    t_ns: int
    llh: np.ndarray
    v_n: np.ndarray
    q_nb: np.ndarray
    euler: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    std_pos_ned: np.ndarray
    std_v_n: np.ndarray
    std_euler: np.ndarray
    gnss_state: str


@dataclass
class AidReport:
    """One aiding update: observation, innovation (predicted minus observed), its variance (diagonal of S),
    test ratio d2/threshold (> 1 fails the gate), fused or not, and the reason when not."""

    source: str
    t_ns: int
    observation: list
    innovation: list
    innovation_var: list
    test_ratio: float
    fused: bool
    reason: str = ""


def initial_covariance(initial: InitialState, config: NavConfig) -> np.ndarray:
    """Diagonal-ish P0 from the initial 1-sigma values; the roll/pitch uncertainty is rotated by the yaw into N/E."""
    noise = config.imu_noise
    P0 = np.zeros((N_STATES, N_STATES))
    P0[POS, POS] = np.diag(np.square(initial.std_pos_ned))
    P0[VEL, VEL] = np.diag(np.square(initial.std_v_n))
    cy, sy = math.cos(initial.euler[2]), math.sin(initial.euler[2])
    R_yaw = np.array([[cy, -sy], [sy, cy]])
    P0[6:8, 6:8] = R_yaw @ np.diag(np.square(initial.std_euler[:2])) @ R_yaw.T
    P0[8, 8] = initial.std_euler[2] ** 2
    std_bg = initial.std_gyro_bias if initial.std_gyro_bias is not None else np.full(3, noise.gyro_bias_std)
    std_ba = initial.std_accel_bias if initial.std_accel_bias is not None else np.full(3, noise.accel_bias_std)
    P0[BG, BG] = np.diag(np.square(std_bg))
    P0[BA, BA] = np.diag(np.square(std_ba))
    return P0


class Navigator:
    """GNSS/INS navigation engine for one vehicle (see the module docstring)."""

    def __init__(self, config: NavConfig, initial: InitialState):
        self.config = config
        self.t_ns = int(initial.t_ns)
        self.state = NavState.from_arrays(initial.llh, initial.v_n, euler_to_quat(initial.euler))
        self.gyro_bias = [float(x) for x in initial.gyro_bias]
        self.accel_bias = [float(x) for x in initial.accel_bias]
        self.kf = ErrorStateKF(initial_covariance(initial, config))
        self.counters: Counter[str] = Counter()
        self.gnss_state = "valid"
        self.last_fused_t_ns = self.t_ns
        self._q_psd = process_noise_psd(config.imu_noise)
        self._gate = {m: (chi2.ppf(config.gate_probability, m) if config.gate_probability > 0 else None) for m in (3,)}
        self._lever_b = np.asarray(config.lever_arm_b, dtype=float)
        self._prev_dtheta = (0.0, 0.0, 0.0)
        self._prev_dvel = (0.0, 0.0, 0.0)
        self._omega_dt = ((0.0, 0.0, 0.0), 1.0)  # last bias-corrected angle increment [rad] and its interval [s]
        self._cov_dt = 0.0
        self._cov_dvel = [0.0, 0.0, 0.0]
        self._pending: list[GnssFix] = []
        self._reports: list[AidReport] = []
        self._last_fix_t_ns = -1
        self._streak_start_t_ns: int | None = None  # first of the current run of rejected position fixes
        self._streak_fixes = 0
        self._streak_after_loss = False
        self._update_stds()

    # ------------------------------------------------------------------ inputs
    def on_imu(self, t_ns: int, dtheta_b, dvel_b) -> bool:
        """Process the increments [rad, m/s, body] of the IMU interval ending at t_ns. Returns False when the
        sample is rejected (counted under its reason); the solution is then `solution()`."""
        dtheta = [float(x) for x in dtheta_b]
        dvel = [float(x) for x in dvel_b]
        if not all(map(math.isfinite, dtheta + dvel)) or len(dtheta) != 3 or len(dvel) != 3:
            return self._reject_imu("imu_nonfinite", t_ns)
        if t_ns <= self.t_ns:
            return self._reject_imu("imu_duplicate" if t_ns == self.t_ns else "imu_out_of_order", t_ns)
        while self._pending and self._pending[0].t_ns <= t_ns:
            fix = self._pending.pop(0)
            if fix.t_ns > self.t_ns:
                frac = (fix.t_ns - self.t_ns) / (t_ns - self.t_ns)
                self._advance(fix.t_ns, [frac * x for x in dtheta], [frac * x for x in dvel])
                dtheta = [(1.0 - frac) * x for x in dtheta]
                dvel = [(1.0 - frac) * x for x in dvel]
            self._fuse_gnss(fix)
        self._advance(t_ns, dtheta, dvel)
        self._check_outage()
        return True

    def on_gnss(self, fix: GnssFix) -> None:
        """Queue a GNSS fix; it is fused when the IMU stream reaches its time (at once if it is already past)."""
        reason = self._gnss_input_error(fix)
        if reason:
            self._reject_gnss(fix, reason)
            return
        gap_s = (fix.t_ns - self._last_fix_t_ns) / NS if self._last_fix_t_ns >= 0 else 0.0
        if self._streak_start_t_ns is None:
            self._streak_after_loss = gap_s > self.config.outage_timeout_s
        self._last_fix_t_ns = fix.t_ns
        if fix.t_ns <= self.t_ns:
            self._fuse_gnss(fix)
            return
        k = len(self._pending)
        while k > 0 and self._pending[k - 1].t_ns > fix.t_ns:
            k -= 1
        self._pending.insert(k, fix)

    def pop_reports(self) -> list[AidReport]:
        """Aiding reports produced since the last call."""
        reports, self._reports = self._reports, []
        return reports

    # ------------------------------------------------------------------ outputs
    def solution(self) -> NavSolution:
        s = self.state
        q_nb = s.q_nb
        return NavSolution(
            self.t_ns, s.llh, s.v_n, q_nb, quat_to_euler(q_nb), np.array(self.gyro_bias), np.array(self.accel_bias),
            self.std_pos_ned, self.std_v_n, self.std_att, self.gnss_state,
        )

    def status(self) -> dict:
        return {
            "t_ns": self.t_ns,
            "gnss_state": self.gnss_state,
            "last_fused_t_ns": self.last_fused_t_ns,
            "pending_fixes": len(self._pending),
            "counters": dict(self.counters),
        }

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    # ------------------------------------------------------------------ internals
    def _advance(self, t_ns: int, dtheta: list, dvel: list) -> None:
        dt = (t_ns - self.t_ns) / NS
        bg, ba = self.gyro_bias, self.accel_bias
        dth = (dtheta[0] - bg[0] * dt, dtheta[1] - bg[1] * dt, dtheta[2] - bg[2] * dt)
        dv = (dvel[0] - ba[0] * dt, dvel[1] - ba[1] * dt, dvel[2] - ba[2] * dt)
        mechanize(self.state, dth, dv, self._prev_dtheta, self._prev_dvel, dt)
        self._prev_dtheta, self._prev_dvel = dth, dv
        self.t_ns = t_ns
        self._cov_dt += dt
        cd = self._cov_dvel
        cd[0] += dv[0]
        cd[1] += dv[1]
        cd[2] += dv[2]
        self._omega_dt = (dth, dt)
        if self._cov_dt >= self.config.cov_interval_s:
            self._propagate_covariance()

    def _propagate_covariance(self) -> None:
        dt = self._cov_dt
        if dt <= 0.0:
            return
        s = self.state
        f_b = np.array(self._cov_dvel) / dt
        F = error_model(s.lat, s.h, (s.vn, s.ve, s.vd), s.C_nb, f_b, self.config.imu_noise)
        Phi, Qd = discretize(F, self._q_psd, dt)
        self.kf.propagate(Phi, Qd)
        self._cov_dt = 0.0
        self._cov_dvel = [0.0, 0.0, 0.0]
        self._update_stds()

    def _update_stds(self) -> None:
        """Refresh the 1-sigma of position [m], velocity [m/s] and attitude error [rad] from P."""
        sd = np.sqrt(np.diag(self.kf.P))
        self.std_pos_ned, self.std_v_n, self.std_att = sd[POS], sd[VEL], sd[ATT]

    def _gnss_input_error(self, fix: GnssFix) -> str:
        cfg = self.config
        arrays = [fix.llh, fix.std_ned] + ([fix.v_n, fix.std_v_n] if fix.v_n is not None else [])
        if any(np.shape(a) != (3,) for a in arrays) or not all(np.all(np.isfinite(a)) for a in arrays):
            return "gnss_malformed"
        if fix.t_ns == self._last_fix_t_ns:
            return "gnss_duplicate"
        if fix.t_ns < self._last_fix_t_ns:
            return "gnss_out_of_order"
        if fix.fix < cfg.min_fix:
            return "gnss_fix_quality"
        if 0 <= fix.num_sats < cfg.min_sats:
            return "gnss_few_satellites"
        if np.any(np.asarray(fix.std_ned) <= 0.0) or np.max(fix.std_ned) > cfg.max_std_m:
            return "gnss_std"
        if (self.t_ns - fix.t_ns) / NS > MAX_FIX_AGE_S:
            return "gnss_stale"
        return ""

    def _fuse_gnss(self, fix: GnssFix) -> None:
        self._propagate_covariance()
        age = (self.t_ns - fix.t_ns) / NS  # > 0 only for a fix that arrived after the IMU passed its time
        dth, dt = self._omega_dt
        omega_ib_b = np.array(dth) / dt
        fix_llh = np.asarray(fix.llh, dtype=float)
        v_ant_n = antenna_velocity(self.state, self._lever_b, omega_ib_b)
        z, H = position_model(self.state, self._lever_b, fix_llh, v_ant_n, age)
        cfg = self.config
        R = np.diag(np.square(np.maximum(fix.std_ned, cfg.pos_std_floor_m)))
        force = self._gate_trapped(fix.t_ns)
        if force:
            self._reset_position_velocity(z, R, fix.t_ns)
        if self._update("gnss_pos", fix.t_ns, fix_llh, z, H, R, gated=not force):
            self.last_fused_t_ns = fix.t_ns
            self._streak_start_t_ns, self._streak_fixes = None, 0
            if self.gnss_state != "valid":
                log.warning("GNSS recovered at t=%.3f s after outage", fix.t_ns / NS)
                self.counters["outage_recovered"] += 1
            self.gnss_state = "valid"
        else:
            if self._streak_start_t_ns is None:
                self._streak_start_t_ns = fix.t_ns
            self._streak_fixes += 1
        if fix.v_n is None or not self.config.use_gnss_velocity:
            return
        fix_v_n = np.asarray(fix.v_n, dtype=float)
        z, H = velocity_model(self.state, self._lever_b, omega_ib_b, fix_v_n)
        R = np.diag(np.square(np.maximum(fix.std_v_n, cfg.vel_std_floor_mps)))
        self._update("gnss_vel", fix.t_ns, fix_v_n, z, H, R)

    def _gate_trapped(self, t_ns: int) -> bool:
        """True when the current run of rejected position fixes says the INS has left its own uncertainty."""
        if self._streak_start_t_ns is None:
            return False
        cfg = self.config
        if self._streak_after_loss and self._streak_fixes >= cfg.reacquire_fixes:
            return True
        return (t_ns - self._streak_start_t_ns) / NS >= cfg.gate_reset_s

    def _reset_position_velocity(self, z: np.ndarray, R: np.ndarray, t_ns: int) -> None:
        """Decorrelate position and velocity and widen their variances to cover the innovation z [m] and the
        velocity error that would explain it since the last fused fix; keeps P positive definite."""
        P = self.kf.P
        since_s = max((t_ns - self.last_fused_t_ns) / NS, 1.0)
        var_pos = np.maximum(np.diag(P)[POS], z * z + np.diag(R))
        var_vel = np.maximum(np.diag(P)[VEL], (z / since_s) ** 2)
        P[0:6, :] = 0.0
        P[:, 0:6] = 0.0
        P[POS, POS] = np.diag(var_pos)
        P[VEL, VEL] = np.diag(var_vel)
        self.counters["gate_reset"] += 1
        log.warning("t=%.3f s: %d GNSS fixes rejected in a row, INS taken as wrong: covariance reset, fix fused",
                    t_ns / NS, self._streak_fixes)

    def _update(self, source: str, t_ns: int, obs: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray,
                gated: bool = True) -> bool:
        gate = self._gate[len(z)] if gated else None
        res = self.kf.update(z, H, R, gate)
        reason = ""
        if res.fused:
            self._feedback(res.dx)
            self.counters[f"{source}_fused"] += 1
        else:
            jump = source == "gnss_pos" and float(np.hypot(z[0], z[1])) > self.config.max_jump_m
            reason = f"{source}_{'jump' if jump else 'gate'}"
            self._count_rejection(reason, t_ns, f"test ratio {res.test_ratio:.1f}, innovation {np.round(z, 2)}")
        self._reports.append(
            AidReport(source, t_ns, obs.tolist(), res.innovation.tolist(), np.diag(res.S).tolist(), res.test_ratio,
                      res.fused, reason)
        )
        return res.fused

    def _feedback(self, dx: np.ndarray) -> None:
        """Apply the estimated error to the navigation state (closed loop) and reset it to zero."""
        s = self.state
        r_m, r_n = earth.radii(s.lat)
        s.lat -= dx[0] / (r_m + s.h)
        s.lon -= dx[1] / ((r_n + s.h) * math.cos(s.lat))
        s.h += dx[2]
        s.vn -= dx[3]
        s.ve -= dx[4]
        s.vd -= dx[5]
        q = quat_multiply(rotvec_to_quat(dx[ATT]), s.q_nb)
        q /= np.linalg.norm(q)
        s.q0, s.q1, s.q2, s.q3 = (float(x) for x in q)
        self.gyro_bias = [b - d for b, d in zip(self.gyro_bias, dx[BG].tolist())]
        self.accel_bias = [b - d for b, d in zip(self.accel_bias, dx[BA].tolist())]
        self._update_stds()

    def _check_outage(self) -> None:
        if self.gnss_state == "valid" and (self.t_ns - self.last_fused_t_ns) / NS > self.config.outage_timeout_s:
            self.gnss_state = "outage"
            self.counters["outage_declared"] += 1
            log.warning("GNSS outage declared at t=%.3f s (no valid fix for %.1f s)", self.t_ns / NS,
                        self.config.outage_timeout_s)

    def _reject_imu(self, reason: str, t_ns) -> bool:
        self._count_rejection(reason, t_ns, "")
        return False

    def _reject_gnss(self, fix: GnssFix, reason: str) -> None:
        self._count_rejection(reason, fix.t_ns, "")
        self._reports.append(AidReport("gnss_pos", int(fix.t_ns), np.asarray(fix.llh, float).tolist(), [], [],
                                       float("nan"), False, reason))

    def _count_rejection(self, reason: str, t_ns, detail: str) -> None:
        self.counters[reason] += 1
        n = self.counters[reason]
        if n <= 3 or n % 1000 == 0:
            log.warning("rejected (%s, #%d) at t=%.3f s %s", reason, n, float(t_ns) / NS, detail)
