"""rtklibexplorer GNSS_IMU sample drive (``drive_0708``): car, consumer MEMS IMU at 100 Hz, u-blox RTK at 4 Hz.

Follows the dataset README and the source converter (rtklibexplorer/GNSS_IMU ``convert_imu_file.py``,
``drive_config.py``):
- IMU ``imu_*.csv``: accel x y z [g], gyro x y z [deg/s], counter [ms]; the first and the last row are skipped.
  The counter is mapped linearly onto [start, end] of the RTKLIB ``.tag`` file, then -0.125 s of logging delay
  is added. Times are GPS seconds since 1980-01-06 (the tag's Unix-style count is in GPST: minus 315964800 s).
- Optional 4th-order Butterworth low-pass run forward and backward (scipy's filtfilt, zero phase; its floats by
  zennav.datasets.butterworth) on the raw sensor axes, as the source does: 10 Hz gyro, 10 Hz horizontal (x, y)
  accel, 5 Hz vertical (z) accel. Zero phase means non-causal (it uses future samples), so it suits
  post-processing only; ``prefilter="none"`` disables it.
- Sensor axes -> body FRD with ``imu_misalign`` through Groves' Euler_to_CTM (the transpose of our C_nb of the
  same angles); units g -> m/s^2 (9.80665) and deg/s -> rad/s; rates -> increments by the trapezoid rule
  (ImuData.from_rates).
- GNSS ``*.pos`` (RTKLIB): Q 1/2/3/4/5 -> RTK_FIXED/RTK_FLOAT/DGPS (SBAS)/DGPS/SINGLE, NEU velocity -> NED.
"""
from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from zennav.datasets.butterworth import lowpass
from zennav.datasets.errors import DataError, existing_file, read_table
from zennav.nav import earth
from zennav.nav.alignment import level
from zennav.nav.rotation import euler_to_dcm
from zennav.nav.types import NS, Dataset, FixType, GnssData, ImuData, ImuNoise, InitialState, NavConfig, Truth

GPS_UNIX_OFFSET_S = 315964800  # Unix-style seconds at 1980-01-06 00:00:00 (the GPS epoch)
IMU_TIME_OFFSET_NS = -125_000_000  # drive_config.imu_t_off: logging delay [ns]
IMU_RATE_HZ = 100.0  # nominal rate, used by the source's filter design [Hz]
IMU_MISALIGN_DEG = np.array([180.0, 0.0, 180.0]) + np.array([0.0, -6.79, 5.35])  # roll, pitch, yaw [deg]
CUTOFF_GYRO_HZ, CUTOFF_ACC_H_HZ, CUTOFF_ACC_V_HZ = 10.0, 10.0, 5.0
LEVER_ARM_B = np.array([0.0, -0.05, -0.65]) - np.array([0.0, 0.0, -0.65])  # antenna minus IMU, FRD [m]
FIX_OF_Q = {1: FixType.RTK_FIXED, 2: FixType.RTK_FLOAT, 3: FixType.DGPS, 4: FixType.DGPS, 5: FixType.SINGLE}
START_SPEED_MPS = 2.0  # the run starts after the first GNSS epoch faster than this (source: yaw_align_max_vel)
STILL_SPEED_MPS = 0.05  # GNSS horizontal speed below which the car counts as still at the start
TAG_MAGIC = b"TIMETAG RTKLIB"


def read_tag(path) -> tuple[int, float, int]:
    """RTKLIB .tag file -> (time_time [s], time_sec [s], last tick [ms]); start = time_time + time_sec (GPST)."""
    path = existing_file(path)
    raw = path.read_bytes()
    n_records = (len(raw) - 76) // 8
    if not raw.startswith(TAG_MAGIC) or n_records < 1 or (len(raw) - 76) % 8:
        raise DataError(path, "not an RTKLIB time-tag file (60-byte 'TIMETAG RTKLIB' header, then 8-byte records)")
    _tick_f, time_time, time_sec = struct.unpack_from("<IId", raw, 60)
    last_tick_ms, _file_pos = struct.unpack_from("<II", raw, len(raw) - 8)
    return time_time, time_sec, last_tick_ms


