"""Coarse alignment of the strapdown INS: static levelling and gyrocompassing, and in-motion yaw and pitch
from the GNSS velocity (seed 002) or its changes. Frames: n = NED, b = FRD, Euler ZYX (roll, pitch, yaw) [rad],
SI units.

Static (Groves 2013, "Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems", 2nd ed.,
section 5.6.2; section 14.4.1 for the error budget). At rest f_b = C_bn (0, 0, -g) and
omega_ib_b = C_bn omega_ie_n with omega_ie_n = Omega (cos L, 0, -sin L):
- levelling (eq. 5.101): roll = atan2(-f_y, -f_z), pitch = atan(f_x / sqrt(f_y^2 + f_z^2));
  1-sigma from the accelerometer bias and white noise: sqrt(b_a^2 + vrw^2 / T) / g;
- gyrocompassing (eq. 5.103): the gyro levelled by roll and pitch measures Omega cos L (cos yaw, -sin yaw), so
  sin yaw = -w_y cos roll + w_z sin roll, cos yaw = w_x cos pitch + (w_y sin roll + w_z cos roll) sin pitch;
  1-sigma sqrt(b_g^2 + arw^2 / T) / (Omega cos L) from the gyro, plus tan L times the levelling error. It needs
  a gyro whose bias is well below the horizontal earth rate (about 15 cos L deg/h): refused otherwise.
The engine's alignment state machine (class Alignment): 'coarse' while the heading is unknown, then 'fine' from
the fix that starts the filter, 'aligned' once the heading 1-sigma is below align_heading_std.
A configured initial state (heading given) is tested against the first GNSS fixes before the filter trusts it
(Alignment.check_initial): the normalised innovation squared (NIS) of the first fix's position, with S = H P H' + R
from the configured 1-sigma (propagated to the fix) and the fix's own, and of the antenna velocity (the fix's
velocity, else the displacement between two fixes against the INS's over the same interval), each against the
chi-square quantile of the engine's gate (gate_probability) on 3 degrees of freedom (the NIS test of Bar-Shalom, Li &
Kirubarajan 2001, "Estimation with applications to tracking and navigation", sec. 5.4; Groves 2013 section 17.3.1,
innovation-based outlier detection, applied to the initial state rather than the fix). Two fixes in a row must fail
(one outlier fix is left to the gate). The fixes see position and velocity directly but the attitude only through
the velocity it integrates: a heading error psi turns a change dv of the horizontal velocity into a velocity error of
about |dv| psi (Groves 2013 section 14.4.2: heading is observable under horizontal acceleration only). So the state
is rejected in two stages, the attitude last:
1. A state never consistent with the fixes (a file's start cut without moving its initial state) has its position
   and velocity reset from the second failing fix (position at the fix with its 1-sigma; velocity the fix's, else the
   displacement from the fix before over their interval with its 1-sigma, as in the coarse alignment's tracking),
   decorrelated from the rest; the attitude, the biases and their covariance are kept. Counted
   init_state_reset_pos_vel and logged.
2. Once position and velocity are consistent with the fixes, what a failing pair contradicts is the attitude. A
   state consistent at rest is tested again at the first fixes in motion (horizontal speed of the fixes at least
   align_min_speed_mps); after the reset every fix is tested. A wrong heading shows there as a velocity (then
   position) innovation once the velocity changes. The state is accepted at a passing pair once the velocity has
   changed by align_min_speed_mps (at rest: moving; after the reset: the engine's horizontal velocity, fused with the
   fixes since, against its value once known to a third of that). A failing pair discards the state, counted
   init_state_rejected and logged: the engine goes back to coarse alignment from the fixes with position, velocity
   and attitude unknown, as if no initial state had been configured (the biases and their 1-sigma are kept). A
   heading given wrong at rest is rejected this way; so is a stale state whose heading the vehicle left.
A state that passes changes nothing.
In motion (seed 002 step S3-1; Groves 2013 section 14.4.2): with the GNSS velocity v_n of a vehicle whose
body x axis moves along its velocity (land vehicles, fixed-wing aircraft): yaw = atan2(v_E, v_N) and
pitch = atan2(-v_D, sqrt(v_N^2 + v_E^2)) (the climb angle); roll 0 with a large variance for ground vehicles.
The yaw 1-sigma is the velocity noise across the track over the speed plus a course allowance (sideslip,
yaw mounting); the climb-angle pitch likewise with a tilt allowance (suspension, pitch mounting).
A vehicle that does not move along its x axis (a multirotor flies sideways and backwards) aligns instead by its
accelerations (align_in_motion: acceleration; Groves 2013 section 14.4.2): between two fixes the IMU's horizontal
velocity change, integrated in the engine's frame of unknown yaw with the known roll and pitch, is the GNSS's rotated
by the unknown yaw offset; its least-squares value over every pair of fixes since the start
(heading_from_vector_pairs) and its 1-sigma hand over once that is below align_max_heading_std. align_in_motion
auto takes the course once the velocity changes confirm it and theirs where they refute it (it waits for them: a car
joining at a steady speed aligns later than by its course).
A vehicle with a body-velocity sensor (a DVL: an AUV crabs in the current, its course is not its heading) aligns by
that velocity (align_in_motion: dvl): the DVL's velocity at the IMU, v_b, rotated by the engine's attitude of unknown
yaw and carried to the fix's time with the IMU's velocity change since, is the GNSS velocity rotated by the yaw
offset; the same least squares over every (DVL, fix) pair (heading_from_vector_pairs). Where no DVL velocity came in
the last DVL_RECENT_S (no bottom lock at the surface, no DVL) it falls back to the course.
Rest, for levelling and gyrocompassing, is a GNSS speed that reads rest and a body that did not turn since the last
fix (turned): a vehicle tilts as it starts to move while its speed still reads rest.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from . import earth
from .aiding import antenna_velocity, position_model, velocity_model
from .eskf import N_STATES, POS, VEL, initial_covariance
from .rotation import euler_to_quat, quat_to_euler
from .types import NS, AlignState, GnssFix, ImuNoise, InitialState, NavConfig

log = logging.getLogger("zennav.nav")


def level(f_b_mean) -> tuple[float, float]:
    """Roll and pitch [rad] from the mean specific force at rest f_b_mean [m/s^2, body]."""
    fx, fy, fz = (float(x) for x in f_b_mean)
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def levelling_std(noise: ImuNoise, duration_s: float, g: float = earth.G0) -> float:
    """1-sigma [rad] of levelled roll and pitch over duration_s [s] of rest: accelerometer bias and noise over g."""
    return math.sqrt(noise.accel_bias_std**2 + noise.vrw**2 / duration_s) / g


def gyrocompass(omega_b_mean, roll: float, pitch: float) -> float:
    """Yaw [rad] from the mean angular rate at rest omega_b_mean [rad/s, body] and the levelled roll, pitch [rad]."""
    wx, wy, wz = (float(x) for x in omega_b_mean)
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    return math.atan2(-wy * cr + wz * sr, wx * cp + (wy * sr + wz * cr) * sp)


def gyrocompass_std(noise: ImuNoise, lat: float, duration_s: float) -> float:
    """Predicted yaw 1-sigma [rad] of gyrocompassing over duration_s [s] at rest at latitude lat [rad]: gyro bias
    and angle random walk over the horizontal earth rate, plus tan(L) times the levelling error."""
    horizontal_rate = earth.OMEGA_IE * math.cos(lat)
    gyro = math.sqrt(noise.gyro_bias_std**2 + noise.arw**2 / duration_s) / horizontal_rate
    return math.hypot(gyro, math.tan(lat) * levelling_std(noise, duration_s))


def gyrocompass_refusal(noise: ImuNoise, lat: float, duration_s: float, max_yaw_std: float) -> str:
    """Why gyrocompassing over duration_s [s] at latitude lat [rad] is refused for this IMU (noise: the configured
    model), or "" when its predicted yaw 1-sigma is at most max_yaw_std [rad]."""
    yaw_std = gyrocompass_std(noise, lat, duration_s)
    if yaw_std <= max_yaw_std:
        return ""
    return (f"gyrocompassing refused: predicted heading 1-sigma {math.degrees(yaw_std):.1f} deg > "
            f"{math.degrees(max_yaw_std):.1f} deg (gyro bias {math.degrees(noise.gyro_bias_std) * 3600:.2f} deg/h, "
            f"ARW {math.degrees(noise.arw) * 60:.3f} deg/sqrt(h) over {duration_s:.0f} s vs horizontal earth rate "
            f"{math.degrees(earth.OMEGA_IE * math.cos(lat)) * 3600:.2f} deg/h at latitude {math.degrees(lat):.1f} deg)")


@dataclass
class StaticAlignment:
    """Result of a static coarse alignment: euler [rad] (yaw NaN when refused), its 1-sigma [rad] (yaw inf when
    refused) and a one-line message saying what was done or why gyrocompassing was refused."""

    euler: np.ndarray
    std_euler: np.ndarray
    gyrocompassed: bool
    message: str


def static_alignment(f_b_mean, omega_b_mean, lat: float, duration_s: float, noise: ImuNoise,
                     max_yaw_std: float) -> StaticAlignment:
    """Levelling, then gyrocompassing when its predicted yaw 1-sigma is at most max_yaw_std [rad] for this gyro
    (noise: the configured IMU model) at latitude lat [rad] after duration_s [s] at rest."""
    roll, pitch = level(f_b_mean)
    tilt_std = levelling_std(noise, duration_s)
    refusal = gyrocompass_refusal(noise, lat, duration_s, max_yaw_std)
    if refusal:
        return StaticAlignment(np.array([roll, pitch, math.nan]), np.array([tilt_std, tilt_std, math.inf]), False,
                               refusal)
    yaw = gyrocompass(omega_b_mean, roll, pitch)
    yaw_std = gyrocompass_std(noise, lat, duration_s)
    msg = (f"gyrocompassed over {duration_s:.0f} s: yaw {math.degrees(yaw):.2f} deg, 1-sigma "
           f"{math.degrees(yaw_std):.2f} deg")
    return StaticAlignment(np.array([roll, pitch, yaw]), np.array([tilt_std, tilt_std, yaw_std]), True, msg)


def course_alignment(v_n, std_v_n, course_std: float, tilt_std: float) -> tuple[np.ndarray, np.ndarray]:
    """In-motion coarse attitude from the NED velocity v_n [m/s] with 1-sigma std_v_n [m/s]: (euler, std_euler)
    [rad] with roll 0, pitch the climb angle, yaw the course; course_std and tilt_std [rad] are the allowances
    for heading minus course and for roll / pitch minus climb angle (see the module docstring)."""
    vn, ve, vd = (float(x) for x in v_n)
    sn, se, sd = (float(x) for x in std_v_n)
    speed_h = math.hypot(vn, ve)
    yaw = math.atan2(ve, vn)
    pitch = math.atan2(-vd, speed_h)
    across2 = (sn * math.sin(yaw)) ** 2 + (se * math.cos(yaw)) ** 2  # velocity variance across the track
    yaw_std = math.sqrt(across2 / speed_h**2 + course_std**2)
    pitch_std = math.sqrt(sd**2 / speed_h**2 + tilt_std**2)
    return np.array([0.0, pitch, yaw]), np.array([tilt_std, pitch_std, yaw_std])


STILL_RATE = math.radians(0.1)  # rad/s: the net rotation a vehicle at rest may show between two fixes (rocking)


def turned(seg, noise: ImuNoise) -> bool:
    """Whether the body rotated between two fixes: the summed angle increments seg[0:3] [rad] over seg[6] [s] beyond
    STILL_RATE plus three times what the gyro's bias, its angle random walk and the earth rate give at rest. A
    vehicle that starts to move tilts (a multirotor to accelerate, a car on its suspension) while its GNSS speed
    still reads rest: its increments would spoil levelling and gyrocompassing (a 2 deg tilt taken as rest)."""
    dt = seg[6]
    at_rest = STILL_RATE * dt + 3.0 * (noise.gyro_bias_std * dt + noise.arw * math.sqrt(dt) + earth.OMEGA_IE * dt)
    return math.sqrt(seg[0] ** 2 + seg[1] ** 2 + seg[2] ** 2) > at_rest


AUTO_CONFIRM_STD = math.radians(30.0)  # align_in_motion auto: the velocity changes' 1-sigma that can confirm a course
ACCEL_MIN_PAIRS = 10  # pairs before the acceleration and dvl methods trust their own residuals for their 1-sigma
DVL_RECENT_S = 3.0  # align_in_motion dvl: a DVL velocity at most this old [s] pairs with a fix (none: the course)


def add_vector_pair(sums: list, a, b, var: float) -> None:
    """Add one pair of horizontal vectors (a in the engine's frame of unknown yaw, b the GNSS's) [m/s, N, E], the
    variance var [(m/s)^2] of b - R a per axis, to the sums of heading_from_vector_pairs."""
    sums[0] += (a[0] * b[0] + a[1] * b[1]) / var
    sums[1] += (a[0] * b[1] - a[1] * b[0]) / var
    sums[2] += (a[0] ** 2 + a[1] ** 2) / var
    sums[3] += (b[0] ** 2 + b[1] ** 2) / var
    sums[4] += 1.0


def heading_from_vector_pairs(sums) -> tuple[float, float]:
    """(psi, 1-sigma) [rad]: the yaw rotation that best takes horizontal vectors a of the IMU (integrated in a frame of
    unknown yaw: velocity changes between fixes, or a DVL's velocity) onto the GNSS's b (the same quantity at the
    fixes), from sums = (sum w a.b, sum w a x b, sum w |a|^2, sum w |b|^2, n pairs) (add_vector_pair) with weights w
    the inverse variance of b - R a per axis. The 2-D orthogonal
    Procrustes (Wahba) solution psi = atan2(sum w a x b, sum w a.b); its 1-sigma the inverse square root of the
    Fisher information sum w |a|^2 times the a-posteriori variance factor s0^2 = RSS / (2 n - 1) of the weighted
    residuals (RSS = sum w |b|^2 + sum w |a|^2 - 2 sqrt(dot^2 + cross^2)): the weights' variances come from the
    reported 1-sigma, which a receiver or a position difference may over- or understate; below ACCEL_MIN_PAIRS
    pairs s0^2 only inflates. (Wahba 1965, SIAM Review 7(3) p. 409; the variance factor: Koch 1999, "Parameter
    Estimation and Hypothesis Testing in Linear Models", sec. 3.2.3; in-motion heading from the GNSS and IMU
    accelerations for a vehicle not moving along its x axis: Groves 2013 section 14.4.2.) inf before any change."""
    dot, cross, info, bb, n = (float(x) for x in sums[:5])
    if info <= 0.0 or n < 1:
        return math.atan2(cross, dot), math.inf
    rss = max(bb + info - 2.0 * math.hypot(dot, cross), 0.0)
    s02 = rss / max(2.0 * n - 1.0, 1.0)
    s02 = s02 if n >= ACCEL_MIN_PAIRS else max(s02, 1.0)
    return math.atan2(cross, dot), math.sqrt(s02 / info)


UNKNOWN_ANGLE_STD = math.pi / math.sqrt(3.0)  # 1-sigma [rad] of an angle uniform in +-180 deg
AT_REST = "consistent at rest (tested again once moving)"  # Alignment.initial_check of a state so far
RESET = "position and velocity reset from the fixes (attitude under test)"  # likewise


def coarse_initial(initial: InitialState) -> InitialState:
    """The engine's start state for coarse alignment: yaw 0 as a placeholder with the 1-sigma of an unknown angle; so
    for an unknown (non-finite) roll or pitch, which in-motion alignment then takes as 0 / the climb angle."""
    known = [math.isfinite(float(a)) for a in initial.euler[:2]]
    euler = [float(a) if k else 0.0 for a, k in zip(initial.euler[:2], known)] + [0.0]
    std = [float(e) if k else UNKNOWN_ANGLE_STD for e, k in zip(initial.std_euler[:2], known)]
    return replace(initial, euler=np.array(euler), std_euler=np.array(std + [UNKNOWN_ANGLE_STD]))


class Alignment:
    """Coarse alignment of the engine and the alignment state machine (see the module docstring). With the
    heading unknown the engine is ``coarse``: it integrates the attitude only, holds the last GNSS velocity and
    dead-reckons on it (Navigator._advance_coarse), and hands every GNSS fix to ``on_fix``, which tracks it, levels
    and gyrocompasses at rest, or starts the filter in motion ('fine').

    initial: the engine's initial state (yaw 0 placeholder when coarse); tilt_std: roll/pitch 1-sigma [rad] and
    tilt_source where it came from; seg / rest: angle [rad], velocity [m/s] increments and time [s] since the last
    fix / summed over the current rest; prev_track: (t_ns, llh, std_ned) of the last tracked fix; times: data time
    [ns] each state was entered. checking: a configured initial state is under test (check_initial); check_prev:
    (t_ns, llh, std_ned, residual after its update [m, NED] or None when not fused) of the last fix under test;
    check_strike: why that fix failed the test ("" passed); check_v_ref: after the reset, the engine's horizontal
    velocity [m/s, NE] the velocity change is measured from (None until known); initial_check: what the test found
    ("" while untested or without a configured state, AT_REST, RESET, "accepted", or "rejected: " and why)."""

    def __init__(self, config: NavConfig, initial: InitialState, coarse: bool):
        self.config = config
        self.initial = initial
        self.coarse = coarse
        self.tilt_std = float(max(initial.std_euler[0], initial.std_euler[1]))
        self.tilt_source = "initial_state" if self.tilt_std < config.align_tilt_std else "none"
        self.seg = [0.0] * 7
        self.rest = [0.0] * 7
        self.rest_prev = False  # the last fix was at rest
        self.prev_track: tuple | None = None
        self.speed_max = 0.0  # fastest horizontal GNSS speed [m/s] seen while coarse
        self.start_heading = math.nan  # the heading [rad] a coarse alignment handed to the filter, and its 1-sigma
        self.start_heading_std = math.nan  # [rad]
        # (a diagnostic of this process's run: not in get_state, a resumed engine reports nan)
        self.dv_p = [0.0, 0.0]  # the IMU's horizontal velocity change since the last fix [m/s, N, E of the yaw-0 frame]
        self.accel_prev: tuple | None = None  # (v_N, v_E, 1-sigma) [m/s] of the last fix with a velocity
        self.accel_sums = [0.0, 0.0, 0.0, 0.0, 0.0]  # weighted a.b, a x b, |a|^2, |b|^2 and the count of pairs
        # a DVL velocity since the last fix, not yet paired: (t_ns, v_N, v_E, variance, dv_p N, E then)
        self.dvl_last: tuple | None = None
        self.dvl_seen_ns: int | None = None  # data time of the last DVL velocity while coarse [ns]
        self.dvl_sums = [0.0, 0.0, 0.0, 0.0, 0.0]  # as accel_sums, of the (DVL, fix) pairs
        self.gyrocompass_refusal = gyrocompass_refusal(config.imu_noise, float(initial.llh[0]),
                                                       config.align_gyrocompass_s, config.align_max_heading_std)
        self.times: dict[str, int] = {}
        self.method = "" if coarse else "given"
        self.state = AlignState.COARSE
        self.checking = not coarse and config.gate_probability > 0.0
        self.check_prev: tuple | None = None
        self.check_strike = ""
        self.check_v_ref: tuple[float, float] | None = None
        self.initial_check = ""

    def start(self, nav) -> None:
        """Enter the first state at the engine's start time."""
        cfg = self.config
        if self.coarse:
            self._set_state(nav, AlignState.COARSE, nav.t_ns,
                            self.gyrocompass_refusal or "gyrocompassing possible at rest")
            if self.gyrocompass_refusal:
                nav.counters["gyrocompass_refused"] += 1
        else:
            aligned = self.initial.std_euler[2] < cfg.align_heading_std
            self._set_state(nav, AlignState.ALIGNED if aligned else AlignState.FINE, nav.t_ns, "heading given")

    def _set_state(self, nav, state: AlignState, t_ns: int, detail: str) -> None:
        self.state = state
        self.times[str(state)] = int(t_ns)
        log.info("alignment %s at t=%.3f s (%s), heading 1-sigma %.2f deg", state, t_ns / NS, detail,
                 math.degrees(math.sqrt(nav.P[8, 8])))

    def check_initial(self, nav, ctx, z: np.ndarray, H: np.ndarray, R: np.ndarray) -> str:
        """Test the configured initial state at a fix (ctx: zennav.nav.aid.FixContext; z, H, R: the fix's position
        innovation [m, NED], its H and R) before its update (see the module docstring). A failed test is a strike (the
        fix goes on to the normal gate); a second in a row, the fixes at most outage_timeout_s apart, resets position
        and velocity from the fix (returns "reset": the fix is used, not to be fused) or, once they were consistent
        (at rest, or reset), discards the state (returns "rejected": the engine is coarse again and the fix is for
        the coarse alignment). Returns "" otherwise."""
        fix, k, prev, cfg = ctx.fix, H.shape[1], self.check_prev, self.config
        dt = math.inf if prev is None else (fix.t_ns - prev[0]) / NS
        pair = 0.0 < dt <= cfg.outage_timeout_s  # the fix before was under test too, not long before
        vel = self._check_velocity(nav, ctx, z, R, prev if pair else None)
        v_fix = None if vel is None else vel[0]
        if self.initial_check == RESET:
            moving = self._velocity_changed(nav)
        else:
            moving = v_fix is not None and math.hypot(v_fix[0], v_fix[1]) >= cfg.align_min_speed_mps
        if self.initial_check == AT_REST and not moving:  # nothing new to test until it moves
            self.check_strike = ""
            return ""
        thr = nav.gate_threshold(3)
        nis = float(z @ np.linalg.solve(H @ nav.P[:k, :k] @ H.T + R, z))
        nis_v = math.nan if vel is None else float(vel[1] @ np.linalg.solve(vel[2], vel[1]))
        fail = ""
        if nis > thr:
            fail = f"position NIS {nis:.1f} > {thr:.1f}, innovation {np.round(z, 2)} m"
        elif nis_v > thr:
            fail = f"velocity NIS {nis_v:.1f} > {thr:.1f}, innovation {np.round(vel[1], 2)} m/s"
        if fail and self.check_strike and pair:
            detail = f"{self.check_strike}; then {fail}"
            if self.initial_check in (AT_REST, RESET):
                return self._reject_initial(nav, ctx, detail)
            assert prev is not None  # a pair
            return self._reset_position_velocity(nav, ctx, detail, prev)
        self.check_strike = fail
        if not fail and vel is not None:
            if moving:
                self.checking, self.check_prev, self.initial_check = False, None, "accepted"
                log.info("t=%.3f s: configured initial state accepted (position NIS %.2f, velocity NIS %.2f)",
                         fix.t_ns / NS, nis, nis_v)
            elif self.initial_check != RESET:
                self.initial_check = AT_REST
        return ""

    def _velocity_changed(self, nav) -> bool:
        """After the reset: whether the engine's horizontal velocity has changed by align_min_speed_mps since
        check_v_ref, its velocity once known to a third of that (1-sigma; the reset's own velocity may be a noisy
        displacement over one fix interval); sets check_v_ref then."""
        cfg, s = self.config, nav.state
        if self.check_v_ref is None:
            if max(nav.P[3, 3], nav.P[4, 4]) <= (cfg.align_min_speed_mps / 3.0) ** 2:
                self.check_v_ref = (float(s.vn), float(s.ve))
            return False
        return math.hypot(s.vn - self.check_v_ref[0], s.ve - self.check_v_ref[1]) >= cfg.align_min_speed_mps

    def _check_velocity(self, nav, ctx, z: np.ndarray, R: np.ndarray, prev: tuple | None):
        """(v_fix, z_v, S_v): the antenna velocity of the fixes [m/s, NED], the INS's minus it and its covariance, from
        the fix's velocity, else from the displacement since prev (the fix before, (t_ns, llh, std_ned, residual)
        or None) against the INS's since its update; None when neither is there."""
        cfg, fix = self.config, ctx.fix
        if fix.v_n is not None and cfg.use_gnss_velocity:
            assert fix.std_v_n is not None  # the input check rejects a velocity without its std (gnss_malformed)
            v_fix = np.asarray(fix.v_n, dtype=float)
            z_v, H_v = velocity_model(nav.state, nav.lever_b, ctx.omega_ib_b, v_fix)
            R_v = np.diag(np.square(np.maximum(fix.std_v_n, cfg.vel_std_floor_mps)))
            return v_fix, z_v, H_v @ nav.P[:N_STATES, :N_STATES] @ H_v.T + R_v
        if prev is None or prev[3] is None:
            return None
        dt = (fix.t_ns - prev[0]) / NS
        v_fix = earth.llh_to_ned(np.asarray(fix.llh, dtype=float), prev[1]) / dt
        return v_fix, (z - prev[3]) / dt, nav.P[VEL, VEL] + np.diag(np.diag(R) + prev[2] ** 2) / dt**2

    def check_fused(self, nav, ctx, std_pos: np.ndarray, fused: bool) -> None:
        """After the update of a fix under test (std_pos: its floored 1-sigma [m, NED]): the fix and, when fused, its
        residual [m, NED] for the velocity test at the next fix."""
        fix = ctx.fix
        llh = np.asarray(fix.llh, dtype=float)
        residual = None
        if fused:
            v_ant_n = antenna_velocity(nav.state, nav.lever_b, ctx.omega_ib_b)
            residual = position_model(nav.state, nav.lever_b, llh, v_ant_n, ctx.age_s)[0]
        self.check_prev = (int(fix.t_ns), llh, np.asarray(std_pos, dtype=float), residual)

    def _reset_position_velocity(self, nav, ctx, detail: str, prev: tuple) -> str:
        """Stage 1 (see the module docstring): two fixes in a row (prev: the one before) contradict a state never
        consistent with them: position and velocity from the fixes, attitude and biases kept; the attitude stays under
        test at the fixes that follow."""
        fix, cfg = ctx.fix, self.config
        nav.counters["init_state_reset_pos_vel"] += 1
        self.initial_check = RESET
        std_pos = np.maximum(fix.std_ned, cfg.pos_std_floor_m)
        v, std_v = self._fix_velocity(fix, std_pos, prev[:3])
        self._track(nav, fix, ctx.omega_ib_b, v, std_pos, std_v)
        nav.hold_learning(fix.t_ns)
        self.check_strike, self.check_v_ref = "", None
        log.warning("t=%.3f s: configured initial position and velocity reset, the first GNSS fixes contradict them "
                    "(%s); attitude kept, tested at the next fixes", fix.t_ns / NS, detail)
        return "reset"

    def _reject_initial(self, nav, ctx, detail: str) -> str:
        """Two fixes in a row contradict the configured initial state once consistent: discard it (position, velocity,
        attitude) and go back to coarse alignment from the fixes, from this one on."""
        t_ns = ctx.fix.t_ns
        nav.counters["init_state_rejected"] += 1
        self.initial_check = f"rejected: {detail}"
        log.warning("t=%.3f s: configured initial state rejected, the first GNSS fixes contradict it (%s): coarse "
                    "alignment from the fixes", t_ns / NS, detail)
        s = nav.state
        start = coarse_initial(replace(self.initial, euler=np.full(3, math.nan)))
        s.vn, s.ve, s.vd = 0.0, 0.0, 0.0
        s.q0, s.q1, s.q2, s.q3 = (float(x) for x in euler_to_quat(start.euler))
        nav.start_filter(initial_covariance(start, self.config), t_ns)
        self.coarse, self.checking, self.check_prev, self.method = True, False, None, ""
        self.prev_track = None  # the coarse jump test has no dead-reckoned position to hold the fix against
        self.tilt_std, self.tilt_source = UNKNOWN_ANGLE_STD, "none"
        self.seg, self.rest, self.rest_prev = [0.0] * 7, [0.0] * 7, False
        self._set_state(nav, AlignState.COARSE, t_ns, "initial state rejected")
        ctx.coarse = True
        return "rejected"

    def monitored(self) -> bool:
        """Whether the sources' consistency monitors run: once aligned, and in fine alignment after a coarse one. While
        a given heading converges its steady innovations are its error; after a coarse alignment the whole attitude
        (climb-angle pitch, roll 0) converges with the fixes, and a filter overconfident then traps and resets."""
        return self.state == AlignState.ALIGNED or (self.state == AlignState.FINE and self.method != "given")

    def check_aligned(self, nav, t_ns: int) -> None:
        """'fine' -> 'aligned' once the heading 1-sigma is below align_heading_std (at a fused fix)."""
        if self.state == AlignState.FINE and nav.std_att[2] < self.config.align_heading_std:
            self._set_state(nav, AlignState.ALIGNED, t_ns, "")

    def add(self, dtheta, dvel, dt: float, dv_n: float, dv_e: float) -> None:
        """Coarse: sum the bias-corrected increments [rad, m/s] over dt [s] for levelling and gyrocompassing, and the
        horizontal velocity change they integrate to in the engine's frame (yaw unknown) [m/s, N, E]."""
        seg = self.seg
        for i in range(3):
            seg[i] += dtheta[i]
            seg[3 + i] += dvel[i]
        seg[6] += dt
        self.dv_p[0] += dv_n
        self.dv_p[1] += dv_e

    def on_body_velocity(self, nav, t_ns: int, v_b, var: float) -> None:
        """Coarse, align_in_motion dvl: a DVL's velocity of the IMU v_b [m/s, body] of the sample at t_ns (the engine
        at most dvl_max_age_s later) with variance var [(m/s)^2] per horizontal axis, kept in the engine's yaw-0 frame
        for the next fix (_dvl_pair)."""
        if not self.coarse or self.config.align_in_motion != "dvl":
            return
        v_e = nav.state.C_nb @ np.asarray(v_b, dtype=float)
        var_e = var + (self._tilt() * float(v_e[2])) ** 2  # a tilt error turns the vertical velocity horizontal
        self.dvl_last = (int(t_ns), float(v_e[0]), float(v_e[1]), var_e, *self.dv_p)
        self.dvl_seen_ns = int(t_ns)

    def on_attitude(self, nav, t_ns: int, roll: float, pitch: float, std: float, max_age_s: float) -> bool:
        """Roll and pitch [rad] with 1-sigma std [rad] from an attitude source at t_ns: taken only while coarse,
        when at most as uncertain as the tilt known so far and at most max_age_s from the engine's time."""
        ok = self.coarse and all(map(math.isfinite, (roll, pitch, std))) and 0.0 < std <= self.tilt_std
        if ok and abs(t_ns - nav.t_ns) <= max_age_s * NS:
            self.set_tilt(nav, roll, pitch, std, "attitude_source")
            return True
        return False

    def set_tilt(self, nav, roll: float, pitch: float, std: float, source: str) -> None:
        """Coarse alignment: replace roll and pitch [rad] (yaw kept) and their 1-sigma [rad]."""
        s = nav.state
        yaw = quat_to_euler(s.q_nb)[2]
        s.q0, s.q1, s.q2, s.q3 = (float(x) for x in euler_to_quat([roll, pitch, yaw]))
        if source != self.tilt_source:
            nav.counters[f"align_tilt_{source}"] += 1
            log.info("coarse alignment: roll %.2f deg, pitch %.2f deg (1-sigma %.2f deg) from %s", math.degrees(roll),
                     math.degrees(pitch), math.degrees(std), source)
        self.tilt_std, self.tilt_source = float(std), source

    def _fix_velocity(self, fix: GnssFix, std_pos: np.ndarray, prev: tuple | None):
        """NED velocity [m/s] of the antenna at a fix and its 1-sigma: the reported one (floored), else the
        difference with the fix before, prev = (t_ns, llh, std_pos), when it is at most outage_timeout_s old;
        (None, None) otherwise."""
        cfg = self.config
        if fix.v_n is not None and cfg.use_gnss_velocity:
            assert fix.std_v_n is not None  # the input check rejects a velocity without its std (gnss_malformed)
            return np.asarray(fix.v_n, dtype=float), np.maximum(fix.std_v_n, cfg.vel_std_floor_mps)
        if prev is None:
            return None, None
        dt = (fix.t_ns - prev[0]) / NS
        if not 0.0 < dt <= cfg.outage_timeout_s:
            return None, None
        v = earth.llh_to_ned(np.asarray(fix.llh, dtype=float), prev[1]) / dt
        return v, np.sqrt(prev[2] ** 2 + std_pos**2) / dt

    def on_fix(self, nav, fix: GnssFix, omega_ib_b: np.ndarray) -> str:
        """Coarse alignment at a fix that passed the jump test: track it, level and gyrocompass at rest, or align in
        motion once fast enough. Returns how the fix was used: align_coarse (tracked), align_gyrocompass or
        align_in_motion (the fix that started the filter)."""
        cfg = self.config
        std_pos = np.maximum(fix.std_ned, cfg.pos_std_floor_m)
        v, std_v = self._fix_velocity(fix, std_pos, self.prev_track)
        if v is not None:
            self.speed_max = max(self.speed_max, math.hypot(v[0], v[1]))
        self._dvl_pair(nav, fix, omega_ib_b, v, std_v)
        self._velocity_change(v, std_v, self.seg[6])
        seg, rest = self.seg, self.rest
        self.tilt_std += cfg.imu_noise.gyro_bias_std * seg[6]  # roll/pitch drift on the gyro since the last fix
        still = v is not None and math.hypot(v[0], v[1]) <= cfg.align_still_speed_mps + 3.0 * max(std_v[0], std_v[1]) \
            and not turned(seg, cfg.imu_noise)
        if still and self.rest_prev:
            self.rest = rest = [a + b for a, b in zip(rest, seg)]
        elif not still:
            self.rest = rest = [0.0] * 7
        self.rest_prev, self.seg = still, [0.0] * 7
        self._track(nav, fix, omega_ib_b, v, std_pos, std_v)
        self.prev_track = (fix.t_ns, np.asarray(fix.llh, dtype=float), std_pos)
        rest_s = rest[6]
        if rest_s >= cfg.align_level_s:
            f_b = np.array(rest[3:6]) / rest_s
            if levelling_std(cfg.imu_noise, rest_s) <= self.tilt_std:
                self.set_tilt(nav, *level(f_b), levelling_std(cfg.imu_noise, rest_s), "levelling")
            if rest_s >= cfg.align_gyrocompass_s and not self.gyrocompass_refusal:
                al = static_alignment(f_b, np.array(rest[0:3]) / rest_s, nav.state.lat, rest_s, cfg.imu_noise,
                                      cfg.align_max_heading_std)
                return self._start_fine(nav, al.euler, al.std_euler, "gyrocompass", fix, omega_ib_b, v, std_pos,
                                        std_v)
        return self._in_motion(nav, fix, omega_ib_b, v, std_pos, std_v)

    def _in_motion(self, nav, fix: GnssFix, omega_ib_b, v, std_pos, std_v) -> str:
        """In-motion hand-over by align_in_motion: "course", "acceleration", "auto": the course once the velocity
        changes confirm it (their heading known within AUTO_CONFIRM_STD and the course within 3 sigma of both from
        it; refuted: a vehicle reversing or not moving along its x axis, counted align_course_refuted), else the
        velocity changes' heading once within align_max_heading_std; or "dvl": the DVL pairs' heading once within
        it, the course where no DVL velocity is recent."""
        how = self.config.align_in_motion
        if how == "dvl" and self._dvl_recent(fix.t_ns):
            chosen = self._rotation_candidate(nav, self.dvl_sums, "dvl") if v is not None else None
        else:
            chosen = self._course_or_acceleration(nav, "course" if how == "dvl" else how, v, std_v)
        if chosen is None:
            return "align_coarse"
        euler, std_euler, method, tilt_source = chosen
        if tilt_source:
            self.tilt_source = tilt_source
        return self._start_fine(nav, euler, std_euler, method, fix, omega_ib_b, v, std_pos, std_v)

    def _course_or_acceleration(self, nav, how: str, v, std_v):
        """The candidate of align_in_motion course, acceleration or auto (_in_motion) at a fix; None: none yet."""
        course = self._course_candidate(nav, v, std_v) if how != "acceleration" else None
        accel = (self._rotation_candidate(nav, self.accel_sums, "acceleration")
                 if how != "course" and v is not None else None)
        if how == "auto" and course is not None:
            psi, std = heading_from_vector_pairs(self.accel_sums)
            yaw = quat_to_euler(nav.state.q_nb)[2] + psi
            if not std <= AUTO_CONFIRM_STD:
                course = None
            elif abs(math.remainder(course[0][2] - yaw, 2.0 * math.pi)) > 3.0 * math.hypot(course[1][2], std):
                nav.counters["align_course_refuted"] += 1
                course = None
        return course or accel

    def _dvl_recent(self, t_ns: int) -> bool:
        """Whether a DVL velocity came in the last DVL_RECENT_S before t_ns, or the engine started less than that
        before it (the first DVL sample may come after the first fix) (align_in_motion dvl)."""
        last = self.dvl_seen_ns if self.dvl_seen_ns is not None else self.times.get(str(AlignState.COARSE), t_ns)
        return t_ns - last <= DVL_RECENT_S * NS

    def _course_candidate(self, nav, v, std_v):
        """(euler, std_euler, "in_motion", tilt source or "") of yaw = course once fast enough and within
        align_max_heading_std; None otherwise."""
        cfg = self.config
        if v is None or not math.hypot(v[0], v[1]) >= cfg.align_min_speed_mps:  # not yet fast enough
            return None
        euler, std_euler = course_alignment(v, std_v, cfg.align_course_std, cfg.align_tilt_std)
        if not std_euler[2] <= cfg.align_max_heading_std:
            return None
        if self.tilt_std < cfg.align_tilt_std:  # a better roll and pitch than 0 and the climb angle
            euler[:2] = quat_to_euler(nav.state.q_nb)[:2]
            std_euler[:2] = self.tilt_std
            return euler, std_euler, "in_motion", ""
        return euler, std_euler, "in_motion", "climb_angle"

    def _rotation_candidate(self, nav, sums, method: str):
        """(euler, std_euler, method, tilt source or "") once the yaw offset of the pairs in sums (the velocity
        changes' or the DVL's, heading_from_vector_pairs) is known within align_max_heading_std: the yaw the engine's
        plus it, roll and pitch the engine's (levelled, given or assumed level) with their 1-sigma; None before."""
        psi, std = heading_from_vector_pairs(sums)
        if not std <= self.config.align_max_heading_std:
            return None
        roll, pitch, yaw = quat_to_euler(nav.state.q_nb)
        tilt = self._tilt()
        return (np.array([roll, pitch, math.remainder(yaw + psi, 2.0 * math.pi)]), np.array([tilt, tilt, std]),
                method, "assumed_level" if self.tilt_std > self.config.align_tilt_std else "")

    def _tilt(self) -> float:
        """Roll/pitch 1-sigma [rad] the acceleration method works with: the known one, at most align_tilt_std (an
        unknown tilt is taken as level within it, as the course method's roll 0)."""
        return min(self.tilt_std, self.config.align_tilt_std)

    def _velocity_change(self, v, std_v, dt: float) -> None:
        """One pair of fixes for the acceleration method: the GNSS horizontal velocity change b since the last fix
        with a velocity against the IMU's a over the same time dt [s] (self.dv_p, in the engine's yaw-0 frame), summed
        for the least-squares rotation b = R(psi) a (see heading_from_vector_pairs); each pair weighted by the
        inverse variance of b - R a per axis: the two fixes' velocity variances, the tilt error times g over dt, the
        accelerometer noise and bias over dt."""
        a, self.dv_p = self.dv_p, [0.0, 0.0]
        cur = None if v is None else (float(v[0]), float(v[1]), float(max(std_v[0], std_v[1])))
        prev, self.accel_prev = self.accel_prev, cur
        if prev is None or cur is None or dt <= 0.0:
            return
        noise = self.config.imu_noise
        var = (prev[2] ** 2 + cur[2] ** 2 + (earth.G0 * self._tilt() * dt) ** 2 + noise.vrw**2 * dt
               + (noise.accel_bias_std * dt) ** 2)
        add_vector_pair(self.accel_sums, a, (cur[0] - prev[0], cur[1] - prev[1]), var)

    def _dvl_pair(self, nav, fix: GnssFix, omega_ib_b, v, std_v) -> None:
        """One (DVL, fix) pair for align_in_motion dvl: the last DVL velocity since the fix before (on_body_velocity;
        every fix takes or drops it, so dv_p's change since it is the IMU's velocity change from it to this fix), at
        most DVL_RECENT_S old, carried to the fix with that change (the engine's yaw-0 frame) and
        to the antenna with the lever arm, against the fix's horizontal velocity v [m/s] (1-sigma std_v), summed for
        b = R(psi) a; weighted by the inverse variance of b - R a per axis: the fix's and the DVL's, the tilt error
        times g and the accelerometer noise and bias over the time between them."""
        last, self.dvl_last = self.dvl_last, None
        if last is None or v is None or not math.hypot(v[0], v[1]) >= self.config.align_min_speed_mps:
            return
        gap = (fix.t_ns - last[0]) / NS
        if not 0.0 <= gap <= DVL_RECENT_S:
            return
        lever_n = nav.state.C_nb @ np.cross(omega_ib_b, nav.lever_b)
        a = (last[1] + self.dv_p[0] - last[4] + lever_n[0], last[2] + self.dv_p[1] - last[5] + lever_n[1])
        noise = self.config.imu_noise
        var = (float(max(std_v[0], std_v[1])) ** 2 + last[3] + (earth.G0 * self._tilt() * gap) ** 2
               + noise.vrw**2 * gap + (noise.accel_bias_std * gap) ** 2)
        add_vector_pair(self.dvl_sums, a, (float(v[0]), float(v[1])), var)

    def _track(self, nav, fix: GnssFix, omega_ib_b: np.ndarray, v_ant_n, std_pos: np.ndarray, std_v) -> None:
        """Put the antenna at the fix and, when given, its velocity at v_ant_n [m/s]; their variances become those
        of the fix (std_pos [m], std_v [m/s])."""
        P = nav.P
        P[0:6, :] = 0.0
        P[:, 0:6] = 0.0
        P[POS, POS] = np.diag(np.square(std_pos))
        P[VEL, VEL] = np.diag(np.square(std_v if std_v is not None else self.initial.std_v_n))
        age = (nav.t_ns - fix.t_ns) / NS
        v_ins_ant = antenna_velocity(nav.state, nav.lever_b, omega_ib_b)
        z, _ = position_model(nav.state, nav.lever_b, np.asarray(fix.llh, dtype=float), v_ins_ant, age)
        dx = np.zeros(N_STATES)
        dx[POS] = z
        if v_ant_n is not None:
            dx[VEL] = v_ins_ant - v_ant_n
        nav.feedback(dx)

    def _start_fine(self, nav, euler, std_euler, method: str, fix: GnssFix, omega_ib_b, v_ant_n, std_pos,
                    std_v) -> str:
        """End of coarse alignment: attitude euler [rad] with 1-sigma std_euler [rad], position and velocity at the
        fix, and a fresh covariance from these 1-sigma values (the bias uncertainty of the initial state)."""
        s = nav.state
        s.q0, s.q1, s.q2, s.q3 = (float(x) for x in euler_to_quat(euler))
        self._track(nav, fix, omega_ib_b, v_ant_n, std_pos, std_v)
        start = replace(self.initial, t_ns=fix.t_ns, llh=s.llh, v_n=s.v_n, euler=np.asarray(euler, dtype=float),
                        std_pos_ned=std_pos, std_v_n=self.initial.std_v_n if std_v is None else std_v,
                        std_euler=np.asarray(std_euler, dtype=float), heading_known=True)
        nav.start_filter(initial_covariance(start, self.config), fix.t_ns)
        self.coarse = False
        self.start_heading, self.start_heading_std = float(euler[2]), float(std_euler[2])
        self.method = method
        nav.counters[f"align_{method}"] += 1
        self._set_state(nav, AlignState.FINE, fix.t_ns,
                        f"{method}: roll, pitch, yaw {np.round(np.degrees(euler), 2)} deg")
        return f"align_{method}"

    def status(self, nav) -> dict:
        return {"state": self.state, "method": self.method, "heading_std_rad": float(nav.std_att[2]),
                "times_ns": dict(self.times), "tilt_source": self.tilt_source, "gyrocompass": self.gyrocompass_refusal,
                "initial_state": self.initial_check, "waiting": self.waiting(),
                "start_heading_rad": self.start_heading, "start_heading_std_rad": self.start_heading_std}

    def waiting(self) -> str:
        """While coarse: what in-motion alignment waits for ("" otherwise): the speed reached against
        align_min_speed_mps, which a vehicle profile or parameter file sets (an AUV cruises at 1-2 m/s)."""
        if not self.coarse:
            return ""
        cfg = self.config
        if cfg.align_in_motion == "dvl" and self.dvl_seen_ns is not None:
            std = heading_from_vector_pairs(self.dvl_sums)[1]
            if self.speed_max < cfg.align_min_speed_mps:
                return (f"in motion (dvl): GNSS speed at most {self.speed_max:.2f} m/s so far, below "
                        f"align_min_speed_mps {cfg.align_min_speed_mps:.2f} m/s, from which DVL/GNSS velocity pairs "
                        f"count (a vehicle profile or --params file sets it)")
            return (f"in motion (dvl): heading 1-sigma {math.degrees(std):.1f} deg from {self.dvl_sums[4]:.0f} "
                    f"DVL/GNSS velocity pairs so far, above align_max_heading_std "
                    f"{math.degrees(cfg.align_max_heading_std):.1f} deg (the yaw = course where no DVL velocity "
                    f"came in the last {DVL_RECENT_S:g} s)")
        if cfg.align_in_motion in ("acceleration", "auto"):
            std = heading_from_vector_pairs(self.accel_sums)[1]
            return (f"in motion ({cfg.align_in_motion}): heading 1-sigma {math.degrees(std):.1f} deg from "
                    f"{self.accel_sums[4]:.0f} velocity changes so far, above align_max_heading_std "
                    f"{math.degrees(cfg.align_max_heading_std):.1f} deg (it needs horizontal manoeuvres"
                    + ("; yaw = course only where they confirm it)" if cfg.align_in_motion == "auto" else ")"))
        return (f"in motion: GNSS speed at most {self.speed_max:.2f} m/s so far, below align_min_speed_mps "
                f"{cfg.align_min_speed_mps:.2f} m/s (a vehicle profile or --params file sets it)"
                if self.speed_max < cfg.align_min_speed_mps else
                f"in motion: a heading 1-sigma within align_max_heading_std "
                f"{math.degrees(cfg.align_max_heading_std):.1f} deg")

    def get_state(self) -> dict:
        """Everything of the alignment that determines the engine's future output (plain, msgpack-safe)."""
        track = self.prev_track
        return {"coarse": bool(self.coarse), "state": str(self.state), "method": self.method,
                "times": dict(self.times), "tilt_std": float(self.tilt_std), "tilt_source": self.tilt_source,
                "seg": [float(x) for x in self.seg], "rest": [float(x) for x in self.rest],
                "rest_prev": bool(self.rest_prev),
                "prev_track": None if track is None else [int(track[0]), track[1].tolist(), track[2].tolist()],
                "speed_max": float(self.speed_max), "dv_p": [float(x) for x in self.dv_p],
                "accel_prev": None if self.accel_prev is None else list(self.accel_prev),
                "accel_sums": [float(x) for x in self.accel_sums],
                "dvl_last": None if self.dvl_last is None else [int(self.dvl_last[0])] + [
                    float(x) for x in self.dvl_last[1:]],
                "dvl_seen_ns": self.dvl_seen_ns, "dvl_sums": [float(x) for x in self.dvl_sums],
                "checking": bool(self.checking), "initial_check": self.initial_check, "check_strike": self.check_strike,
                "check_v_ref": None if self.check_v_ref is None else list(self.check_v_ref),
                "check_prev": None if self.check_prev is None else [int(self.check_prev[0])] + [
                    None if x is None else x.tolist() for x in self.check_prev[1:]]}

    def set_state(self, st: dict) -> None:
        self.coarse, self.state, self.method = bool(st["coarse"]), AlignState(st["state"]), st["method"]
        self.times = {str(k): int(v) for k, v in st["times"].items()}
        self.tilt_std, self.tilt_source = float(st["tilt_std"]), st["tilt_source"]
        self.seg, self.rest, self.rest_prev = [float(x) for x in st["seg"]], [float(x) for x in st["rest"]], \
            bool(st["rest_prev"])
        track = st["prev_track"]
        # a checkpoint from before these (the course method only): they start again
        self.speed_max = float(st.get("speed_max", 0.0))
        self.dv_p = [float(x) for x in st.get("dv_p", (0.0, 0.0))]
        prev = st.get("accel_prev")
        self.accel_prev = None if prev is None else tuple(float(x) for x in prev)
        self.accel_sums = [float(x) for x in st.get("accel_sums", (0.0,) * 5)]
        last = st.get("dvl_last")
        self.dvl_last = None if last is None else (int(last[0]), *(float(x) for x in last[1:]))
        seen = st.get("dvl_seen_ns")
        self.dvl_seen_ns = None if seen is None else int(seen)
        self.dvl_sums = [float(x) for x in st.get("dvl_sums", (0.0,) * 5)]
        self.prev_track = None if track is None else (int(track[0]), np.array(track[1], dtype=float),
                                                      np.array(track[2], dtype=float))
        self.checking, self.initial_check, self.check_strike = bool(st["checking"]), st["initial_check"], \
            st["check_strike"]
        ref = st["check_v_ref"]
        self.check_v_ref = None if ref is None else (float(ref[0]), float(ref[1]))
        prev = st["check_prev"]
        self.check_prev = None if prev is None else (int(prev[0]), *(None if x is None else np.array(x, dtype=float)
                                                                     for x in prev[1:]))
