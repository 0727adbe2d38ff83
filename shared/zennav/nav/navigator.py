"""The navigation engine: strapdown mechanization + 15-state error-state Kalman filter loosely coupled
with GNSS position and velocity, with input validation, GNSS quality gates, innovation gating and
outage detection. Step-wise API (``on_imu``, ``on_gnss``), no transport: the same object serves the
ins service, replay, benchmarks and tests.

GNSS fixes are queued by ``on_gnss`` and fused when the IMU stream reaches their time: the IMU
interval that contains a fix time is split there (increments shared linearly), so the update
happens at the exact fix time. A fix older than the current IMU time is fused at once with its
position propagated by the velocity over the (sub-interval) age.

Alignment (zennav.nav.alignment): with the heading unknown (InitialState.heading_is_known) the engine starts in
'coarse': it integrates only the attitude, holds the last GNSS velocity and dead-reckons the position on it
(nothing is integrated with the unknown heading), levels at rest, gyrocompasses at rest where the gyro allows
it, and otherwise takes yaw (and, without a better tilt, pitch) from the GNSS velocity once the speed exceeds
align_min_speed_mps. The filter then starts from that attitude with its honest variance ('fine') and the
alignment is complete ('aligned') when the heading 1-sigma drops below align_heading_std. With a known heading
the engine starts in 'fine' or 'aligned'. All the alignment decisions are taken at GNSS fixes.

GNSS faults: quality gates at input, a jump test before the update (a fix more than max_jump_m from the INS
prediction and outside the chi-square gate of the reported R), the chi-square gate with the adapted R
(zennav.nav.adaptive_r, seed 001, per source), the gate-trap recovery, outage declaration and recovery; every
rejection is counted under its reason and reported (AidReport.reason).
"""
from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from . import earth
from .adaptive_r import AdaptiveR
from .aiding import antenna_velocity, body_velocity_model, position_model, velocity_model
from .alignment import course_alignment, gyrocompass_refusal, level, levelling_std, static_alignment
from .learning import OUTPUTS, LearningTap, LearnQuery, LearnSample
from .eskf import ATT, BA, BG, N_STATES, POS, VEL, ErrorStateKF, discretize, error_model, process_noise_psd
from .rotation import euler_to_quat, quat_multiply, quat_to_euler, rotvec_to_quat
from .strapdown import NavState, mechanize
from .types import NS, GnssFix, InitialState, NavConfig

log = logging.getLogger("zennav.nav")