def _lowpass(x: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """4th-order Butterworth low-pass, forward and backward (zero phase, non-causal), along axis 0."""
    return lowpass(x, cutoff_hz / (0.5 * IMU_RATE_HZ))


def load_imu(csv_path, prefilter: str = "zero-phase") -> ImuData:
    """Raw IMU csv + its .tag -> ImuData in FRD, t_ns in GPS nanoseconds since 1980-01-06 (see module doc)."""
    if prefilter not in ("zero-phase", "none"):
        raise ValueError(f"prefilter must be 'zero-phase' or 'none', not {prefilter!r}")
    time_time, time_sec, last_tick_ms = read_tag(str(csv_path) + ".tag")
    table = read_table(csv_path, 7, delimiter=",", skip_header=1, skip_footer=1)
    table.require_finite()
    ms = table.data[:, 6]
    table.require_increasing(np.round(ms * 1e6).astype(np.int64), "IMU counter")
    if len(ms) < 2:
        raise DataError(csv_path, "fewer than two IMU rows")
    # Linear map of the counter onto [start, end], end = start + last tick: seconds after the tag's whole second.
    rel_s = time_sec + (ms - ms[0]) / 1000.0 * (last_tick_ms / 1000.0) / ((ms[-1] - ms[0]) / 1000.0)
    t_ns = (time_time - GPS_UNIX_OFFSET_S) * NS + np.round(rel_s * 1e9).astype(np.int64) + IMU_TIME_OFFSET_NS
    acc_g, gyro_dps = table.data[:, 0:3], table.data[:, 3:6]
    if prefilter == "zero-phase":
        gyro_dps = _lowpass(gyro_dps, CUTOFF_GYRO_HZ)
        acc_g = np.column_stack([_lowpass(acc_g[:, :2], CUTOFF_ACC_H_HZ), _lowpass(acc_g[:, 2], CUTOFF_ACC_V_HZ)])
    C_b_imu = euler_to_dcm(np.deg2rad(IMU_MISALIGN_DEG)).T  # Groves Euler_to_CTM: sensor axes -> body FRD
    f_ib_b = acc_g @ C_b_imu.T * earth.G0
    omega_ib_b = np.deg2rad(gyro_dps) @ C_b_imu.T
    return ImuData.from_rates(t_ns, omega_ib_b, f_ib_b)


def load_gnss(pos_path) -> GnssData:
    """RTKLIB .pos (GPST date/time, lat/lon/h, Q, ns, sdn/sde/sdu, ..., vn ve vu, sdvn sdve sdvu, ...) -> GnssData."""
    table = read_table(pos_path, 24, comments="%", text_cols=2)
    table.require_finite()
    text = table.text
    assert text is not None  # read with text_cols=2
    try:
        stamps = np.char.add(np.char.add(np.char.replace(text[:, 0], "/", "-"), "T"), text[:, 1])
        t_ns = (stamps.astype("datetime64[ns]") - np.datetime64("1980-01-06T00:00:00", "ns")).astype(np.int64)
    except ValueError:
        bad = next(k for k, s in enumerate(stamps) if not _is_time(s))
        raise table.error(bad, f"cannot parse date/time {' '.join(text[bad])!r}") from None
    table.require_increasing(t_ns)
    d = table.data
    q = d[:, 3].astype(int)
    bad_q = np.flatnonzero(~np.isin(q, list(FIX_OF_Q)))
    if bad_q.size:
        raise table.error(int(bad_q[0]), f"solution quality Q={d[bad_q[0], 3]:g} is not 1..5")
    return GnssData(
        t_ns=t_ns,
        llh=np.column_stack([np.deg2rad(d[:, 0]), np.deg2rad(d[:, 1]), d[:, 2]]),
        std_ned=d[:, 5:8].copy(),
        v_n=np.column_stack([d[:, 13], d[:, 14], -d[:, 15]]),
        std_v_n=d[:, 16:19].copy(),
        fix=np.array([int(FIX_OF_Q[k]) for k in q], dtype=np.int64),
        num_sats=d[:, 4].astype(np.int64),
    )


def _is_time(stamp: str) -> bool:
    try:
        np.datetime64(stamp, "ns")
    except ValueError:
        return False
    return True


def _one(folder: Path, pattern: str) -> Path:
    found = sorted(folder.glob(pattern))
    if len(found) != 1:
        raise DataError(folder, f"expected exactly one {pattern} file, found {len(found)}")
    return found[0]


def _imu_noise() -> ImuNoise:
    """IMU noise of this installation, in SI.

    The README's tuning values (0.0038 deg/s/sqrt(Hz), 70 ug/sqrt(Hz)) are the IMU's datasheet densities; on this
    car the engine vibration dominates: one-second averages of the stationary start give effective densities of
    0.048 / 0.035 / 0.004 deg/s/sqrt(Hz) (x/y/z) and 0.4-1.75 mg/sqrt(Hz). The filter uses the measured upper values.
    Bias instability: typical consumer-MEMS in-run values (36 deg/h, 2 mg) as first-order Gauss-Markov, tau 300 s.
    """
    tau_s = 300.0
    return ImuNoise(
        arw=math.radians(0.05),  # 0.05 deg/s/sqrt(Hz) -> rad/sqrt(s)
        vrw=1.5e-3 * earth.G0,  # 1.5 mg/sqrt(Hz) -> m/s/sqrt(s)
        gyro_bias_std=math.radians(0.01),  # 0.01 deg/s
        accel_bias_std=2e-3 * earth.G0,  # 2 mg
        gyro_bias_tau=tau_s,
        accel_bias_tau=tau_s,
    )


# The IMU's datasheet noise (TDK ICM-45686, drive_config.py), as a KF-GINS user configures it: the white-noise
# densities the README quotes, 0.0038 deg/s/sqrt(Hz) and 70 ug/sqrt(Hz); the README's bias random-walk densities
# (3.8e-5 deg/s^2/sqrt(Hz), 7 ug/s/sqrt(Hz)) as first-order Gauss-Markov with KF-GINS's default 1 h correlation
# time, sigma = q sqrt(tau / 2): 5.8 deg/h and 0.30 mg. About 10x below what the vibrating car shows (_imu_noise).
DATASHEET_TAU_S = 3600.0
DATASHEET_NOISE = ImuNoise(
    arw=math.radians(0.0038),
    vrw=70e-6 * earth.G0,
    gyro_bias_std=math.radians(3.8e-5) * math.sqrt(DATASHEET_TAU_S / 2.0),
    accel_bias_std=7e-6 * earth.G0 * math.sqrt(DATASHEET_TAU_S / 2.0),
    gyro_bias_tau=DATASHEET_TAU_S,
    accel_bias_tau=DATASHEET_TAU_S,
)


def _initial_state(imu: ImuData, gnss: GnssData, pos_path: Path) -> tuple[InitialState, dict]:
    """Initial state at the first IMU sample after the first GNSS epoch faster than START_SPEED_MPS."""
    v_n_gnss = gnss.v_n
    assert v_n_gnss is not None  # load_gnss always reads the velocity
    speed = np.hypot(v_n_gnss[:, 0], v_n_gnss[:, 1])
    moving = np.flatnonzero(speed > START_SPEED_MPS)
    if moving.size == 0:
        raise DataError(pos_path, f"the GNSS speed never exceeds {START_SPEED_MPS} m/s")
    k_gnss = int(moving[0])
    k0 = int(np.searchsorted(imu.t_ns, gnss.t_ns[k_gnss], side="right"))
    t0 = int(imu.t_ns[k0])

    # Roll and pitch by accelerometer levelling over the stationary start. Valid at t0 because the car has just left
    # rest (about 2 s earlier) on the same spot; the 1 deg std covers the change of road slope.
    t_still = gnss.t_ns[int(np.argmax(speed > STILL_SPEED_MPS))] - NS
    still = imu.t_ns < t_still
    dt = np.diff(imu.t_ns[still]) / NS
    f_b = imu.dvel[still][1:].sum(axis=0) / dt.sum()
    roll, pitch = level(f_b)

    def at_t0(values):
        return np.array([np.interp(t0, gnss.t_ns, values[:, i]) for i in range(3)])

    v_n = at_t0(v_n_gnss)
    euler = np.array([roll, pitch, math.atan2(v_n[1], v_n[0])])  # yaw = GNSS course (source: yaw_align)
    llh_antenna = at_t0(gnss.llh)  # the epoch's antenna position carried the <= 10 ms to t0
    lever_n = euler_to_dcm(euler) @ LEVER_ARM_B
    llh = earth.ned_to_llh(-lever_n, llh_antenna)
    initial = InitialState(
        t_ns=t0,
        llh=llh,
        v_n=v_n,
        euler=euler,
        std_pos_ned=np.maximum(gnss.std_ned[k_gnss], 0.05),
        std_v_n=np.full(3, 0.1),
        std_euler=np.deg2rad([1.0, 1.0, 3.0]),
        std_gyro_bias=np.full(3, math.radians(0.2)),  # README: initial gyro bias uncertainty 0.2 deg/s
        std_accel_bias=np.full(3, 0.2),  # README: initial accel bias uncertainty 0.2 m/s^2
    )
    notes = {
        "stationary_window_s": [int(imu.t_ns[0]) / NS, int(t_still) / NS],
        "stationary_f_b_mps2": f_b.tolist(),
        "start_gnss_epoch_s": int(gnss.t_ns[k_gnss]) / NS,
    }
    return initial, notes


def load(folder, prefilter: str = "zero-phase") -> Dataset:
    """The drive_0708 folder -> Dataset (times: GPS ns since 1980-01-06; truth = the RTK-fixed epochs)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "dataset folder not found")
    imu = load_imu(_one(folder, "imu_*.csv"), prefilter)
    pos_path = _one(folder, "*.pos")
    gnss = load_gnss(pos_path)
    assert gnss.v_n is not None  # load_gnss always reads the velocity
    fixed = gnss.fix == int(FixType.RTK_FIXED)
    truth = Truth(
        t_ns=gnss.t_ns[fixed],
        llh=gnss.llh[fixed],
        v_n=gnss.v_n[fixed],
        euler=None,
        source="RTK GNSS of the same receiver (not independent); RTK-fixed epochs only, at the antenna",
        at_antenna=True,
    )
    initial, start_notes = _initial_state(imu, gnss, pos_path)
    config = NavConfig(imu_noise=_imu_noise(), lever_arm_b=LEVER_ARM_B.copy(), start_t_ns=initial.t_ns)
    rate_hz = (len(imu) - 1) * NS / int(imu.t_ns[-1] - imu.t_ns[0])
    notes = {
        "source": "rtklibexplorer/GNSS_IMU data/drive_0708 (BSD-3), car, IMU TDK ICM-45686 per drive_config.py",
        "time": "GPS seconds since 1980-01-06 (GPST)",
        "imu_rate_hz": rate_hz,
        "gnss_rate_hz": (len(gnss) - 1) * NS / int(gnss.t_ns[-1] - gnss.t_ns[0]),
        "imu_prefilter": prefilter,
        "imu_increments": "trapezoid rule on rates: dtheta_k = (w_{k-1} + w_k) / 2 * dt_k",
        "imu_time_offset_s": IMU_TIME_OFFSET_NS / NS,
        "imu_misalign_deg": IMU_MISALIGN_DEG.tolist(),
        "noise": "white noise measured on the stationary start (engine vibration, about 10x the datasheet); "
        "bias Gauss-Markov 0.01 deg/s, 2 mg, tau 300 s",
        "truth": "no independent reference: the same receiver's RTK fixes; no attitude truth",
        **start_notes,
    }
    return Dataset("rtklibexplorer_drive_0708", imu, gnss, config, initial, truth, notes)
