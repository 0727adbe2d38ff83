"""comma2k19 example segment: 60 s of highway driving, phone-class IMU, u-blox GNSS, comma's fused pose.

Follows the dataset README (NumPy ``t.npy``/``value.npy`` pairs, ``t`` = device boot time [s]):
- IMU ``processed_log/IMU/accelerometer`` [m/s^2] and ``gyro`` [rad/s, Android bias-corrected], both already in
  FRD, each with its own times. The gyro is resampled (linear) onto the accelerometer times, then
  rates -> increments by the trapezoid rule (ImuData.from_rates).
- Boot time -> GPS time by a linear fit of ``global_pose/frame_times`` to ``frame_gps_times`` (week, tow);
  times are GPS seconds since 1980-01-06 (week * 604800 + tow).
- GNSS ``live_gnss_ublox``: lat, lon [deg], speed [m/s], utc_timestamp [ms], altitude [m], bearing [deg];
  the fix time is utc_timestamp + 18 leap seconds (2018). No accuracy is given: assumed stds below.
- Odometer ``processed_log/CAN/wheel_speed`` [m/s]: the mean of the rear wheels (load_odometer).
- Truth ``global_pose``: ECEF camera position and velocity, and the quaternion that the README calls "rotating
  ECEF -> camera frame [forward, right, down]". In our convention it is q_e_cam (it maps camera FRD coordinates to
  ECEF): that reading gives a yaw within 1 deg of the velocity course on this highway, the transposed one is
  40 deg off in roll and yaw.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from zennav.datasets.errors import DataError, existing_file
from zennav.nav import earth
from zennav.nav.rotation import dcm_to_euler, quat_to_dcm, wrap_angle
from zennav.nav.types import (
    NS,
    Dataset,
    FixType,
    GnssData,
    ImuData,
    ImuNoise,
    InitialState,
    NavConfig,
    OdometerData,
    Truth,
)

WEEK_NS = 604800 * NS
LEAP_SECONDS_MS = 18_000  # GPS - UTC in 2018 [ms]
GPS_EPOCH_UNIX_MS = 315964800 * 1000  # 1980-01-06 00:00:00 as Unix time [ms]
STD_NED_M = np.array([2.0, 2.0, 4.0])  # assumed u-blox position 1-sigma, north east down [m]
STD_V_N_MPS = np.array([0.3, 0.3, 3.0])  # assumed speed 1-sigma; the vertical velocity is not measured (0 given)


def _npy(path: Path, tail: tuple) -> np.ndarray:
    """A finite float array of shape (N >= 2, *tail) from a .npy file."""
    path = existing_file(path)
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise DataError(path, f"not a numeric .npy file: {exc}") from None
    if array.shape[1:] != tail or len(array) < 2 or not np.issubdtype(array.dtype, np.number):
        raise DataError(path, f"array of shape {array.shape} ({array.dtype}), "
                              f"expected (N, {', '.join(map(str, tail))})")
    bad = np.flatnonzero(~np.isfinite(array.reshape(len(array), -1)).all(axis=1))
    if bad.size:
        raise DataError(path, f"row {bad[0]} is NaN or infinite")
    return array.astype(float)


def _require_increasing(path: Path, t) -> None:
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataError(path, f"row {k}: time {t[k]} is not after the previous {t[k - 1]}")


def _log(folder: Path, log: str, tail: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(t [boot s], value) of one processed_log entry."""
    t = _npy(folder / log / "t.npy", ())
    value = _npy(folder / log / "value.npy", tail)
    if len(value) != len(t):
        raise DataError(folder / log / "value.npy", f"{len(value)} rows for {len(t)} times")
    _require_increasing(folder / log / "t.npy", t)
    return t, value


