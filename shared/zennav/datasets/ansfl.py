"""ANSFL "Quadrotor Dead Reckoning with Multiple Inertial Sensors": DJI Phantom 4 RTK flights with an Xsens DOT IMU.

One flight folder (``Horizontal/path_N``, ``Vertical/path_N``, ``StraightLine/path_N``) holds ``GT.csv`` (10 Hz DJI
RTK/flight-controller export: time [s], distance, speed, compass_heading, pitch, roll [deg], height_above_takeoff [m],
North, East, Down [m] relative to the first sample) and ``IMU_1.csv.gz`` (120 Hz Xsens DOT: time [s], Euler x/y/z
[deg], Acc x/y/z [m/s^2, z about +g when level], Gyr x/y/z [deg/s]); StraightLine folders add ``GTExtended.csv``
with latitude/longitude. Times are seconds since the first GT sample (the files carry no absolute GPS time).

Mounting (not documented; estimated from the data, all 61 flights): the Xsens axes are forward-left-up on the drone.
- Gravity: the accelerometer z reads +9.5..10.9 m/s^2 over each flight's first second (z up), and the mean of
  (GT specific force, from the second derivative of GT positions rotated by the GT attitude, minus the FLU-flipped
  accelerometer) is below 0.45 m/s^2 per axis on every flight.
- Gyro against the body rates differentiated from the GT attitude (10 Hz, both averaged over the same 0.1 s
  intervals, after the time offset below): with ``diag(1, -1, -1)`` the residual is 1.3-3.4 deg/s RMS for body
  rates of 3-90 deg/s RMS; any other axis permutation or sign is tens of deg/s off. The Xsens yaw agrees too:
  90 deg - Euler_Z (ENU yaw to NED heading) is within about 5 deg of the GT heading (magnetic declination there
  is about 5 deg E).
- A per-flight least-squares rotation (Wahba/SVD fit of GT body rates to IMU rates) on top of the flip is
  rotation vector [-0.30, -1.57, -0.98] deg (median; per-axis spread 0.3/0.6/0.4 deg) on the 45 flights of
  Horizontal 1-27, Vertical 1-14 and StraightLine 1-4, and [-0.45, +0.76, +0.14] deg on Vertical 15-30 (the
  authors' "second_exp": the sensor was apparently re-seated). MOUNT_ROTVEC_DEG is the median over all 61 flights,
  [-0.35, -1.44, -0.95] deg: within 0.5 deg for the first group, about 2.3 deg off (mostly about y) for Vertical
  15-30. It fits the GT attitude residual from 1.5-3.4 to 1.3-3.3 deg/s RMS; the initial attitude 1-sigma covers it.
  ``C_b_s = rotvec_to_dcm(MOUNT_ROTVEC_DEG) @ diag(1, -1, -1)`` maps sensor axes to body FRD; the attitude truth
  and the initial attitude are the DJI body attitude, so the body frame here is the drone's.

Time alignment: the README says the IMU time is synchronized to GT; it is not. Cross-correlating the IMU body
rates with the GT attitude rates (``estimate_time_offset``, least squares over shifts of +-1.5 s, refined to 2 ms)
gives offsets t_GT = t_IMU + offset of -0.69 to +0.65 s, constant within 10 ms inside each recording session and
drifting about -2 ms per consecutive path (Horizontal 8-15: -0.404 ... -0.419 s, 16-21: +0.359 ... +0.350 s, 22-27:
+0.647 ... +0.639 s; Vertical 1-7 about 0, 9-14 about -0.045, 15-22 about -0.08 s). At tau = 0 the residual is
2-120 deg/s RMS instead of 1.3-3.4, so the loader estimates and applies the offset per flight by default
(``time_offset_s=None``); a number forces it. The estimate uses the GT attitude, i.e. the reference, as a
calibration step.

IMU time repairs: the time column is a 120 Hz grid; 5 files hold a row stamped like its successor after a double step
(``t, t+2d, t+2d``: the orientation columns show the row is at t+d); it is moved to t+d. One file (Vertical/path_21)
wraps at 2^32 us (-4294.967 s); later times are unwrapped. Any other non-increasing time is a DataError.

IMU data: FLU-flipped and mounted as above, deg/s -> rad/s, rates -> increments by the trapezoid rule
(ImuData.from_rates); samples outside the GT time span are dropped. No prefilter.

GNSS aiding = the GT positions (there is no separate GNSS), converted to geodetic about an origin: the first
GTExtended latitude/longitude/altitude where it exists (altitude above sea level used as the height: the geoid
offset does not matter), else the README's approximate 32.8257 N, 34.9560 E at height 0 + height_above_takeoff of
the first sample. Only relative geometry matters (the Earth-rate and gravity changes over a few km are
negligible). Position 1-sigma GNSS_STD_M = 0.05 m north/east, 0.3 m down. Horizontal: DJI RTK about 1 cm + 1 ppm
(DJI's figure, not verified), the unknown antenna-to-IMU lever arm (about 0.1-0.2 m on a Phantom) swings a few cm
with the +-30 deg roll, plus 10 Hz time-tag jitter at 3-7 m/s. Down: GT Down is the height above take-off rounded to
0.1 m (uniform: 0.029 m) and on fast climbs (Vertical 3, 16, 21, 23, 29: up to 7 m/s) it disagrees with the
accelerometers by decimetres: with 0.05 m the filter rejects 36-74 fixes per flight and tracks 0.5-2.6 m
horizontal RMS; with 0.3 m none or 1 and 6-8 cm. No GNSS velocity: velocity differentiated from the same positions
carries no new information.

Truth = the same GT (positions, Savitzky-Golay velocity over 1 s, DJI flight-controller attitude rounded to 0.1 deg).
It is honest only for scoring outage windows, where the GT positions are withheld from the filter.

Initial state at the first IMU sample inside the GT span: GT position, GT-derived velocity and GT attitude
interpolated there, heading known.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from zennav.datasets.errors import DataError, read_table, read_text
from zennav.nav import earth
from zennav.nav.rotation import euler_to_dcm, rotvec_to_dcm, wrap_angle
from zennav.nav.types import (
    NS,
    Dataset,
    FixType,
    GnssData,
    ImuData,
    ImuNoise,
    InitialState,
    NavConfig,
    Truth,
)

GROUPS = {"Horizontal": 27, "Vertical": 30, "StraightLine": 4}  # flight folders path_1..N of each group
GT_COLUMNS = ("time", "distance", "speed", "compass_heading", "pitch", "roll", "height_above_takeoff",
              "north", "east", "down")
GTX_COLUMNS = ("time", "latitude", "longitude", "altitude_above_sealevel", "north", "east", "down",
               "xspeed", "yspeed", "zspeed", "roll", "pitch", "compass_heading")
IMU_COLUMNS = ("time", "euler_x", "euler_y", "euler_z", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z")
ORIGIN_DEG = (32.8257, 34.9560)  # README: "near 32.8257 N, 34.9560 E" (approximate; only relative geometry matters)
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])
MOUNT_ROTVEC_DEG = np.array([-0.35, -1.44, -0.95])  # residual sensor-to-body rotation after the flip (see module doc)
C_B_S = rotvec_to_dcm(np.deg2rad(MOUNT_ROTVEC_DEG)) @ FLU_TO_FRD  # Xsens sensor axes -> drone body FRD
WRAP_S = 2**32 * 1e-6  # the IMU time counter wraps at 2^32 microseconds [s]
GNSS_STD_M = np.array([0.05, 0.05, 0.3])  # 1-sigma of the GT positions as aiding, north/east/down [m] (module doc)
MAX_OFFSET_S = 1.5  # time-offset search range [s]
SG_WINDOW_S = 1.0  # Savitzky-Golay window of the GT velocity [s]


def _header(path: Path, expected: tuple[str, ...]) -> None:
    """DataError at line 1 unless the csv header names ``expected`` (case, spaces and '(unit)' ignored)."""
    text = read_text(path)
    first = text.split("\n", 1)[0]
    names = tuple(tok.split("(")[0].strip().lower() for tok in first.split(","))
    if names != expected:
        raise DataError(path, f"header {first.strip()!r} does not name the columns {', '.join(expected)}", 1)


def _table(path: Path, expected: tuple[str, ...]):
    _header(path, expected)
    table = read_table(path, len(expected), delimiter=",", skip_header=1)
    table.require_finite()
    return table


def _imu_times(table) -> tuple[np.ndarray, dict]:
    """IMU time column [s] -> strictly increasing ns, with the two repairs of the module doc (counted in notes)."""
    t = table.data[:, 0].copy()
    wraps = np.flatnonzero(np.diff(t) < -0.5 * WRAP_S)
    for k in wraps:
        t[k + 1:] += WRAP_S
    d = np.diff(t)
    nominal = float(np.median(d)) if d.size else 0.0
    moved = 0
    for k in np.flatnonzero(d == 0.0):
        if k > 0 and abs(t[k] - t[k - 1] - 2.0 * nominal) < 0.1 * nominal:
            t[k] -= nominal
            moved += 1
    t_ns = np.round(t * 1e9).astype(np.int64)
    table.require_increasing(t_ns, "IMU time")
    return t_ns, {"imu_time_wraps": len(wraps), "imu_rows_restamped": moved}


def load_gt(path) -> tuple[np.ndarray, np.ndarray]:
    """GT.csv -> (t_ns (K,), data (K, 10) in file units); times strictly increasing and evenly spaced."""
    path = Path(path)
    table = _table(path, GT_COLUMNS)
    t_ns = np.round(table.data[:, 0] * 1e9).astype(np.int64)
    table.require_increasing(t_ns, "GT time")
    if len(t_ns) < 5:
        raise DataError(path, f"{len(t_ns)} GT rows; at least 5 are needed")
    dt = np.diff(t_ns)
    uneven = np.flatnonzero(np.abs(dt - np.median(dt)) > 0.01 * np.median(dt))
    if uneven.size:
        raise table.error(int(uneven[0]) + 1, "GT times are not evenly spaced (the velocity filter needs a fixed rate)")
    return t_ns, table.data


def load_origin(folder: Path, gt: np.ndarray) -> tuple[np.ndarray, str]:
    """Geodetic origin (lat, lon [rad], h [m]) of the GT NED frame and how it was chosen."""
    path = folder / "GTExtended.csv"
    if path.is_file():
        row = _table(path, GTX_COLUMNS).data[0]
        if np.any(row[4:7] != 0.0):
            raise DataError(path, "the first row's North/East/Down are not 0: it is not the GT origin", 2)
        return (np.array([math.radians(row[1]), math.radians(row[2]), row[3]]),
                "GTExtended.csv first row (latitude, longitude, altitude above sea level as height)")
    return (np.array([math.radians(ORIGIN_DEG[0]), math.radians(ORIGIN_DEG[1]), gt[0, 6]]),
            f"approximate: README site {ORIGIN_DEG[0]} N, {ORIGIN_DEG[1]} E, height = height above take-off")


def gt_velocity(t_ns: np.ndarray, ned: np.ndarray) -> np.ndarray:
    """NED velocity [m/s] of evenly spaced GT positions: Savitzky-Golay (quadratic) derivative over SG_WINDOW_S."""
    dt = float(np.median(np.diff(t_ns))) / NS
    window = round(SG_WINDOW_S / dt) | 1
    if window > len(t_ns):
        window = len(t_ns) if len(t_ns) % 2 else len(t_ns) - 1
    return savgol_filter(ned, window, min(2, window - 1), deriv=1, delta=dt, axis=0, mode="interp")


def _mean_over(t_s: np.ndarray, x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean of the sampled signal x (N, 3) over each interval [a, b] (trapezoid integral; times in s)."""
    cum = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t_s)[:, None], 0)])
    integral = np.stack([np.interp(b, t_s, c) - np.interp(a, t_s, c) for c in cum.T], -1)
    return integral / (b - a)[:, None]


