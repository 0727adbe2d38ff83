"""Plain data containers shared by the core, the loaders, the simulator and the services.

Conventions (README.md): n = NED, b = forward-right-down, SI units and radians,
times are integer nanoseconds of GPS time (``t_ns``) in the dataset's own reference
(seconds of week for KF-GINS files, seconds since the GPS epoch otherwise).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import Enum, IntEnum

import numpy as np

NS = 1_000_000_000
HEADING_UNKNOWN_STD = math.radians(20.0)  # a yaw 1-sigma above this [rad] is too large for a small-angle filter


class FixType(IntEnum):
    """GNSS solution quality, ordered from worst to best."""

    NONE = 0
    SINGLE = 1
    DGPS = 2
    RTK_FLOAT = 3
    RTK_FIXED = 4


class _StrEnum(str, Enum):
    """A str that is an enum member: compares equal to, formats and msgpack-packs as its value ("valid")."""

    __str__ = str.__str__
    __format__ = str.__format__  # type: ignore[assignment]


class GnssState(_StrEnum):
    """GNSS position aiding: fixes fused within NavConfig.outage_timeout_s (valid) or not (outage)."""

    VALID = "valid"
    OUTAGE = "outage"


class AlignState(_StrEnum):
    """Alignment: heading unknown (coarse), filter running with a large heading variance (fine), done (aligned)."""

    COARSE = "coarse"
    FINE = "fine"
    ALIGNED = "aligned"


@dataclass
class ImuData:
    """IMU increments over the interval that ends at ``t_ns[k]`` (body frame b, FRD).

    dtheta: (N, 3) angle increments [rad]; dvel: (N, 3) velocity increments of specific force [m/s].
    """

    t_ns: np.ndarray
    dtheta: np.ndarray
    dvel: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)

    def slice(self, sel) -> ImuData:
        return ImuData(self.t_ns[sel], self.dtheta[sel], self.dvel[sel])

    @classmethod
    def from_rates(cls, t_ns, omega_ib_b, f_ib_b) -> ImuData:
        """Increments from rates sampled at t_ns: angular rate [rad/s] and specific force [m/s^2], frame b.

        Trapezoid rule over each interval: dtheta_k = (w_{k-1} + w_k) / 2 * (t_k - t_{k-1}), the same for dvel.
        The first sample has no predecessor: its own rate times the first interval's length.
        """
        t_ns = np.asarray(t_ns, dtype=np.int64)
        dt = np.diff(t_ns) / NS
        dt = np.concatenate([dt[:1], dt])[:, None]

        def increments(rate):
            rate = np.asarray(rate, dtype=float)
            return np.concatenate([rate[:1], 0.5 * (rate[1:] + rate[:-1])]) * dt

        return cls(t_ns, increments(omega_ib_b), increments(f_ib_b))


@dataclass
class GnssData:
    """GNSS fixes of the antenna phase centre.

    llh: (M, 3) latitude, longitude [rad], ellipsoidal height [m]; std_ned: (M, 3) reported 1-sigma [m];
    v_n / std_v_n: (M, 3) NED velocity and its 1-sigma [m/s] or None; fix: (M,) FixType;
    num_sats: (M,) satellites used, -1 when unknown.
    """

    t_ns: np.ndarray
    llh: np.ndarray
    std_ned: np.ndarray
    v_n: np.ndarray | None = None
    std_v_n: np.ndarray | None = None
    fix: np.ndarray | None = None
    num_sats: np.ndarray | None = None

    def __post_init__(self):
        m = len(self.t_ns)
        if (self.v_n is None) != (self.std_v_n is None):
            raise ValueError("GnssData: v_n and std_v_n are given together or not at all")
        if self.fix is None:
            self.fix = np.full(m, int(FixType.SINGLE), dtype=np.int64)
        if self.num_sats is None:
            self.num_sats = np.full(m, -1, dtype=np.int64)

    def __len__(self) -> int:
        return len(self.t_ns)

    def fix_at(self, k: int) -> GnssFix:
        v_n, std_v_n, fix, num_sats = self.v_n, self.std_v_n, self.fix, self.num_sats
        assert fix is not None and num_sats is not None  # __post_init__ fills them
        return GnssFix(
            t_ns=int(self.t_ns[k]),
            llh=self.llh[k].copy(),
            std_ned=self.std_ned[k].copy(),
            v_n=None if v_n is None else v_n[k].copy(),
            std_v_n=None if std_v_n is None else std_v_n[k].copy(),
            fix=int(fix[k]),
            num_sats=int(num_sats[k]),
        )

    def slice(self, sel) -> GnssData:
        v_n, std_v_n, fix, num_sats = self.v_n, self.std_v_n, self.fix, self.num_sats
        assert fix is not None and num_sats is not None  # __post_init__ fills them
        return GnssData(
            self.t_ns[sel],
            self.llh[sel],
            self.std_ned[sel],
            None if v_n is None else v_n[sel],
            None if std_v_n is None else std_v_n[sel],
            fix[sel],
            num_sats[sel],
        )


@dataclass
class GnssFix:
    """One GNSS epoch; fields as in GnssData."""

    t_ns: int
    llh: np.ndarray
    std_ned: np.ndarray
    v_n: np.ndarray | None = None
    std_v_n: np.ndarray | None = None
    fix: int = int(FixType.SINGLE)
    num_sats: int = -1


@dataclass
class Truth:
    """Reference trajectory: llh (K, 3) [rad, rad, m], v_n (K, 3) [m/s] or None, euler (K, 3) roll/pitch/yaw [rad]
    or None."""

    t_ns: np.ndarray
    llh: np.ndarray
    v_n: np.ndarray | None = None
    euler: np.ndarray | None = None
    source: str = ""
    at_antenna: bool = False  # True when llh/v_n are of the GNSS antenna (RTK as truth), not of the IMU


@dataclass
class ImuNoise:
    """IMU error model, SI: angle random walk [rad/sqrt(s)], velocity random walk [m/s/sqrt(s)],
    bias instability as first-order Gauss-Markov 1-sigma [rad/s, m/s^2] with correlation times [s];
    scale-factor errors (dimensionless, 1e-6 = 1 ppm) as first-order Gauss-Markov 1-sigma with correlation
    times [s]: 0 says the IMU description has none (15 states; see NavConfig.scale_factors)."""

    arw: float = np.deg2rad(0.2) / 60.0
    vrw: float = 0.1 / 60.0
    gyro_bias_std: float = np.deg2rad(10.0) / 3600.0
    accel_bias_std: float = 1e-3 * 9.80665
    gyro_bias_tau: float = 3600.0
    accel_bias_tau: float = 3600.0
    gyro_scale_std: float = 0.0
    accel_scale_std: float = 0.0
    gyro_scale_tau: float = 3600.0
    accel_scale_tau: float = 3600.0

    def has_scale_factors(self) -> bool:
        """Whether the description gives the scale factors an uncertainty."""
        return self.gyro_scale_std > 0.0 or self.accel_scale_std > 0.0


@dataclass
class InitialState:
    """Initial navigation state and its 1-sigma uncertainty (SI; attitude as roll, pitch, yaw [rad]).

    heading_known: False says "heading unknown": euler[2] is ignored and the navigator aligns (zennav.nav.alignment:
    gyrocompassing at rest where the gyro allows it, else yaw from the GNSS velocity once moving). A non-finite
    yaw or a yaw 1-sigma above HEADING_UNKNOWN_STD says the same (`heading_is_known`).
    """

    t_ns: int
    llh: np.ndarray
    v_n: np.ndarray
    euler: np.ndarray
    std_pos_ned: np.ndarray = field(default_factory=lambda: np.array([1.0, 1.0, 2.0]))
    std_v_n: np.ndarray = field(default_factory=lambda: np.array([0.1, 0.1, 0.1]))
    std_euler: np.ndarray = field(default_factory=lambda: np.deg2rad([1.0, 1.0, 5.0]))
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    std_gyro_bias: np.ndarray | None = None  # None: the ImuNoise bias std
    std_accel_bias: np.ndarray | None = None
    heading_known: bool = True
    gyro_scale: np.ndarray = field(default_factory=lambda: np.zeros(3))  # initial scale-factor errors [-]
    accel_scale: np.ndarray = field(default_factory=lambda: np.zeros(3))
    std_gyro_scale: np.ndarray | None = None  # None: the ImuNoise scale-factor std
    std_accel_scale: np.ndarray | None = None

    def heading_is_known(self) -> bool:
        """True when the yaw can start a small-angle error-state filter (see the class docstring)."""
        yaw, std = float(self.euler[2]), float(self.std_euler[2])
        return bool(self.heading_known) and math.isfinite(yaw) and std <= HEADING_UNKNOWN_STD


@dataclass
class NavConfig:
    """Everything the navigation engine needs besides the data, SI units.

    lever_arm_b: GNSS antenna relative to the IMU, body frame FRD [m].
    gate_probability: chi-square gate of GNSS innovations (per update, on its degrees of freedom); <= 0 disables gating.
    outage_timeout_s: an outage is declared when no valid fix has been fused for this long.
    cov_interval_s: longest interval over which the error covariance is propagated in one step.
    min_fix / min_sats / max_std_m: GNSS quality gates (num_sats -1 means unknown and passes).
    max_jump_m: a position fix further than this [m] horizontally from the INS prediction and outside the gate of
        its horizontal innovation with the reported R is a jump: rejected before the update (gnss_pos_jump).
    pos_std_floor_m / vel_std_floor_mps: lower bounds on the reported GNSS 1-sigma, standing for the errors that
        formal RTK sigmas leave out (antenna phase centre, multipath, IMU/GNSS time-tag jitter).
    gate_reset_s: when position fixes keep arriving but are all rejected for this long, the INS (not the GNSS)
        is taken to be wrong: position/velocity covariance is reset from the innovation and the fix is fused.
    gate_reset_max_rate_mps: with the consistency monitor, that reset only while the horizontal innovation changes by
        at most this [m/s] from one rejected fix to the next (an INS that is off drifts slowly; fixes dragged away
        by a spoofer do not) ...
    gate_reset_unsteady_s: ... or once they have been rejected this long, whatever the innovation does (a drag that
        long cannot be told from a diverging INS by innovations alone).
    reacquire_fixes: after a loss of GNSS (no fix for outage_timeout_s), this many consecutive rejected fixes
        trigger the same reset (the INS drifted beyond its own uncertainty during the outage).

    Alignment (zennav.nav.alignment; used when the initial heading is unknown, InitialState.heading_is_known):
    align_in_motion: how the heading is found in motion: "course" (yaw = course, pitch = climb angle: a vehicle
        moving along its body x axis), "acceleration" (the GNSS velocity changes against the IMU's in the
        levelled frame: any direction of motion, e.g. a multirotor; it needs horizontal accelerations), "auto"
        (the course where the velocity changes confirm it, theirs where they refute it: a vehicle reversing, or one
        that does not move along x; nothing before they are known) or "dvl" (a DVL's body velocity against the GNSS
        velocity: an AUV that crabs in a current; the course where no DVL velocity is recent).
    align_min_speed_mps: GNSS horizontal speed [m/s] above which yaw = course and pitch = climb angle (in motion).
    align_course_std / align_tilt_std: 1-sigma [rad] of heading minus course (sideslip, yaw mounting) and of
        roll 0 / pitch = climb angle for a ground vehicle when no better tilt is known.
    align_still_speed_mps: GNSS speed [m/s] below which the vehicle counts as at rest (levelling, gyrocompassing).
    align_level_s / align_gyrocompass_s: rest time [s] needed to level / to gyrocompass.
    align_max_heading_std: the largest heading 1-sigma [rad] a coarse alignment hands to the filter: gyrocompassing
        is refused above it, in-motion alignment waits for a fix fast enough to be below it.
    align_heading_std: the alignment is complete ('aligned') when the heading 1-sigma is below this [rad].

    Adaptive R (zennav.nav.adaptive_r, seed 001), one estimator per GNSS source (position, velocity):
    adaptive_r: on/off; adaptive_window: m [updates]; adaptive_forgetting: b; adaptive_test_probability: the
    chi-square quantile of the inflation test; adaptive_floor / adaptive_ceiling: R bounds relative to the
    reported (floored) R, as variance ratios. Off by default: innovations cannot tell GNSS noise from INS model
    error, and on the rtklibexplorer drive the time-correlated innovations of its vibrating consumer IMU inflate R
    10-100x (RTK-referenced error 0.065 -> 0.25 m with full GNSS; 15 s outage drift 10.9 -> 8.7 m). Turn it on
    where the GNSS quality changes (simulated noise x10: position RMS 3-5 m -> 0.8-0.9 m).
    """

    imu_noise: ImuNoise = field(default_factory=ImuNoise)
    lever_arm_b: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gate_probability: float = 0.9999
    outage_timeout_s: float = 2.0
    cov_interval_s: float = 0.05
    min_fix: int = int(FixType.SINGLE)
    min_sats: int = 4
    max_std_m: float = 30.0
    max_jump_m: float = 20.0
    pos_std_floor_m: float = 0.05
    vel_std_floor_mps: float = 0.1
    gate_reset_s: float = 10.0
    gate_reset_max_rate_mps: float = 3.0
    gate_reset_unsteady_s: float = 30.0
    reacquire_fixes: int = 3
    use_gnss_velocity: bool = True
    align_in_motion: str = "course"
    align_min_speed_mps: float = 3.0
    align_course_std: float = math.radians(2.0)
    align_tilt_std: float = math.radians(5.0)
    align_still_speed_mps: float = 0.1
    align_level_s: float = 5.0
    align_gyrocompass_s: float = 60.0
    align_max_heading_std: float = math.radians(10.0)
    align_heading_std: float = math.radians(0.5)
    adaptive_r: bool = False
    adaptive_window: int = 5
    adaptive_forgetting: float = 0.95
    adaptive_test_probability: float = 0.99
    adaptive_floor: float = 1.0
    adaptive_ceiling: float = 400.0
    learning: bool = False  # emit LearnSample / LearnQuery for learned INS-error compensation (nav/learning.py)
    learn_after_s: float = 30.0  # no training samples before this time [s] from the start (filter converging)
    learn_horizon_s: float = 60.0  # longest outage the "drift" target learns [s] (shadow INS length)
    learn_drift: bool = True  # run the shadow INSs of the "drift" target's samples (off: none of its samples)
    learn_answer_max_age_s: float = 1.0  # a learned answer is fused only if its query is at most this old [s]
    learn_forward_only: bool = False  # with nhc: fuse only the forward output of the learned body velocity
    # fuse a learned body-velocity output only where its 1-sigma is below the filter's own 1-sigma of it: "on"
    # always, "nhc" while the non-holonomic constraint is on, "off" never (zennav.nav.aid.learned)
    learn_where_better: str = "nhc"
    learn_held_fraction: float = 0.0  # part of a learned body-velocity answer's variance that is a bias held through
    # the outage (a random-constant state per output, restarted at each outage's first answer); the rest is white
    learn_nhc_floor: bool = False  # with nhc: floor the learned lateral and vertical 1-sigma at the constraint's own
    learn_consistency: bool = True  # learned body velocity: R of each output from its innovations (adaptive R)
    learn_consistency_window: int = 5  # innovations [answers] in that estimator's inflation window
    # learned DVL beam errors (zennav.nav.dvl_anomaly): hold time [s] of a sample waiting for its answers; the
    # anomaly rule: k-sigma of the VB R, chi-square probability of lambda, persistence window and count [samples]
    dvl_learned: bool = False  # the tight DVL learns and compensates its beam errors (with learning; the service's)
    dvl_answer_timeout_s: float = 0.5
    dvl_anomaly_k_sigma: float = 3.0
    dvl_anomaly_probability: float = 0.99
    dvl_anomaly_window: int = 5
    dvl_anomaly_min_count: int = 3
    nhc: bool = False  # non-holonomic constraint of a land vehicle (zennav.nav.aid.constraints)
    nhc_std_mps: float = 0.1  # 1-sigma of the constrained lateral and vertical body velocity [m/s]
    nhc_every_s: float = 0.1  # period of the constraint's updates [s of data time]
    nhc_corr_s: float = 0.5  # correlation time of the violations (sideslip, suspension pitch) [s]; 0: white
    # the vehicle frame v (forward-right-down of the car body) for the constraints and the odometer
    # (zennav.nav.aid.vehicle): configured, not estimated
    vehicle_mount_euler: tuple = (0.0, 0.0, 0.0)  # roll, pitch, yaw of v in the IMU body frame [rad]: C_bv
    vehicle_lever_b: tuple = (0.0, 0.0, 0.0)  # IMU to the constraint point (rear axle centre), body FRD [m]
    # zero velocity and angular rate at standstill (zennav.nav.aid.zupt)
    zupt: bool = False
    zupt_window_s: float = 0.5  # detector window [s]
    zupt_accel_std_mps2: float = 0.1  # still: RMS deviation of f_b from its window mean below this [m/s^2]
    zupt_gyro_rms: float = math.radians(0.5)  # still: RMS of the bias-corrected body rate below this [rad/s]
    zupt_accel_mps2: float = 0.1  # still: horizontal specific force in n (acceleration) below this [m/s^2]
    zupt_accel_change_mps2: float = 0.03  # stay still: mean f_b changed by less since the stop began [m/s^2]
    zupt_gnss_speed_mps: float = 0.2  # not still while a GNSS velocity of the last second is faster [m/s]
    zupt_ins_speed_mps: float = 2.0  # not still while the INS speed is above this [m/s]
    zupt_enter_s: float = 1.0  # hysteresis: still after the test passed this long; left at the first failure [s]
    zupt_every_s: float = 0.1  # period of the updates while still [s of data time]
    zupt_std_mps: float = 0.02  # 1-sigma of the zero velocity [m/s]
    zaru: bool = True  # with the zero velocity, the zero angular rate (earth rate) calibrating the gyro bias
    zaru_std: float = math.radians(0.05)  # 1-sigma of the body rate averaged between updates [rad/s]
    # odometer / wheel speed with a scale-factor state (zennav.nav.aid.odometer)
    odometer: bool = False
    odo_std_mps: float = 0.1  # 1-sigma of one forward-speed sample [m/s]
    odo_scale_std: float = 0.01  # initial 1-sigma of the scale-factor error [ratio]
    odo_scale_psd: float = 1e-8  # PSD of the scale factor's driving noise [ratio^2/s]
    odo_scale_tau_s: float = 3600.0  # its Gauss-Markov correlation time [s]
    odo_max_age_s: float = 0.1  # a sample older than this behind the IMU time is not fused [s]
    odo_max_speed_mps: float = 80.0  # a sample faster than this (either sign) is malformed [m/s]
    scale_factors: bool = True  # estimate gyro/accel scale factors (21 states) when the IMU description has them
    consistency: bool = True  # NIS monitor and adaptive fading factor of the GNSS sources (nav.consistency)
    consistency_window: int = 10  # updates in the NIS window
    consistency_test_probability: float = 0.999  # chi-square quantile of the window's NIS test (overconfident above)
    consistency_max_pos_m: float = 1.0  # largest position innovation [m] (and step) an inflating window may hold
    consistency_max_vel_mps: float = 0.5  # the same for the velocity innovation [m/s]
    consistency_max_factor: float = 100.0  # largest covariance factor of one update
    # Doppler velocity log geometry (zennav.nav.beams): four Janus beams tilted dvl_tilt from the DVL's z axis, in
    # the "+" layout (beam 1 forward) or the "x" layout (beam 1 at +45 deg); the DVL frame d in the IMU body frame
    # (roll, pitch, yaw of d in b: C_bd) and the lever arm IMU -> DVL, body FRD [m]
    dvl_tilt: float = math.radians(30.0)  # [rad]
    dvl_layout: str = "x"
    dvl_mount_euler: tuple = (0.0, 0.0, 0.0)  # [rad]
    dvl_lever_b: tuple = (0.0, 0.0, 0.0)  # [m]
    depth_surface_h_m: float = 0.0  # height of the water surface [m] (DepthData)
    has_dvl: bool = False  # the data carries DVL samples (set by the loader; the DVL source runs only then)
    has_depth: bool = False  # the data carries depth samples (the depth source runs only then)
    # DVL aiding (zennav.nav.aid.dvl): off, loose (3-D DVL-frame velocity) or tight (per beam, with four beam-bias
    # states and one scale-factor state, each first-order Gauss-Markov)
    dvl_mode: str = "tight"
    dvl_beam_std_mps: float = 0.02  # 1-sigma of one beam velocity [m/s]
    dvl_velocity_std_mps: float = 0.02  # loose: 1-sigma per axis of a DVL-reported d-frame velocity [m/s]
    dvl_bias_std_mps: float = 0.01  # initial 1-sigma of each beam bias [m/s]
    dvl_bias_psd: float = 1e-8  # PSD of its driving noise [(m/s)^2/s]
    dvl_bias_tau_s: float = 3600.0  # its correlation time [s]
    dvl_scale_std: float = 0.005  # initial 1-sigma of the scale-factor error [ratio]
    dvl_scale_psd: float = 1e-9  # PSD of its driving noise [ratio^2/s]
    dvl_scale_tau_s: float = 3600.0  # its correlation time [s]
    dvl_mount_std: float = math.radians(0.5)  # initial 1-sigma of each mounting-misalignment angle [rad] (0: none)
    dvl_mount_psd: float = 1e-6 * math.radians(1.0) ** 2  # PSD of its driving noise [rad^2/s]
    dvl_mount_tau_s: float = 100000.0  # its correlation time [s]
    dvl_delay_std_s: float = 0.0  # initial 1-sigma of the DVL's time offset against the IMU [s] (0: no state)
    dvl_delay_psd: float = 1e-6  # PSD of its driving noise [s^2/s]
    dvl_delay_tau_s: float = 100000.0  # its correlation time [s]
    dvl_max_age_s: float = 0.2  # a sample older than this behind the IMU time is not fused [s]
    dvl_max_beam_mps: float = 10.0  # a valid beam faster than this (either sign) is malformed [m/s]
    # pressure depth with a bias state (zennav.nav.aid.depth)
    depth: bool = True
    depth_std_m: float = 0.05  # 1-sigma of one depth sample [m]
    depth_bias_std_m: float = 0.1  # initial 1-sigma of the depth bias [m]
    depth_bias_psd: float = 1e-6  # PSD of its driving noise [m^2/s]
    depth_bias_tau_s: float = 3600.0  # its correlation time [s]
    depth_max_age_s: float = 0.2  # a sample older than this behind the IMU time is not fused [s]
    # variational-Bayes adaptive measurement noise (zennav.nav.vbkf), per source
    vb_dvl: bool = False  # on the DVL source (tight or loose)
    vb_gnss: bool = False  # on the GNSS position and velocity sources
    vb_forgetting: float = 0.97  # rho, forgetting factor of the inverse-Gamma parameters
    vb_iterations: int = 3  # fixed-point iterations per update
    vb_floor: float = 1.0  # lowest R, as a variance ratio to the nominal R (1: VB only inflates R)
    vb_ceiling: float = 1e4  # highest R, as a variance ratio to the nominal R
    start_t_ns: int | None = None
    end_t_ns: int | None = None

    def with_(self, **kw) -> NavConfig:
        return replace(self, **kw)


@dataclass
class Dataset:
    """A recording ready for the core: IMU, GNSS, optional truth, and the configuration to run it."""

    name: str
    imu: ImuData
    gnss: GnssData
    config: NavConfig
    initial: InitialState
    truth: Truth | None = None
    notes: dict = field(default_factory=dict)
    odometer: OdometerData | None = None  # wheel speeds, where the recording has them
    dvl: DvlData | None = None  # Doppler velocity log (an AUV), its geometry in config (NavConfig dvl_*)
    depth: DepthData | None = None  # pressure depth sensor (an AUV)


@dataclass
class OdometerData:
    """Forward speed of the vehicle at its odometer (wheel speed, CAN speed; negative reversing) [m/s] at t_ns (N,)."""

    t_ns: np.ndarray
    speed_mps: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)

    def slice(self, sel) -> OdometerData:
        return OdometerData(self.t_ns[sel], self.speed_mps[sel])


@dataclass
class DvlData:
    """Doppler velocity log samples at t_ns (N,), velocity over the bottom of the DVL (its lever arm point).

    beams: (N, 4) beam velocities [m/s], each the DVL's velocity projected on the beam's unit vector
    (zennav.nav.beams.janus_directions, DVL frame d); beam_valid: (N, 4) bool (bottom lock per beam).
    For a DVL that reports only its velocity in d: beams None, velocity_d (N, 3) [m/s] and velocity_valid (N,)."""

    t_ns: np.ndarray
    beams: np.ndarray | None = None
    beam_valid: np.ndarray | None = None
    velocity_d: np.ndarray | None = None
    velocity_valid: np.ndarray | None = None

    def __post_init__(self):
        if self.beams is None and self.velocity_d is None:
            raise ValueError("DvlData: beams or velocity_d is required")
        if self.beams is not None and self.beam_valid is None:
            self.beam_valid = np.isfinite(self.beams)
        if self.velocity_d is not None and self.velocity_valid is None:
            self.velocity_valid = np.isfinite(self.velocity_d).all(axis=1)

    def __len__(self) -> int:
        return len(self.t_ns)

    def sample(self, k: int) -> DvlSample:
        def row(a):
            return None if a is None else a[k].copy()

        return DvlSample(int(self.t_ns[k]), row(self.beams), row(self.beam_valid), row(self.velocity_d),
                         None if self.velocity_valid is None else bool(self.velocity_valid[k]))

    def slice(self, sel) -> DvlData:
        def part(a):
            return None if a is None else a[sel]

        return DvlData(self.t_ns[sel], part(self.beams), part(self.beam_valid), part(self.velocity_d),
                       part(self.velocity_valid))


@dataclass
class DvlSample:
    """One DVL sample; fields as in DvlData (beams (4,), beam_valid (4,), velocity_d (3,), velocity_valid)."""

    t_ns: int
    beams: np.ndarray | None = None
    beam_valid: np.ndarray | None = None
    velocity_d: np.ndarray | None = None
    velocity_valid: bool | None = None


@dataclass
class DepthData:
    """Pressure depth sensor samples: depth_m (N,) [m, positive down] at t_ns (N,): depth = h_surface - h (+ the
    sensor's bias), h the sensor's height and h_surface = NavConfig.depth_surface_h_m [m] in the dataset's heights."""

    t_ns: np.ndarray
    depth_m: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)

    def sample(self, k: int) -> DepthSample:
        return DepthSample(int(self.t_ns[k]), float(self.depth_m[k]))

    def slice(self, sel) -> DepthData:
        return DepthData(self.t_ns[sel], self.depth_m[sel])


@dataclass
class DepthSample:
    """One depth reading [m, positive down] at t_ns."""

    t_ns: int
    depth_m: float