def _pose_times_ns(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """(boot time [s], GPS ns since 1980-01-06) of the global_pose frames."""
    boot = _npy(folder / "global_pose" / "frame_times.npy", ())
    week_tow = _npy(folder / "global_pose" / "frame_gps_times.npy", (2,))
    t_ns = week_tow[:, 0].astype(np.int64) * WEEK_NS + np.round(week_tow[:, 1] * 1e9).astype(np.int64)
    if len(boot) != len(t_ns):
        raise DataError(folder / "global_pose", f"{len(boot)} frame_times for {len(t_ns)} frame_gps_times")
    _require_increasing(folder / "global_pose" / "frame_times.npy", boot)
    _require_increasing(folder / "global_pose" / "frame_gps_times.npy", t_ns)
    return boot, t_ns


def _boot_to_gps(boot: np.ndarray, gps_ns: np.ndarray):
    """Linear map boot time [s] -> GPS ns, fitted to the pose frames; returns (function, max residual [s])."""
    rel_gps_s = (gps_ns - gps_ns[0]) / NS
    slope, offset = np.polyfit(boot - boot[0], rel_gps_s, 1)

    def to_gps_ns(t_boot):
        return gps_ns[0] + np.round((slope * (np.asarray(t_boot) - boot[0]) + offset) * 1e9).astype(np.int64)

    return to_gps_ns, float(np.abs(slope * (boot - boot[0]) + offset - rel_gps_s).max())


def load_imu(folder, to_gps_ns) -> ImuData:
    """Accelerometer and bias-corrected gyro (FRD) -> ImuData on the accelerometer times (within the gyro's)."""
    folder = Path(folder)
    t_acc, f_ib_b = _log(folder, "processed_log/IMU/accelerometer", (3,))
    t_gyro, omega = _log(folder, "processed_log/IMU/gyro", (3,))
    inside = (t_acc >= t_gyro[0]) & (t_acc <= t_gyro[-1])
    t_acc, f_ib_b = t_acc[inside], f_ib_b[inside]
    omega_ib_b = np.column_stack([np.interp(t_acc, t_gyro, omega[:, i]) for i in range(3)])
    return ImuData.from_rates(to_gps_ns(t_acc), omega_ib_b, f_ib_b)


def load_gnss(folder) -> GnssData:
    """live_gnss_ublox -> GnssData with the assumed stds; altitude taken as ellipsoidal height (see notes)."""
    folder = Path(folder)
    log = "processed_log/GNSS/live_gnss_ublox"
    _, value = _log(folder, log, (6,))
    lat, lon, speed, utc_ms, alt, bearing = value.T
    t_ns = (np.round(utc_ms).astype(np.int64) - GPS_EPOCH_UNIX_MS + LEAP_SECONDS_MS) * 1_000_000
    _require_increasing(folder / log / "value.npy", t_ns)
    course = np.deg2rad(bearing)
    m = len(t_ns)
    return GnssData(
        t_ns=t_ns,
        llh=np.column_stack([np.deg2rad(lat), np.deg2rad(lon), alt]),
        std_ned=np.tile(STD_NED_M, (m, 1)),
        v_n=np.column_stack([speed * np.cos(course), speed * np.sin(course), np.zeros(m)]),
        std_v_n=np.tile(STD_V_N_MPS, (m, 1)),
        fix=np.full(m, int(FixType.SINGLE), dtype=np.int64),
        num_sats=np.full(m, -1, dtype=np.int64),
    )


def load_odometer(folder, to_gps_ns) -> OdometerData:
    """processed_log/CAN/wheel_speed (FL, FR, RL, RR [m/s], about 89 Hz) -> the mean of the two rear wheels, the
    speed of the rear axle centre (the constraint point of zennav.nav.aid.vehicle), on GPS times."""
    t_boot, wheels = _log(Path(folder), "processed_log/CAN/wheel_speed", (4,))
    return OdometerData(to_gps_ns(t_boot), 0.5 * (wheels[:, 2] + wheels[:, 3]))


def load_truth(folder, t_ns: np.ndarray) -> Truth:
    """global_pose (camera, 20 Hz) -> Truth: ECEF -> llh, ECEF velocity -> NED, q_e_cam -> NED Euler angles."""
    folder = Path(folder) / "global_pose"
    r_e = _npy(folder / "frame_positions.npy", (3,))
    v_e = _npy(folder / "frame_velocities.npy", (3,))
    q_e_cam = _npy(folder / "frame_orientations.npy", (4,))
    if not len(r_e) == len(v_e) == len(q_e_cam) == len(t_ns):
        raise DataError(folder, "frame_positions, frame_velocities, frame_orientations and frame_times "
                                "differ in length")
    llh = earth.ecef_to_llh(r_e)
    v_n = np.empty_like(v_e)
    euler = np.empty_like(v_e)
    for k in range(len(t_ns)):
        C_ne = earth.C_en(llh[k, 0], llh[k, 1]).T
        v_n[k] = C_ne @ v_e[k]
        euler[k] = dcm_to_euler(C_ne @ quat_to_dcm(q_e_cam[k] / np.linalg.norm(q_e_cam[k])))
    return Truth(
        t_ns=t_ns,
        llh=llh,
        v_n=v_n,
        euler=euler,
        source="comma global_pose: fused INS/GNSS/vision pose of the camera (not independent: same IMU and GNSS)",
    )


def _interp_truth(truth: Truth, t_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth (llh, v_n, euler) linearly interpolated at t_ns (yaw unwrapped first)."""
    assert truth.euler is not None  # load_truth always gives the attitude
    euler = truth.euler.copy()
    euler[:, 2] = np.unwrap(euler[:, 2])

    def at(values):
        return np.array([np.interp(t_ns, truth.t_ns, values[:, i]) for i in range(3)])

    euler_t0 = at(euler)
    euler_t0[2] = wrap_angle(euler_t0[2])
    return at(truth.llh), at(truth.v_n), euler_t0


def load(folder) -> Dataset:
    """The comma2k19 example segment folder -> Dataset (times: GPS ns since 1980-01-06)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "dataset folder not found")
    boot, pose_t_ns = _pose_times_ns(folder)
    to_gps_ns, fit_residual_s = _boot_to_gps(boot, pose_t_ns)
    imu = load_imu(folder, to_gps_ns)
    gnss = load_gnss(folder)
    truth = load_truth(folder, pose_t_ns)
    t0 = int(imu.t_ns[np.searchsorted(imu.t_ns, truth.t_ns[0])])
    llh, v_n, euler = _interp_truth(truth, t0)
    initial = InitialState(
        t_ns=t0,
        llh=llh,
        v_n=v_n,
        euler=euler,
        std_pos_ned=np.full(3, 2.0),
        std_v_n=np.full(3, 0.5),
        std_euler=np.deg2rad([2.0, 2.0, 5.0]),
    )
    # Assumed phone-class IMU (no datasheet in the dataset): gyro 0.01 deg/s/sqrt(Hz), accel 200 ug/sqrt(Hz),
    # residual bias instability 0.01 deg/s and 0.05 m/s^2 (Gauss-Markov, 300 s).
    noise = ImuNoise(
        arw=math.radians(0.01),
        vrw=200e-6 * earth.G0,
        gyro_bias_std=math.radians(0.01),
        accel_bias_std=0.05,
        gyro_bias_tau=300.0,
        accel_bias_tau=300.0,
    )
    config = NavConfig(imu_noise=noise, lever_arm_b=np.zeros(3), start_t_ns=t0)
    notes = {
        "source": "commaai/comma2k19 Example_1 segment 40 (MIT), Toyota RAV4, 2018-08-02, highway 280",
        "time": "GPS seconds since 1980-01-06; IMU boot time mapped by a linear fit to the pose frames",
        "boot_to_gps_fit_residual_s": fit_residual_s,
        "imu_rate_hz": float((len(imu) - 1) * NS / (imu.t_ns[-1] - imu.t_ns[0])),
        "imu_increments": "gyro resampled onto accelerometer times; trapezoid rule on rates",
        "gnss_rate_hz": float((len(gnss) - 1) * NS / (gnss.t_ns[-1] - gnss.t_ns[0])),
        "gnss_std_assumed": "u-blox accuracy not recorded: assumed 1-sigma 2 m horizontal, 4 m vertical, 0.3 m/s "
        "horizontal velocity; vertical velocity not measured: 0 with 3 m/s",
        "gnss_altitude": "datum not documented; used as ellipsoidal height (it agrees with the pose's ellipsoidal "
        "heights to about 1 m, whereas mean-sea-level heights would differ by the geoid undulation, about -32 m)",
        "gnss_time": "utc_timestamp + 18 leap seconds",
        "lever_arm": "unknown: zeros (GNSS antenna, IMU and the camera of the truth are not surveyed)",
        "imu_noise": "assumed phone-class values, not from a datasheet",
        "truth": "comma's fused pose of the camera, not independent",
    }
    notes["odometer"] = "CAN wheel_speed, mean of the rear wheels (RL, RR): the rear axle centre; scale unknown"
    return Dataset("comma2k19_example_segment", imu, gnss, config, initial, truth, notes,
                   load_odometer(folder, to_gps_ns))