def gt_body_rates(t_ns: np.ndarray, euler: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body angular rate [rad/s] between consecutive GT attitudes: (midpoint times [s], (K-1, 3) rates)."""
    C = euler_to_dcm(euler)
    dC = np.einsum("kji,kjl->kil", C[:-1], C[1:])  # C_k^T C_{k+1}
    angle = np.arccos(np.clip(0.5 * (np.trace(dC, axis1=1, axis2=2) - 1.0), -1.0, 1.0))
    axis = np.stack([dC[:, 2, 1] - dC[:, 1, 2], dC[:, 0, 2] - dC[:, 2, 0], dC[:, 1, 0] - dC[:, 0, 1]], -1)
    scale = np.where(angle > 1e-9, angle / np.maximum(2.0 * np.sin(angle), 1e-12), 0.5)
    t_s = t_ns / NS
    return 0.5 * (t_s[1:] + t_s[:-1]), axis * scale[:, None] / np.diff(t_s)[:, None]


def estimate_time_offset(imu_t_ns, omega_b, gt_t_ns, gt_euler) -> tuple[float, float]:
    """Offset [s] with t_GT = t_IMU + offset that best fits the IMU body rates (N, 3) [rad/s] to the GT attitude
    rates (least squares of the rates averaged over the GT intervals; 20 ms grid over +-MAX_OFFSET_S, 2 ms grid
    around its best, parabolic vertex) and the residual RMS [rad/s] there. ValueError when they overlap by less
    than 2 * MAX_OFFSET_S + 1 s."""
    t_imu = np.asarray(imu_t_ns) / NS
    t_mid, w_gt = gt_body_rates(gt_t_ns, gt_euler)
    half = 0.5 * float(np.median(np.diff(gt_t_ns))) / NS

    def costs(taus, margin):
        use = (t_mid - half > t_imu[0] + margin[1]) & (t_mid + half < t_imu[-1] + margin[0])
        if np.count_nonzero(use) < 10:
            raise ValueError("IMU and GT overlap too little to estimate the IMU time offset (pass time_offset_s)")
        out = [np.mean(np.sum((w_gt[use] - _mean_over(t_imu + tau, omega_b, t_mid[use] - half,
                                                      t_mid[use] + half)) ** 2, 1)) for tau in taus]
        return np.array(out)

    coarse = np.arange(-MAX_OFFSET_S, MAX_OFFSET_S + 1e-9, 0.02)
    tau0 = float(coarse[int(np.argmin(costs(coarse, (coarse[0], coarse[-1]))))])
    fine = tau0 + np.arange(-0.03, 0.0300001, 0.002)
    c = costs(fine, (fine[0], fine[-1]))
    k = int(np.clip(np.argmin(c), 1, len(fine) - 2))
    den = c[k - 1] - 2.0 * c[k] + c[k + 1]
    step = 0.5 * (c[k - 1] - c[k + 1]) / den if den > 0 else 0.0
    return float(fine[k] + np.clip(step, -1.0, 1.0) * 0.002), float(math.sqrt(c.min()))


def _interp(t_query, t_ns, values) -> np.ndarray:
    return np.stack([np.interp(t_query, t_ns, values[:, i]) for i in range(values.shape[1])], -1)


def _imu_noise() -> ImuNoise:
    """IMU noise for the filter, SI. No stationary part exists in these flights to measure it at rest.

    The Xsens DOT datasheet gives 0.007 deg/s/sqrt(Hz) and 120 ug/sqrt(Hz) white noise, 10 deg/h and 0.03 mg bias
    instability. In flight the propeller vibration dominates: the second differences of the 120 Hz samples (which
    remove the motion) give 0.17-0.23 / 0.32-1.17 / 0.26-0.34 deg/s/sqrt(Hz) (x/y/z) and 9-80 mg/sqrt(Hz). With the
    datasheet values the filter is overconfident and rejects GT fixes (horizontal RMS 0.8-10 m with full GNSS on 3 of
    4 flights tried); with the vibration values it tracks (2-7 cm) but 10 s outages drift 9-30 m. 0.1 deg/s/sqrt(Hz)
    and 10 mg/sqrt(Hz) (between the two, picked on 6 of these flights, so tuned on the data it is scored on) track
    within 2-11 cm and drift 2-6 m on those 6. Bias: widened datasheet-class values, 0.05 deg/s and 5 mg,
    Gauss-Markov tau 300 s.
    """
    tau_s = 300.0
    return ImuNoise(
        arw=math.radians(0.1),  # 0.1 deg/s/sqrt(Hz) -> rad/sqrt(s)
        vrw=10e-3 * earth.G0,  # 10 mg/sqrt(Hz) -> m/s/sqrt(s)
        gyro_bias_std=math.radians(0.05),
        accel_bias_std=5e-3 * earth.G0,
        gyro_bias_tau=tau_s,
        accel_bias_tau=tau_s,
    )


def load(folder, time_offset_s: float | None = None) -> Dataset:
    """One flight folder -> Dataset (times: ns since the first GT sample). time_offset_s: t_GT = t_IMU + offset;
    None estimates it (see the module doc)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "flight folder not found")
    gt_path, imu_path = folder / "GT.csv", folder / "IMU_1.csv.gz"
    t_gt, gt = load_gt(gt_path)
    imu_table = _table(imu_path, IMU_COLUMNS)
    t_imu, repairs = _imu_times(imu_table)
    if len(t_imu) < 2:
        raise DataError(imu_path, "fewer than two IMU rows")
    omega_b = np.deg2rad(imu_table.data[:, 7:10]) @ C_B_S.T
    f_b = imu_table.data[:, 4:7] @ C_B_S.T
    euler_gt = np.column_stack([np.deg2rad(gt[:, 5]), np.deg2rad(gt[:, 4]), wrap_angle(np.deg2rad(gt[:, 3]))])

    residual = None
    if time_offset_s is None:
        try:
            time_offset_s, residual = estimate_time_offset(t_imu, omega_b, t_gt, euler_gt)
        except ValueError as exc:
            raise DataError(imu_path, str(exc)) from None
    t_imu = t_imu + round(time_offset_s * NS)
    inside = (t_imu >= t_gt[0]) & (t_imu <= t_gt[-1])
    if np.count_nonzero(inside) < 2:
        raise DataError(imu_path, f"no IMU samples inside the GT time span after the {time_offset_s:+.3f} s offset")
    imu = ImuData.from_rates(t_imu[inside], omega_b[inside], f_b[inside])

    origin, origin_note = load_origin(folder, gt)
    ned = gt[:, 7:10]
    llh = earth.ned_to_llh(ned, origin)
    v_n = gt_velocity(t_gt, ned)
    std = np.tile(GNSS_STD_M, (len(t_gt), 1))
    gnss = GnssData(t_gt, llh, std, fix=np.full(len(t_gt), int(FixType.RTK_FIXED), dtype=np.int64))
    truth = Truth(
        t_ns=t_gt, llh=llh, v_n=v_n, euler=euler_gt,
        source="DJI RTK/flight-controller GT (the same positions aid the filter: honest only inside outages)",
        at_antenna=True,
    )

    t0 = int(imu.t_ns[0])
    yaw_unwrapped = np.unwrap(euler_gt[:, 2])
    euler0 = np.array([np.interp(t0, t_gt, euler_gt[:, 0]), np.interp(t0, t_gt, euler_gt[:, 1]),
                       float(wrap_angle(np.interp(t0, t_gt, yaw_unwrapped)))])
    initial = InitialState(
        t_ns=t0,
        llh=earth.ned_to_llh(_interp(t0, t_gt, ned), origin),
        v_n=_interp(t0, t_gt, v_n),
        euler=euler0,
        std_pos_ned=GNSS_STD_M.copy(),
        std_v_n=np.full(3, 0.2),
        std_euler=np.deg2rad([2.0, 2.0, 3.0]),  # DJI attitude + mounting spread (2.3 deg on Vertical 15-30)
        std_gyro_bias=np.full(3, math.radians(0.2)),
        std_accel_bias=np.full(3, 0.1),
        heading_known=True,
    )
    config = NavConfig(imu_noise=_imu_noise(), lever_arm_b=np.zeros(3), start_t_ns=t0)
    group = folder.parent.name
    notes = {
        "source": "ansfl/Quadrotor-Dead-Reckoning-with-Multiple-Inertial-Sensors (CC BY 4.0), DJI Phantom 4 RTK, "
                  "Xsens DOT IMU_1",
        "flight": f"{group}/{folder.name}",
        "time": "seconds since the first GT sample (no absolute GPS time in the files)",
        "imu_rate_hz": (len(imu) - 1) * NS / int(imu.t_ns[-1] - imu.t_ns[0]),
        "gnss_rate_hz": (len(gnss) - 1) * NS / int(gnss.t_ns[-1] - gnss.t_ns[0]),
        "imu_increments": "trapezoid rule on rates: dtheta_k = (w_{k-1} + w_k) / 2 * dt_k",
        "imu_time_offset_s": time_offset_s,
        "imu_time_offset": "estimated from GT attitude rates" if residual is not None else "given",
        "imu_time_fit_rms_dps": None if residual is None else math.degrees(residual),
        **repairs,
        "mounting": "sensor FLU -> body FRD, then rotation vector "
                    f"{MOUNT_ROTVEC_DEG.tolist()} deg (estimated from the data)",
        "origin": origin_note,
        "gnss": f"GT positions as RTK fixes, 1-sigma N/E/D {GNSS_STD_M.tolist()} m, no velocity",
        "truth": "the same GT: positions, Savitzky-Golay velocity, DJI attitude (0.1 deg)",
    }
    return Dataset(f"ansfl_{group}_{folder.name}", imu, gnss, config, initial, truth, notes)
