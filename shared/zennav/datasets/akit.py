"""A-KIT / Snapir AUV (ANSFL, University of Haifa; ECA A18D with an iXblue Phins Subsea INS and a Teledyne RDI
Workhorse Navigator DVL, Haifa, 2022-06-08): 13 segments of 400 s, ``TrajectoryN/{IMU,DVL,GT}_trajectoryN.csv``.
The data folder's README says what each file is, where it comes from and what its providers checked; read it.

IMU (``IMU_trajectoryN.csv.gz``, 100 Hz, time = linspace(0, 400, 40000) [s], ACC X/Y/Z [m/s^2], GYRO X/Y/Z [rad/s]):
- **y axis flipped**: these are the authors' pre-fix IMU files, whose y axis is sign-flipped against the GT/DVL body
  frame (forward-right-down). README evidence: raw gyro-y is anti-correlated with the GT pitch rate (r = -0.97 on
  T12) and the accelerometer roll with the GT roll (r = -0.95); after negating ACC Y and GYRO Y, gyro-only attitude
  on T12 stays within 0.44/0.26/0.10 deg of the GT over 400 s, without it it drifts to 8.3 deg in pitch (retimed and
  skew-corrected as below: within 0.01 deg with the flip, on every segment within 0.3 deg). The loader negates
  both columns (C_B_S); tests/unit/test_akit.py checks it (``gyro_attitude``).
- **rounded**: gyro to q_g = 1e-4 rad/s (20.6 deg/h), accelerometer to q_a = 1e-4 m/s^2. The vehicle's own motion
  dithers the rounding (second differences of the 100 Hz samples show 1.6e-4 to 8.8e-4 rad/s and 0.008 to
  0.046 m/s^2 per sample, well above q), so it acts as white noise of variance q^2 / 12 per sample, i.e. a random
  walk q / sqrt(12) * sqrt(dt): 2.9e-6 rad/sqrt(s) (0.0099 deg/sqrt(h)) and 2.9e-6 m/s/sqrt(s). For the gyro
  this dominates a Phins-class FOG's own angle random walk (order 0.001-0.005 deg/sqrt(h), not verified
  against a datasheet): ARW = the rounding figure. For the accelerometer it does not: a navigation-grade
  accelerometer has about 20-50 ug/sqrt(Hz) (2-5e-4 m/s/sqrt(s)); VRW = 50 ug/sqrt(Hz). Biases (``_imu_noise``):
  Phins class (gyro 0.01 deg/h, accelerometer 50 ug), widened 5x / 2x for what the files' processing left
  unknown; Gauss-Markov 1 h.
- IMU rates -> increments by the trapezoid rule (ImuData.from_rates).

Time base (``retime=True``, default): the files' time columns are linspace(0, 400, N), which stamps the 400 rows of
1 Hz GT and DVL 1.0025 s apart (and the 40000 IMU rows 10.0003 ms apart): against the IMU the GT/DVL time runs
0.25 % fast (400/399). Evidence: the IMU-vs-GT skew estimated (below) on 50 s windows drifts by +0.12 s per window
with the file times on every segment (T2 +0.53 ... +1.38 s, T5 -0.44 ... +0.39 s, T12 -0.41 ... +0.43 s), that is
the README's "lag of 0.7-0.95 s" is this drift's mean; with row k at k / 1 Hz (GT, DVL) and k / 100 Hz (IMU), the
README's rates, it is constant within 0.01 s (T2 +0.45, T5 -0.50, T12 -0.47 s) and the rate-fit residual falls
(T12 0.13 -> 0.004 deg/s, T2 -> 0.019 deg/s). The loader retimes the rows so; ``retime=false`` keeps the columns.

Skew: on the retimed base the IMU-vs-GT skew is +0.41 to +0.46 s (T1-T4, T7-T10, T13) or -0.43 to -0.50 s (T5, T6,
T11, T12): about half a GT interval either way. The loader estimates it per segment (``skew_s="auto"``, default)
with zennav.datasets.ansfl.estimate_time_offset: least squares of the IMU body rates, averaged over each 1 s GT
interval, against the body rates between consecutive GT attitudes, over shifts of +-1.5 s (20 ms grid, then 2 ms and
a parabolic vertex; the range is 3x the skews found). All three axes take part, so the straight segments (T12:
0.01 rad of yaw change) are fitted on their roll/pitch motion from the waves, where a yaw-rate-only
cross-correlation has nothing to lock on. The Earth and transport rates (about 7e-5 rad/s) are left in the IMU
rates: a slowly varying term that does not move the minimum. Convention: t_GT = t_IMU + skew_s; the IMU times are
shifted onto the GT time base. A number (``skew_s=0.4``) forces it.

Reference point and DVL skew: the README takes the DVL and the GT to share their time grid and place; they do not.
The DVL's body velocity v_d(t) matches the reference's body velocity C_bn v_n plus omega_nb_b x l_b, the velocity
of a point at l_b from the reference point, best at t + dvl_skew with dvl_skew +1.40 to +1.50 s on T1-T4, T7-T10,
T13 and +0.50 to +0.60 s on T5, T6, T11, T12: the DVL lags the IMU by 1.0-1.05 s on every segment, and the GT sits
half a sample either side of both. Fitted jointly (least squares per trajectory, lag on a 50 ms grid) l_b is the
same on every segment: median (-1.87, -0.04, +0.22) m, spread 0.12 / 0.03 / 0.08 m (1-sigma over the 13). The
IMU is there too, not at the reference point: a filter given the reference's velocity at the IMU and the DVL there
with that lever arm rejects the DVL in the turns (T2: 36 of 398 samples, innovations 0.1-0.15 m/s per beam at
11 deg/s, the INS velocity following the DVL point), with both at that point it fuses all. So the Phins/Delph
output point is 1.9 m forward of the IMU and the DVL velocities are given at (or transformed to) the IMU:
IMU_FROM_REF_B, a vehicle constant. The loader moves the reference to the IMU (``ref_lever=true``, default):
    llh_IMU = llh + C_nb l_b (as NED), v_n,IMU = v_n + C_nb (omega_nb_b x l_b),  l_b = IMU_FROM_REF_B,
with omega_nb_b from consecutive GT attitudes, for the truth, the initial state, the derived GNSS and depth;
``ref_lever=false`` uses the reference as it is. The DVL's lever arm from the IMU is then 0. With the lever and the
skew the DVL-vs-reference residual falls from 0.05-0.2 m/s RMS (y axis, turning segments) to 0.005-0.014 m/s on
11 segments (T9 0.035, T11 0.047). The loader estimates the DVL skew per segment (``dvl_skew_s="auto"``,
``estimate_dvl_skew``; a number forces it) and shifts the DVL times onto the GT base. What remains (not
calibrated: the filter's beam-bias and scale states meet it): the DVL frame is taken as the body frame although
the same fit gives a mounting of about 0.07 deg pitch and 0.1-0.3 deg yaw and a scale -0.4..+0.8 %, varying
between segments.

Times: the files carry no absolute time; t_ns = ns since the first GT row (GT time 0).

GT (``GT_trajectoryN.csv``, 1 Hz: longitude, latitude [rad], altitude [m, negative under water], v_N/E/D [m/s],
roll, pitch, yaw [rad]): a Delph post-processed solution of the same Phins aided by the same DVL, so a high-quality
reference, **not independent** of the IMU/DVL. Moved to the IMU (above), it is the Truth (llh, v_n, euler) and gives
the initial state.

Derived sensors (none of these is a recording; notes say so too):
- **DVL beams, derived**: the file gives the DVL's velocity in the body frame at 1 Hz. The four Janus beams of the
  Workhorse (tilt 30 deg) are computed from it, v_beam = B v_d (zennav.nav.beams), all valid, alongside the given
  velocity_d. Layout "x" (beams at 45, 135, 225, 315 deg from forward): the Haifa group's DVL papers on this vehicle
  (BeamsNet, A-KIT) model the beams at psi_i = 45 + 90 (i - 1) deg; the mounting is not documented, and with beams
  derived from a 3-D velocity the choice changes no information, only which beam pairs are "parallel". DVL frame =
  body frame (the mounting is not documented: zero), at the IMU (lever arm 0; above). The filter is told
  the README's 0.02 m/s per beam (NavConfig dvl_beam_std_mps, dvl_velocity_std_mps).
- **Depth, derived** from the GT altitude at the IMU: depth = -alt + a constant bias (depth_bias_m, default 0) +
  seeded white noise (depth_std_m, default 0.05 m: a 0.1 % full-scale pressure sensor of 50 m) at the GT rate
  (1 Hz); the water surface is height 0 (NavConfig.depth_surface_h_m).
- **GNSS, derived**: an AUV has GNSS only at the surface. Fixes from the GT at the IMU (lever arm 0) at 1 Hz, only
  for the first gnss_s seconds of the run (default 60 s, "at the surface" to align and train; 0: none), with seeded
  white noise of GNSS_STD_M (position) and GNSS_VEL_STD_MPS (velocity), the reported 1-sigma.
- **DVL anomalies** (zennav.datasets.dvl_anomalies) where asked (``anomalies=<spec>``), recorded in notes.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from zennav.datasets import dvl_anomalies
from zennav.datasets.ansfl import estimate_time_offset, gt_body_rates
from zennav.datasets.errors import DataError, read_table, read_text
from zennav.nav import earth
from zennav.nav.beams import beams_from_velocity, janus_directions
from zennav.nav.rotation import euler_to_dcm, euler_to_quat, quat_multiply, quat_to_euler, wrap_angle
from zennav.nav.types import (
    NS,
    Dataset,
    DepthData,
    DvlData,
    FixType,
    GnssData,
    ImuData,
    ImuNoise,
    InitialState,
    NavConfig,
    Truth,
)

TRAJECTORIES = 13  # TrajectoryN, N = 1..13
IMU_COLUMNS = ("time", "acc x", "acc y", "acc z", "gyro x", "gyro y", "gyro z")
DVL_COLUMNS = ("time", "dvl x", "dvl y", "dvl z")
GT_COLUMNS = ("time", "longitude", "latitude", "altitude", "v north", "v east", "v down", "roll", "pitch", "yaw")
C_B_S = np.diag([1.0, -1.0, 1.0])  # IMU file axes -> body FRD: the README's y flip (module doc)
Q_GYRO = 1e-4  # rounding step of the gyro columns [rad/s]
Q_ACCEL = 1e-4  # rounding step of the accelerometer columns [m/s^2]
DVL_TILT = math.radians(30.0)  # Workhorse Navigator beam tilt [rad]
DVL_LAYOUT = "x"
DVL_STD_MPS = 0.02  # README: Workhorse velocity 1-sigma [m/s]
GNSS_STD_M = np.array([0.5, 0.5, 1.0])  # derived surface fixes, 1-sigma N/E/D [m] (SBAS/DGPS class)
GNSS_VEL_STD_MPS = 0.05  # derived surface fix velocity 1-sigma [m/s] (GNSS Doppler class)
GT_RATE_HZ = 1.0  # README: GT and DVL at 1 Hz (retime)
IMU_RATE_HZ = 100.0  # README: INS at 100 Hz (retime)
IMU_FROM_REF_B = np.array([-1.87, -0.04, 0.22])  # reference point -> IMU, body FRD [m]: estimated (module doc)
DVL_MAX_SKEW_S = 2.5  # search range of the DVL skew [s]
MIN_DEPTH_STD_M = 0.01  # the depth 1-sigma the filter is told at least (depth_std_m=0: a noiseless derived depth)


def folder_of(n: int, root: Path) -> Path:
    """The folder of TrajectoryN under the dataset folder root."""
    return root / f"Trajectory{n}"


def _table(path: Path, expected: tuple[str, ...]):
    """The csv at path, checked: its header names ``expected`` (case, spaces and '[unit]' ignored), all finite."""
    first = read_text(path).split("\n", 1)[0]
    names = tuple(tok.split("[")[0].strip().lower() for tok in first.split(","))
    if names != expected:
        raise DataError(path, f"header {first.strip()!r} does not name the columns {', '.join(expected)}", 1)
    table = read_table(path, len(expected), delimiter=",", skip_header=1)
    table.require_finite()
    return table


def _times(table, what: str, rate_hz: float | None) -> np.ndarray:
    """The rows' times [ns]: the file's time column, or with rate_hz row k at k / rate_hz (the module doc's
    retiming; the column must then be evenly spaced, as the files' linspace is)."""
    t_ns = np.round(table.data[:, 0] * NS).astype(np.int64)
    table.require_increasing(t_ns, f"{what} time")
    if len(t_ns) < 10:
        raise DataError(table.path, f"{len(t_ns)} {what} rows; at least 10 are needed")
    if rate_hz is None:
        return t_ns
    dt = np.diff(table.data[:, 0])
    uneven = np.flatnonzero(np.abs(dt - dt.mean()) > 1e-6 * dt.mean())
    if uneven.size:
        raise table.error(int(uneven[0]) + 1, f"{what} times are not evenly spaced: cannot retime (retime=false)")
    return np.round(np.arange(len(t_ns)) * (NS / rate_hz)).astype(np.int64)


def _imu_noise() -> ImuNoise:
    """Phins-class noise with the rounding of the files as the gyro's white noise (module doc), SI."""
    dt_s = 0.01
    return ImuNoise(
        arw=Q_GYRO / math.sqrt(12.0) * math.sqrt(dt_s),  # 2.9e-6 rad/sqrt(s) = 0.0099 deg/sqrt(h)
        vrw=50e-6 * earth.G0,  # 50 ug/sqrt(Hz) = 4.9e-4 m/s/sqrt(s) (rounding alone: 2.9e-6)
        gyro_bias_std=math.radians(0.05) / 3600.0,  # 5 x the Phins 0.01 deg/h
        accel_bias_std=100e-6 * earth.G0,  # 2 x 50 ug
        gyro_bias_tau=3600.0,
        accel_bias_tau=3600.0,
    )


def _rotvec_quats(rv: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) of rotation vectors rv (N, 3) [rad]."""
    angle = np.linalg.norm(rv, axis=1)
    half_sinc = 0.5 * np.sinc(angle / (2.0 * np.pi))  # sin(angle / 2) / angle, 0.5 at 0
    return np.column_stack([np.cos(0.5 * angle), half_sinc[:, None] * rv])


def gyro_attitude(imu: ImuData, t0_ns: int, euler0: np.ndarray, lat: float) -> tuple[np.ndarray, np.ndarray]:
    """Attitude from the gyros alone: q_nb propagated from euler0 [rad] at t0_ns through the increments after it,
    removing the Earth rate at latitude lat [rad] (transport rate neglected: 2 m/s gives 3e-7 rad/s). Returns
    (t_ns (M,), euler (M, 3) [rad]) at the IMU samples after t0_ns; a diagnostic of axes and skew.
    q_k = q_E(t_k) q_0 dq_1 ... dq_k, the Earth rotation about a fixed n axis in closed form and the body
    increments' running product by a prefix scan (log2 M vectorised steps)."""
    sel = imu.t_ns > t0_ns
    t_ns = imu.t_ns[sel]
    prod = _rotvec_quats(imu.dtheta[sel]).T  # (4, M); becomes dq_1 ... dq_k
    shift = 1
    while shift < prod.shape[1]:
        prod[:, shift:] = quat_multiply(prod[:, :-shift], prod[:, shift:])
        shift *= 2
    earth_q = _rotvec_quats(-np.outer((t_ns - t0_ns) / NS, earth.omega_ie_n(lat))).T
    q0 = euler_to_quat(euler0)[:, None]
    return t_ns, quat_to_euler(quat_multiply(earth_q, quat_multiply(q0, prod)).T)


def estimate_dvl_skew(t_gt_ns, v_n, euler, t_dvl_ns, v_d, lever_b) -> tuple[float, float]:
    """DVL skew [s] (t_GT = t_DVL + skew) that best fits the DVL velocities v_d (N, 3) [m/s, body] to the reference's
    C_bn v_n + omega_nb_b x lever_b at the shifted times (GT rows (K,) v_n [m/s], euler [rad]; rates between
    consecutive GT attitudes), each axis's mean residual removed; 20 ms grid over +-DVL_MAX_SKEW_S and a parabolic
    vertex. Returns (skew, residual RMS per axis [m/s]). ValueError when the DVL covers too little of the GT."""
    t_s, td = np.asarray(t_gt_ns) / NS, np.asarray(t_dvl_ns) / NS
    v_b = np.einsum("kji,kj->ki", euler_to_dcm(euler), v_n)
    t_mid, omega_nb_b = gt_body_rates(np.asarray(t_gt_ns), euler)
    use = (td > t_s[0] + DVL_MAX_SKEW_S + 1.0) & (td < t_s[-1] - DVL_MAX_SKEW_S - 1.0)
    if np.count_nonzero(use) < 10:
        raise ValueError("DVL and GT overlap too little to estimate the DVL skew (pass dvl_skew_s)")

    def cost(tau: float) -> float:
        q = td[use] + tau
        predicted = _interp(q, t_s, v_b) + np.cross(_interp(q, t_mid, omega_nb_b), lever_b)
        r = v_d[use] - predicted
        return float(np.mean((r - r.mean(axis=0)) ** 2))

    grid = np.arange(-DVL_MAX_SKEW_S, DVL_MAX_SKEW_S + 1e-9, 0.02)
    c = np.array([cost(float(tau)) for tau in grid])
    k = int(np.clip(np.argmin(c), 1, len(grid) - 2))
    den = c[k - 1] - 2.0 * c[k] + c[k + 1]
    step = float(np.clip(0.5 * (c[k - 1] - c[k + 1]) / den, -1.0, 1.0)) if den > 0 else 0.0
    tau = float(grid[k] + step * 0.02)
    return tau, math.sqrt(cost(tau))


def at_point(t_gt_ns, llh, v_n, euler, l_b) -> tuple[np.ndarray, np.ndarray]:
    """Positions (K, 3) [rad, rad, m] and NED velocities (K, 3) [m/s] of the point at l_b [m, body FRD] from the
    reference's (GT rows: llh, v_n, euler [rad]): r_n = C_nb l_b, v_n + C_nb (omega_nb_b x l_b), omega_nb_b
    between consecutive GT attitudes interpolated at the rows."""
    C_nb = euler_to_dcm(euler)
    t_mid, omega_nb_b = gt_body_rates(np.asarray(t_gt_ns), euler)
    omega_rows = _interp(np.asarray(t_gt_ns) / NS, t_mid, omega_nb_b)
    r_n = C_nb @ l_b
    dllh = np.stack(earth.ned_to_dllh(r_n.T, llh[:, 0], llh[:, 2]), -1)
    return llh + dllh, v_n + np.einsum("kij,kj->ki", C_nb, np.cross(omega_rows, l_b))


def _skew(option, name, estimate, path) -> tuple[float, float | None]:
    """(skew [s], fit residual or None when given) from a skew option "auto" (estimate()) or a number."""
    if option == "auto":
        try:
            return estimate()
        except ValueError as exc:
            raise DataError(path, str(exc)) from None
    if isinstance(option, bool) or not isinstance(option, int | float) or not math.isfinite(option):
        raise DataError(path, f"{name} must be 'auto' or a number of seconds, got {option!r}")
    return float(option), None


def _interp(t_query, t_ns, values) -> np.ndarray:
    return np.stack([np.interp(t_query, t_ns, values[:, i]) for i in range(values.shape[1])], -1)


def load(
    folder,
    retime: bool = True,
    skew_s="auto",
    dvl_skew_s="auto",
    ref_lever: bool = True,
    gnss_s: float = 60.0,
    seed: int = 0,
    depth_std_m: float = 0.05,
    depth_bias_m: float = 0.0,
    anomalies: str | None = None,
    anomalies_from_s: float = 0.0,
) -> Dataset:
    """One TrajectoryN folder -> Dataset (module doc). retime: rows at the README's 1 Hz / 100 Hz (True) or the
    files' time columns; skew_s: "auto" or t_GT - t_IMU [s]; dvl_skew_s: "auto" or
    t_GT - t_DVL [s]; ref_lever: the reference moved to the IMU by IMU_FROM_REF_B (True) or not; gnss_s: derived GNSS
    fixes during this many seconds from the start (0: none); seed: of every derived noise and of the anomalies;
    depth_std_m / depth_bias_m: derived depth white-noise 1-sigma and constant bias [m]; anomalies: a
    zennav.datasets.dvl_anomalies spec, injected at or after anomalies_from_s [s] from the start."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "trajectory folder not found")
    n = folder.name.removeprefix("Trajectory")
    imu_path, dvl_path, gt_path = (folder / f"{kind}_trajectory{n}.csv" for kind in ("IMU", "DVL", "GT"))
    imu_path = imu_path.with_name(imu_path.name + ".gz")
    for name, value in (("gnss_s", gnss_s), ("depth_std_m", depth_std_m), ("anomalies_from_s", anomalies_from_s)):
        if not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
            raise DataError(folder, f"{name} must be a number >= 0, got {value!r}")
    if not isinstance(depth_bias_m, int | float) or not math.isfinite(depth_bias_m):
        raise DataError(folder, f"depth_bias_m must be a number, got {depth_bias_m!r}")

    gt_table = _table(gt_path, GT_COLUMNS)
    if not isinstance(retime, bool):
        raise DataError(folder, f"retime must be true or false, got {retime!r}")
    t_gt, gt = _times(gt_table, "GT", GT_RATE_HZ if retime else None), gt_table.data
    dvl_table = _table(dvl_path, DVL_COLUMNS)
    t_dvl = _times(dvl_table, "DVL", GT_RATE_HZ if retime else None)
    imu_table = _table(imu_path, IMU_COLUMNS)
    t_imu = _times(imu_table, "IMU", IMU_RATE_HZ if retime else None)
    f_b = imu_table.data[:, 1:4] @ C_B_S.T
    omega_b = imu_table.data[:, 4:7] @ C_B_S.T

    llh_ref = np.column_stack([gt[:, 2], gt[:, 1], gt[:, 3]])  # file order: longitude, latitude, altitude
    v_n_ref = gt[:, 4:7].copy()
    euler = np.column_stack([gt[:, 7], gt[:, 8], wrap_angle(gt[:, 9])])
    if not isinstance(ref_lever, bool):
        raise DataError(folder, f"ref_lever must be true or false, got {ref_lever!r}")
    l_b = IMU_FROM_REF_B.copy() if ref_lever else np.zeros(3)
    llh, v_n = at_point(t_gt, llh_ref, v_n_ref, euler, l_b)

    skew, residual = _skew(skew_s, "skew_s", lambda: estimate_time_offset(t_imu, omega_b, t_gt, euler), imu_path)
    t_imu = t_imu + round(skew * NS)
    # start at the IMU sample nearest the first GT row inside the shifted IMU span; end at the last GT row
    row0 = int(np.searchsorted(t_gt, t_imu[0], side="left"))
    if row0 >= len(t_gt) - 1:
        raise DataError(imu_path, f"no GT rows inside the IMU span after the {skew:+.3f} s skew")
    k0 = int(np.argmin(np.abs(t_imu - t_gt[row0])))
    inside = (np.arange(len(t_imu)) >= k0) & (t_imu <= t_gt[-1])
    if np.count_nonzero(inside) < 2:
        raise DataError(imu_path, f"no IMU samples inside the GT span after the {skew:+.3f} s skew")
    imu = ImuData.from_rates(t_imu[inside], omega_b[inside], f_b[inside])
    t0 = int(imu.t_ns[0])

    yaw_unwrapped = np.unwrap(euler[:, 2])
    euler0 = np.array([np.interp(t0, t_gt, euler[:, 0]), np.interp(t0, t_gt, euler[:, 1]),
                       float(wrap_angle(np.interp(t0, t_gt, yaw_unwrapped)))])
    initial = InitialState(
        t_ns=t0,
        llh=_interp(t0, t_gt, llh),
        v_n=_interp(t0, t_gt, v_n),
        euler=euler0,
        # the reference itself, within 5 ms of a GT row: its position 0.1 m / 0.05 m down, velocity 0.05 m/s (GT
        # and DVL agree to 0.01-0.02 m/s), attitude 0.05 deg roll/pitch and 0.1 deg yaw (post-processed Phins;
        # the 1 Hz rows leave the wave motion between them)
        std_pos_ned=np.array([0.1, 0.1, 0.05]),
        std_v_n=np.full(3, 0.05),
        std_euler=np.radians([0.05, 0.05, 0.1]),
        heading_known=True,
    )

    rng_gnss, rng_depth = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    gnss_rows = np.flatnonzero((t_gt > t0) & (t_gt <= t0 + round(gnss_s * NS)))
    ned_noise = GNSS_STD_M * rng_gnss.standard_normal((len(gnss_rows), 3))
    gnss_llh = np.array([earth.ned_to_llh(e, p) for e, p in zip(ned_noise, llh[gnss_rows], strict=True)])
    gnss = GnssData(
        t_gt[gnss_rows], gnss_llh.reshape(-1, 3), np.tile(GNSS_STD_M, (len(gnss_rows), 1)),
        v_n[gnss_rows] + GNSS_VEL_STD_MPS * rng_gnss.standard_normal((len(gnss_rows), 3)),
        np.full((len(gnss_rows), 3), GNSS_VEL_STD_MPS), np.full(len(gnss_rows), int(FixType.DGPS), dtype=np.int64),
    )

    B = janus_directions(DVL_TILT, DVL_LAYOUT)
    v_d_all = dvl_table.data[:, 1:4]
    dvl_skew, dvl_residual = _skew(
        dvl_skew_s, "dvl_skew_s", lambda: estimate_dvl_skew(t_gt, v_n_ref, euler, t_dvl, v_d_all, l_b), dvl_path)
    t_dvl = t_dvl + round(dvl_skew * NS)
    dvl_rows = (t_dvl >= t0) & (t_dvl <= imu.t_ns[-1])
    v_d = v_d_all[dvl_rows]
    beams = beams_from_velocity(v_d, B)
    dvl = DvlData(t_dvl[dvl_rows], beams, np.ones(beams.shape, dtype=bool), v_d.copy(),
                  np.ones(len(v_d), dtype=bool))
    events: list[dvl_anomalies.AnomalyEvent] = []
    if anomalies:
        try:
            dvl, events = dvl_anomalies.inject(dvl, str(anomalies), B, seed=seed,
                                               t_from_ns=t0 + round(anomalies_from_s * NS))
        except ValueError as exc:
            raise DataError(folder, str(exc)) from None

    depth_rows = t_gt >= t0
    depth = DepthData(t_gt[depth_rows], -llh[depth_rows, 2] + depth_bias_m
                      + depth_std_m * rng_depth.standard_normal(int(depth_rows.sum())))

    truth = Truth(t_ns=t_gt, llh=llh, v_n=v_n, euler=euler,
                  source="Delph post-processed Phins solution at the IMU (aided by the same DVL: not independent)")
    config = NavConfig(imu_noise=_imu_noise(), lever_arm_b=np.zeros(3), start_t_ns=t0, dvl_tilt=DVL_TILT,
                       dvl_layout=DVL_LAYOUT, depth_surface_h_m=0.0,
                       has_dvl=True, has_depth=True,
                       dvl_beam_std_mps=DVL_STD_MPS, dvl_velocity_std_mps=DVL_STD_MPS,
                       depth_std_m=max(depth_std_m, MIN_DEPTH_STD_M))
    notes = {
        "source": "ansfl/A-KIT (no license stated; cite Cohen & Klein, Eng. Appl. of AI 146, 110221, 2025): Snapir "
                  "AUV, iXblue Phins Subsea, Teledyne RDI Workhorse Navigator DVL",
        "trajectory": folder.name,
        "time": "ns since the first GT row (no absolute time in the files); "
                + ("rows retimed at 1 Hz (GT, DVL) and 100 Hz (IMU)" if retime else "the files' time columns"),
        "imu_axes": "ACC Y and GYRO Y negated (the README's y flip of the pre-fix IMU files)",
        "imu_rounding": f"gyro {Q_GYRO} rad/s, accel {Q_ACCEL} m/s^2: gyro ARW from the rounding (q^2/12 per sample)",
        "imu_increments": "trapezoid rule on rates: dtheta_k = (w_{k-1} + w_k) / 2 * dt_k",
        "skew_s": skew,
        "skew": "estimated from the GT attitude rates (t_GT = t_IMU + skew_s)" if residual is not None else "given",
        "skew_fit_rms_dps": None if residual is None else math.degrees(residual),
        "dvl": f"DERIVED beams: Janus tilt {math.degrees(DVL_TILT):g} deg, layout {DVL_LAYOUT!r}, from the recorded "
               "body-frame DVL velocity (also given as velocity_d); DVL frame = body frame, at the IMU",
        "dvl_std_mps": DVL_STD_MPS,
        "dvl_skew_s": dvl_skew,
        "dvl_skew": "estimated from the GT body velocity (t_GT = t_DVL + dvl_skew_s)" if dvl_residual is not None
                    else "given",
        "dvl_skew_fit_rms_mps": dvl_residual,
        "imu_from_reference_b_m": l_b.tolist(),
        "reference": "GT moved from its output point to the IMU by imu_from_reference_b_m (estimated)" if ref_lever
                     else "GT as given (its output point taken as the IMU)",
        "depth": f"DERIVED from the GT altitude: -alt + {depth_bias_m:g} m bias + N(0, {depth_std_m:g} m), 1 Hz",
        "gnss": (f"DERIVED from the GT, first {gnss_s:g} s only ('at the surface'): {len(gnss)} fixes, 1-sigma N/E/D "
                 f"{GNSS_STD_M.tolist()} m and {GNSS_VEL_STD_MPS} m/s, seeded noise") if len(gnss)
                else "none (gnss_s=0)",
        "seed": seed,
        "dvl_anomalies": [e.as_dict() for e in events],
        "dvl_anomaly_spec": anomalies or "",
        "truth": "GT: post-processed Phins (Delph), not independent of the IMU/DVL",
    }
    return Dataset(f"akit_{folder.name}", imu, gnss, config, initial, truth, notes, dvl=dvl, depth=depth)