MAX_FIX_AGE_S = 1.0  # a fix older than this behind the IMU time is stale and not fused
LEARN_SETTLE_S = 10.0  # no training samples for this long after an outage or a covariance reset [s]


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
    test ratio d2/threshold (> 1 fails the gate), fused or not, and the reason when not: a rejection (gnss_*), or
    during coarse alignment how the fix was used instead (align_coarse: tracked; align_in_motion /
    align_gyrocompass: the fix that started the filter)."""

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
        self._coarse = not initial.heading_is_known()  # coarse alignment: the per-sample flag of _advance
        if self._coarse:  # yaw 0 as a placeholder with the 1-sigma of an angle uniform in +-180 deg; so for an
            # unknown (non-finite) roll or pitch, which in-motion alignment then takes as 0 / the climb angle
            known = [math.isfinite(float(a)) for a in initial.euler[:2]]
            euler = [float(a) if k else 0.0 for a, k in zip(initial.euler[:2], known)] + [0.0]
            std = [float(e) if k else math.pi / math.sqrt(3.0) for e, k in zip(initial.std_euler[:2], known)]
            initial = replace(initial, euler=np.array(euler), std_euler=np.array(std + [math.pi / math.sqrt(3.0)]))
        self._initial = initial
        self.state = NavState.from_arrays(initial.llh, initial.v_n, euler_to_quat(initial.euler))
        self.gyro_bias = [float(x) for x in initial.gyro_bias]
        self.accel_bias = [float(x) for x in initial.accel_bias]
        self.kf = ErrorStateKF(initial_covariance(initial, config))
        self.counters: Counter[str] = Counter()
        self.gnss_state = "valid"
        self.last_fused_t_ns = self.t_ns
        self._q_psd = process_noise_psd(config.imu_noise)
        self._gate = {m: (chi2.ppf(config.gate_probability, m) if config.gate_probability > 0 else None) for m in (2, 3)}
        self._adaptive = {src: AdaptiveR(3, config.adaptive_window, config.adaptive_forgetting,
                                         config.adaptive_test_probability, config.adaptive_floor,
                                         config.adaptive_ceiling)
                          for src in ("gnss_pos", "gnss_vel")} if config.adaptive_r else {}
        self._R_used: dict[str, np.ndarray] = {}  # R of the last update per source, adapted or not
        self._lever_b = np.asarray(config.lever_arm_b, dtype=float)
        self._prev_dtheta = (0.0, 0.0, 0.0)
        self._prev_dvel = (0.0, 0.0, 0.0)
        self._omega_dt = ((0.0, 0.0, 0.0), 1.0)  # last bias-corrected angle increment [rad] and its interval [s]
        self._cov_dt = 0.0
        self._cov_dvel = [0.0, 0.0, 0.0]
        self._pending: list[GnssFix] = []
        self._reports: list[AidReport] = []
        self._tap = LearningTap(config.learn_horizon_s) if config.learning else None
        self._dx_since_fix = np.zeros(N_STATES)  # corrections of the GNSS fix being fused
        self._last_dx = np.zeros(N_STATES)
        self._gnss_interval_s: float | None = None  # between the last two fused position fixes
        self._learn_start_t_ns = self.t_ns + int(config.learn_after_s * NS)
        self._last_fix_t_ns = -1
        self._streak_start_t_ns: int | None = None  # first of the current run of rejected position fixes
        self._streak_fixes = 0
        self._streak_after_loss = False
        self._init_alignment(initial)
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
        if self._tap is not None:
            self._tap.maybe_query(self.t_ns, self.state, self._gnss_interval_s)
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

    def pop_samples(self) -> list[LearnSample]:
        """Training samples produced since the last call (only with config.learning)."""
        if self._tap is None:
            return []
        samples, self._tap.samples = self._tap.samples, []
        return samples

    def pop_queries(self) -> list[LearnQuery]:
        """Prediction requests produced since the last call (only with config.learning)."""
        if self._tap is None:
            return []
        queries, self._tap.queries = self._tap.queries, []
        return queries

    def on_correction(self, query: LearnQuery, value, std) -> bool:
        """Fuse a learned prediction for a query (nav/learning.py) as a pseudo-measurement, gated like GNSS:
        "position" / "velocity": N and E error rates [m/s, m/s^2] accrued over the query's interval; "drift": N and
        E error of the free-running INS since the last fix [m], fused into the position alone (a Schmidt update:
        velocity, attitude and biases stay as they are, as in the shadow INSs the model learned from);
        "body_velocity": the velocity in the body frame [m/s, FRD], now. std: the 1-sigma of value, alike."""
        value, std = np.asarray(value, dtype=float), np.asarray(std, dtype=float)
        shape = (len(OUTPUTS[query.target]),) if query.target in OUTPUTS else None
        if self._tap is None or shape is None or value.shape != shape or std.shape != shape or not (
                np.all(np.isfinite(value)) and np.all(std > 0)):
            self._count_rejection("correction_malformed", query.t_ns, "")
            return False
        self._propagate_covariance()
        if query.target == "body_velocity":
            z, H = body_velocity_model(self.state, value)
            return self._update("learned_body_velocity", query.t_ns, value, z, H, np.diag(np.square(std)))
        H = np.zeros((2, N_STATES))
        first = 3 if query.target == "velocity" else 0
        H[0, first], H[1, first + 1] = 1.0, 1.0
        if query.target == "drift":
            fused = self._update("learned_drift", query.t_ns, value, value - self._tap.shift_ne, H,
                                 np.diag(np.square(std)), gain_states=POS)
            if fused:
                self._tap.shift_ne += self._last_dx[0:2]
            return fused
        return self._update(f"learned_{query.target}", query.t_ns, value, value * query.dt_s, H,
                            np.diag(np.square(std * query.dt_s)))

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
            "alignment": {"state": self.align_state, "method": self.align_method,
                          "heading_std_rad": float(self.std_att[2]), "times_ns": dict(self.align_times),
                          "tilt_source": self._tilt_source, "gyrocompass": self._gyrocompass_refusal},
            "adaptive_r": bool(self._adaptive),
            "measurement_noise": {src: self._adaptive[src].status() if src in self._adaptive else {"R": R.tolist()}
                                  for src, R in self._R_used.items()},
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
        if self._coarse:
            self._advance_coarse(t_ns, dth, dv, dt)
            return
        mechanize(self.state, dth, dv, self._prev_dtheta, self._prev_dvel, dt)
        if self._tap is not None:
            self._tap.on_step(dtheta, dvel, dth, dv, dt)
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
        self._dx_since_fix = np.zeros(N_STATES)
        age = (self.t_ns - fix.t_ns) / NS  # > 0 only for a fix that arrived after the IMU passed its time
        dth, dt = self._omega_dt
        omega_ib_b = np.array(dth) / dt
        fix_llh = np.asarray(fix.llh, dtype=float)
        v_ant_n = antenna_velocity(self.state, self._lever_b, omega_ib_b)
        z, H = position_model(self.state, self._lever_b, fix_llh, v_ant_n, age)
        cfg = self.config
        R = np.diag(np.square(np.maximum(fix.std_ned, cfg.pos_std_floor_m)))
        if self._coarse:
            self._coarse_fix(fix, z, omega_ib_b)
            return
        force = self._gate_trapped(fix.t_ns)
        if force:
            self._reset_position_velocity(z, R, fix.t_ns)
            pos_fused = self._update("gnss_pos", fix.t_ns, fix_llh, z, H, R, gated=False)
        else:
            pos_fused = not self._is_jump(fix.t_ns, fix_llh, z, H, R) and self._update(
                "gnss_pos", fix.t_ns, fix_llh, z, H, R)
        if pos_fused:
            if 0 < (fix.t_ns - self.last_fused_t_ns) / NS < 5.0:
                self._gnss_interval_s = (fix.t_ns - self.last_fused_t_ns) / NS
            self.last_fused_t_ns = fix.t_ns
            self._streak_start_t_ns, self._streak_fixes = None, 0
            if self.gnss_state != "valid":
                self._learn_start_t_ns = max(self._learn_start_t_ns, fix.t_ns + int(LEARN_SETTLE_S * NS))
                log.warning("GNSS recovered at t=%.3f s after outage", fix.t_ns / NS)
                self.counters["outage_recovered"] += 1
            self.gnss_state = "valid"
        else:
            if self._streak_start_t_ns is None:
                self._streak_start_t_ns = fix.t_ns
            self._streak_fixes += 1
        if fix.v_n is not None and self.config.use_gnss_velocity:
            fix_v_n = np.asarray(fix.v_n, dtype=float)
            z, H = velocity_model(self.state, self._lever_b, omega_ib_b, fix_v_n)
            R = np.diag(np.square(np.maximum(fix.std_v_n, cfg.vel_std_floor_mps)))
            self._update("gnss_vel", fix.t_ns, fix_v_n, z, H, R)
        if self.align_state == "fine" and self.std_att[2] < cfg.align_heading_std:
            self._set_align_state("aligned", fix.t_ns, "")
        if self._tap is not None and pos_fused:
            self._tap.on_fix(fix.t_ns, self.state, self._dx_since_fix, fix.t_ns >= self._learn_start_t_ns,
                             self.gyro_bias, self.accel_bias, self._prev_dtheta, self._prev_dvel)

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
        self._learn_start_t_ns = max(self._learn_start_t_ns, t_ns + int(LEARN_SETTLE_S * NS))
        log.warning("t=%.3f s: %d GNSS fixes rejected in a row, INS taken as wrong: covariance reset, fix fused",
                    t_ns / NS, self._streak_fixes)

    def _update(self, source: str, t_ns: int, obs: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray,
                gated: bool = True, gain_states: slice | None = None) -> bool:
        gate = self._gate[len(z)] if gated else None
        est = self._adaptive.get(source) if gated else None
        if est is not None:
            R = est.update(z, H @ self.kf.P @ H.T, R)
        self._R_used[source] = R
        res = self.kf.update(z, H, R, gate, gain_states)
        reason = ""
        if res.fused:
            self._feedback(res.dx)
            self._last_dx = res.dx
            self._dx_since_fix += res.dx
            self.counters[f"{source}_fused"] += 1
        else:
            reason = f"{source}_gate"
            self._count_rejection(reason, t_ns, f"test ratio {res.test_ratio:.1f}, innovation {np.round(z, 2)}")
        self._reports.append(
            AidReport(source, t_ns, obs.tolist(), res.innovation.tolist(), np.diag(res.S).tolist(), res.test_ratio,
                      res.fused, reason)
        )
        return res.fused

    def _is_jump(self, t_ns: int, obs: np.ndarray, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> bool:
        """Jump test of a position fix before its update: further than max_jump_m [m] horizontally from the INS
        prediction (innovation z) and outside the chi-square gate of the horizontal innovation with the reported R
        (not the adapted one, so that an inflated R cannot let a jump in). A jump is rejected, kept out of the
        adaptive R estimate, and reported as gnss_pos_jump with its 3-dof test ratio."""
        if self._gate[2] is None or math.hypot(z[0], z[1]) <= self.config.max_jump_m:
            return False
        S = H @ self.kf.P @ H.T + R
        if float(z[:2] @ np.linalg.solve(S[:2, :2], z[:2])) <= self._gate[2]:
            return False
        ratio = float(z @ np.linalg.solve(S, z)) / self._gate[3]
        self._count_rejection("gnss_pos_jump", t_ns, f"test ratio {ratio:.1f}, innovation {np.round(z, 2)}")
        self._reports.append(AidReport("gnss_pos", t_ns, obs.tolist(), z.tolist(), np.diag(S).tolist(), ratio, False,
                                       "gnss_pos_jump"))
        return True

    # ------------------------------------------------------------------ alignment
    def on_attitude(self, t_ns: int, roll: float, pitch: float, std: float) -> bool:
        """Roll and pitch [rad] with their 1-sigma std [rad] from an attitude source (e.g. the zennav.attitude filter)
        at t_ns. Taken only during coarse alignment, when at most as uncertain as the tilt known so far; returns
        whether it was taken."""
        ok = self._coarse and all(map(math.isfinite, (roll, pitch, std))) and 0.0 < std <= self._tilt_std
        if ok and abs(t_ns - self.t_ns) <= MAX_FIX_AGE_S * NS:
            self._set_tilt(roll, pitch, std, "attitude_source")
            return True
        return False

    def _init_alignment(self, initial: InitialState) -> None:
        cfg = self.config
        self._tilt_std = float(max(initial.std_euler[0], initial.std_euler[1]))  # roll/pitch 1-sigma [rad]
        self._tilt_source = "initial_state" if self._tilt_std < cfg.align_tilt_std else "none"
        self._seg = [0.0] * 7  # angle [rad], velocity [m/s] increments and time [s] since the last fix (coarse)
        self._rest = [0.0] * 7  # the same summed over the current rest period
        self._rest_prev = False  # the last fix was at rest
        self._prev_track: tuple | None = None  # (t_ns, llh, std_ned) of the last fix tracked in coarse alignment
        self._gyrocompass_refusal = gyrocompass_refusal(cfg.imu_noise, float(initial.llh[0]), cfg.align_gyrocompass_s,
                                                        cfg.align_max_heading_std)
        self.align_times: dict[str, int] = {}
        self.align_method = "" if self._coarse else "given"
        if self._coarse:
            self._set_align_state("coarse", self.t_ns, self._gyrocompass_refusal or "gyrocompassing possible at rest")
            if self._gyrocompass_refusal:
                self.counters["gyrocompass_refused"] += 1
        else:
            aligned = initial.std_euler[2] < cfg.align_heading_std
            self._set_align_state("aligned" if aligned else "fine", self.t_ns, "heading given")

    def _set_align_state(self, state: str, t_ns: int, detail: str) -> None:
        self.align_state = state
        self.align_times[state] = int(t_ns)
        log.info("alignment %s at t=%.3f s (%s), heading 1-sigma %.2f deg", state, t_ns / NS, detail,
                 math.degrees(math.sqrt(self.kf.P[8, 8])))

    def _set_tilt(self, roll: float, pitch: float, std: float, source: str) -> None:
        """Coarse alignment: replace roll and pitch [rad] (yaw kept) and their 1-sigma [rad]."""
        s = self.state
        yaw = quat_to_euler(s.q_nb)[2]
        s.q0, s.q1, s.q2, s.q3 = (float(x) for x in euler_to_quat([roll, pitch, yaw]))
        if source != self._tilt_source:
            self.counters[f"align_tilt_{source}"] += 1
            log.info("coarse alignment: roll %.2f deg, pitch %.2f deg (1-sigma %.2f deg) from %s", math.degrees(roll),
                     math.degrees(pitch), math.degrees(std), source)
        self._tilt_std, self._tilt_source = float(std), source

    def _advance_coarse(self, t_ns: int, dth: tuple, dv: tuple, dt: float) -> None:
        """Coarse alignment step: the attitude from the gyro (roll and pitch hold; the yaw is unknown), the
        velocity held at the last GNSS velocity and the position dead-reckoned on it; the increments [rad, m/s]
        are summed for levelling and gyrocompassing."""
        s = self.state
        lat, lon, h, vn, ve, vd = s.lat, s.lon, s.h, s.vn, s.ve, s.vd
        mechanize(s, dth, dv, self._prev_dtheta, self._prev_dvel, dt)
        r_m, r_n = earth.radii(lat)
        s.lat, s.lon, s.h = lat + vn * dt / (r_m + h), lon + ve * dt / ((r_n + h) * math.cos(lat)), h - vd * dt
        s.vn, s.ve, s.vd = vn, ve, vd
        self._prev_dtheta, self._prev_dvel = dth, dv
        self.t_ns = t_ns
        self._omega_dt = (dth, dt)
        seg = self._seg
        for i in range(3):
            seg[i] += dth[i]
            seg[3 + i] += dv[i]
        seg[6] += dt

    def _fix_velocity(self, fix: GnssFix, std_pos: np.ndarray):
        """NED velocity [m/s] of the antenna at a fix and its 1-sigma: the reported one (floored), else the
        difference with the last tracked fix when it is at most outage_timeout_s old; (None, None) otherwise."""
        cfg = self.config
        if fix.v_n is not None and cfg.use_gnss_velocity:
            return np.asarray(fix.v_n, dtype=float), np.maximum(fix.std_v_n, cfg.vel_std_floor_mps)
        prev = self._prev_track
        dt = (fix.t_ns - prev[0]) / NS if prev is not None else 0.0
        if not 0.0 < dt <= cfg.outage_timeout_s:
            return None, None
        v = earth.llh_to_ned(np.asarray(fix.llh, dtype=float), prev[1]) / dt
        return v, np.sqrt(prev[2] ** 2 + std_pos**2) / dt

    def _coarse_fix(self, fix: GnssFix, z: np.ndarray, omega_ib_b: np.ndarray) -> None:
        """Coarse alignment at a fix (z: INS antenna minus fix [m, NED]): reject a jump from the dead-reckoned
        position, track the fix, level and gyrocompass at rest, or align in motion once fast enough."""
        cfg = self.config
        t = fix.t_ns
        fix_llh = np.asarray(fix.llh, dtype=float)
        if (self._prev_track is not None and math.hypot(z[0], z[1]) > cfg.max_jump_m
                and self._streak_fixes < cfg.reacquire_fixes):
            self._streak_fixes += 1
            self._count_rejection("gnss_pos_jump", t, f"coarse alignment, {math.hypot(z[0], z[1]):.1f} m from the "
                                  "dead-reckoned position")
            self._reports.append(AidReport("gnss_pos", t, fix_llh.tolist(), z.tolist(), [], float("nan"), False,
                                           "gnss_pos_jump"))
            return
        self._streak_fixes = 0
        std_pos = np.maximum(fix.std_ned, cfg.pos_std_floor_m)
        v, std_v = self._fix_velocity(fix, std_pos)
        seg, rest = self._seg, self._rest
        self._tilt_std += cfg.imu_noise.gyro_bias_std * seg[6]  # roll/pitch drift on the gyro since the last fix
        still = v is not None and math.hypot(v[0], v[1]) <= cfg.align_still_speed_mps + 3.0 * max(std_v[0], std_v[1])
        if still and self._rest_prev:
            self._rest = rest = [a + b for a, b in zip(rest, seg)]
        elif not still:
            self._rest = rest = [0.0] * 7
        self._rest_prev, self._seg = still, [0.0] * 7
        self._track(fix, omega_ib_b, v, std_pos, std_v)
        self._prev_track = (t, fix_llh, std_pos)
        if self.gnss_state != "valid":
            self.counters["outage_recovered"] += 1
        self.gnss_state, self.last_fused_t_ns = "valid", t
        rest_s = rest[6]
        if rest_s >= cfg.align_level_s:
            f_b = np.array(rest[3:6]) / rest_s
            if levelling_std(cfg.imu_noise, rest_s) <= self._tilt_std:
                self._set_tilt(*level(f_b), levelling_std(cfg.imu_noise, rest_s), "levelling")
            if rest_s >= cfg.align_gyrocompass_s and not self._gyrocompass_refusal:
                al = static_alignment(f_b, np.array(rest[0:3]) / rest_s, self.state.lat, rest_s, cfg.imu_noise,
                                      cfg.align_max_heading_std)
                self._start_fine(al.euler, al.std_euler, "gyrocompass", fix, omega_ib_b, v, std_pos, std_v)
                return
        fast = v is not None and math.hypot(v[0], v[1]) >= cfg.align_min_speed_mps
        euler, std_euler = (course_alignment(v, std_v, cfg.align_course_std, cfg.align_tilt_std) if fast
                            else (None, None))
        if fast and std_euler[2] <= cfg.align_max_heading_std:
            if self._tilt_std < cfg.align_tilt_std:  # a better roll and pitch than 0 and the climb angle
                euler[:2] = quat_to_euler(self.state.q_nb)[:2]
                std_euler[:2] = self._tilt_std
            else:
                self._tilt_source = "climb_angle"
            self._start_fine(euler, std_euler, "in_motion", fix, omega_ib_b, v, std_pos, std_v)
            return
        self.counters["gnss_align_coarse"] += 1
        self._reports.append(AidReport("gnss_pos", t, fix_llh.tolist(), z.tolist(), [], float("nan"), False,
                                       "align_coarse"))

    def _track(self, fix: GnssFix, omega_ib_b: np.ndarray, v_ant_n, std_pos: np.ndarray, std_v) -> None:
        """Coarse alignment: put the antenna at the fix and, when given, its velocity at v_ant_n [m/s]; their
        variances become those of the fix (std_pos [m], std_v [m/s])."""
        P = self.kf.P
        P[0:6, :] = 0.0
        P[:, 0:6] = 0.0
        P[POS, POS] = np.diag(np.square(std_pos))
        P[VEL, VEL] = np.diag(np.square(std_v if std_v is not None else self._initial.std_v_n))
        age = (self.t_ns - fix.t_ns) / NS
        v_ins_ant = antenna_velocity(self.state, self._lever_b, omega_ib_b)
        z, _ = position_model(self.state, self._lever_b, np.asarray(fix.llh, dtype=float), v_ins_ant, age)
        dx = np.zeros(N_STATES)
        dx[POS] = z
        if v_ant_n is not None:
            dx[VEL] = v_ins_ant - v_ant_n
        self._feedback(dx)

    def _start_fine(self, euler, std_euler, method: str, fix: GnssFix, omega_ib_b, v_ant_n, std_pos, std_v) -> None:
        """End of coarse alignment: attitude euler [rad] with 1-sigma std_euler [rad], position and velocity at the
        fix, and a fresh covariance from these 1-sigma values (the bias uncertainty of the initial state)."""
        s = self.state
        s.q0, s.q1, s.q2, s.q3 = (float(x) for x in euler_to_quat(euler))
        self._track(fix, omega_ib_b, v_ant_n, std_pos, std_v)
        start = replace(self._initial, t_ns=fix.t_ns, llh=s.llh, v_n=s.v_n, euler=np.asarray(euler, dtype=float),
                        std_pos_ned=std_pos, std_v_n=self._initial.std_v_n if std_v is None else std_v,
                        std_euler=np.asarray(std_euler, dtype=float), heading_known=True)
        self.kf.P = initial_covariance(start, self.config)
        self._coarse = False
        self._cov_dt, self._cov_dvel = 0.0, [0.0, 0.0, 0.0]
        self._learn_start_t_ns = max(self._learn_start_t_ns, fix.t_ns + int(LEARN_SETTLE_S * NS))
        self._update_stds()
        self.align_method = method
        self.counters[f"align_{method}"] += 1
        self._set_align_state("fine", fix.t_ns, f"{method}: roll, pitch, yaw {np.round(np.degrees(euler), 2)} deg")
        self._reports.append(AidReport("gnss_pos", fix.t_ns, np.asarray(fix.llh, dtype=float).tolist(), [], [],
                                       float("nan"), False, f"align_{method}"))

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
