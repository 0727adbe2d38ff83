"""A-KIT / Snapir AUV (ANSFL, University of Haifa; ECA A18D with an iXblue Phins Subsea INS and a Teledyne RDI
Workhorse Navigator DVL, Haifa, 2022-06-08): 13 segments of 400 s, ``TrajectoryN/{IMU,DVL,GT}_trajectoryN.csv``.
The data folder's README says what each file is, where it comes from and what its providers checked; read it.

IMU (``IMU_trajectoryN.csv.gz``, 100 Hz, time = linspace(0, 400, 40000) [s], ACC X/Y/Z [m/s^2], GYRO X/Y/Z [rad/s]):
- **y axis flipped**: these are the authors' pre-fix IMU files, whose y axis is sign-flipped against the GT/DVL body
  frame (forward-right-down). README evidence: raw gyro-y is anti-correlated with the GT pitch rate (r = -0.97 on
  T12) and the accelerometer roll with the GT roll (r = -0.95); after negating ACC Y and GYRO Y, gyro-only attitude
  on T12 stays within 0.44/0.26/0.10 deg of the GT over 400 s, without it it drifts to 8.3 deg in pitch. The loader
  negates both columns (C_B_S); tests/unit/test_akit.py checks it (``gyro_attitude``).
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

Skew: the README reports IMU-vs-GT lags of +0.7 to +0.95 s on 9 segments and 0 to 0.2 s on the others. The loader
estimates it per segment (``skew_s="auto"``, default) with zennav.datasets.ansfl.estimate_time_offset: least
squares of the IMU body rates, averaged over each 1 s GT interval, against the body rates between consecutive GT
attitudes, over shifts of +-1.5 s (20 ms grid, then 2 ms and a parabolic vertex). All three axes take part, so
the straight segments (T12: 0.01 rad of yaw change) are fitted on their roll/pitch motion from the waves, where a
yaw-rate-only cross-correlation has nothing to lock on. The Earth and transport rates (about 7e-5 rad/s) are left
in the IMU rates: a slowly varying term that does not move the minimum. Convention: t_GT = t_IMU + skew_s; the IMU
times are shifted onto the GT/DVL time base. A number (``skew_s=0.8``) forces it.

Times: the files carry no absolute time; t_ns = ns since the first GT row (GT time 0).

GT (``GT_trajectoryN.csv``, 1 Hz: longitude, latitude [rad], altitude [m, negative under water], v_N/E/D [m/s],
roll, pitch, yaw [rad]): a Delph post-processed solution of the same Phins aided by the same DVL, so a high-quality
reference, **not independent** of the IMU/DVL. It is the Truth (llh, v_n, euler) and gives the initial state.

Derived sensors (none of these is a recording; notes say so too):
- **DVL beams, derived**: the file gives the DVL's velocity in the body frame at 1 Hz. The four Janus beams of the
  Workhorse (tilt 30 deg) are computed from it, v_beam = B v_d (zennav.nav.beams), all valid, alongside the given
  velocity_d. Layout "x" (beams at 45, 135, 225, 315 deg from forward): the Haifa group's DVL papers on this vehicle
  (BeamsNet, A-KIT) model the beams at psi_i = 45 + 90 (i - 1) deg; the mounting is not documented, and with beams
  derived from a 3-D velocity the choice changes no information, only which beam pairs are "parallel". DVL frame =
  body frame (mounting and lever arm unknown: zero).
- **Depth, derived** from the GT altitude: depth = -alt + a constant bias (depth_bias_m, default 0) + seeded white
  noise (depth_std_m, default 0.05 m: a 0.1 % full-scale pressure sensor of 50 m) at the GT rate (1 Hz); the
  water surface is height 0 (NavConfig.depth_surface_h_m).
- **GNSS, derived**: an AUV has GNSS only at the surface. Fixes from the GT at 1 Hz, only for the first gnss_s
  seconds of the run (default 60 s, "at the surface" to align and train; 0: none), with seeded white noise of
  GNSS_STD_M (position) and GNSS_VEL_STD_MPS (velocity), the reported 1-sigma.
- **DVL anomalies** (zennav.datasets.dvl_anomalies) where asked (``anomalies=<spec>``), recorded in notes.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from zennav.datasets import dvl_anomalies
from zennav.datasets.ansfl import estimate_time_offset
from zennav.datasets.errors import DataError, read_table, read_text
from zennav.nav import earth
from zennav.nav.beams import beams_from_velocity, janus_directions
from zennav.nav.rotation import euler_to_quat, quat_multiply, quat_to_euler, wrap_angle
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


def _times(table, what: str) -> np.ndarray:
    t_ns = np.round(table.data[:, 0] * NS).astype(np.int64)
    table.require_increasing(t_ns, f"{what} time")
    if len(t_ns) < 10:
        raise DataError(table.path, f"{len(t_ns)} {what} rows; at least 10 are needed")
    return t_ns


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


def _skew(option, t_imu, omega_b, t_gt, euler_gt, path) -> tuple[float, float | None]:
    """(skew [s], fit residual [rad/s] or None when given) from the skew_s option (module doc)."""
    if option == "auto":
        try:
            return estimate_time_offset(t_imu, omega_b, t_gt, euler_gt)
        except ValueError as exc:
            raise DataError(path, str(exc)) from None
    if isinstance(option, bool) or not isinstance(option, int | float) or not math.isfinite(option):
        raise DataError(path, f"skew_s must be 'auto' or a number of seconds, got {option!r}")
    return float(option), None


def _interp(t_query, t_ns, values) -> np.ndarray:
    return np.stack([np.interp(t_query, t_ns, values[:, i]) for i in range(values.shape[1])], -1)


def load(
    folder,
    skew_s="auto",
    gnss_s: float = 60.0,
    seed: int = 0,
    depth_std_m: float = 0.05,
    depth_bias_m: float = 0.0,
    anomalies: str | None = None,
    anomalies_from_s: float = 0.0,
) -> Dataset:
    """One TrajectoryN folder -> Dataset (module doc). skew_s: "auto" or t_GT - t_IMU [s]; gnss_s: derived GNSS
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
    t_gt, gt = _times(gt_table, "GT"), gt_table.data
    dvl_table = _table(dvl_path, DVL_COLUMNS)
    t_dvl = _times(dvl_table, "DVL")
    imu_table = _table(imu_path, IMU_COLUMNS)
    t_imu = _times(imu_table, "IMU")
    f_b = imu_table.data[:, 1:4] @ C_B_S.T
    omega_b = imu_table.data[:, 4:7] @ C_B_S.T

    llh = np.column_stack([gt[:, 2], gt[:, 1], gt[:, 3]])  # file order: longitude, latitude, altitude
    v_n = gt[:, 4:7].copy()
    euler = np.column_stack([gt[:, 7], gt[:, 8], wrap_angle(gt[:, 9])])

    skew, residual = _skew(skew_s, t_imu, omega_b, t_gt, euler, imu_path)
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
    dvl_rows = t_dvl >= t0
    v_d = dvl_table.data[dvl_rows, 1:4]
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
                  source="Delph post-processed Phins solution (aided by the same DVL: not independent)")
    config = NavConfig(imu_noise=_imu_noise(), lever_arm_b=np.zeros(3), start_t_ns=t0, dvl_tilt=DVL_TILT,
                       dvl_layout=DVL_LAYOUT, depth_surface_h_m=0.0, has_dvl=True, has_depth=True,
                       dvl_beam_std_mps=DVL_STD_MPS, dvl_velocity_std_mps=DVL_STD_MPS,
                       depth_std_m=max(depth_std_m, MIN_DEPTH_STD_M))
    notes = {
        "source": "ansfl/A-KIT (no license stated; cite Cohen & Klein, Eng. Appl. of AI 146, 110221, 2025): Snapir "
                  "AUV, iXblue Phins Subsea, Teledyne RDI Workhorse Navigator DVL",
        "trajectory": folder.name,
        "time": "ns since the first GT row (no absolute time in the files)",
        "imu_axes": "ACC Y and GYRO Y negated (the README's y flip of the pre-fix IMU files)",
        "imu_rounding": f"gyro {Q_GYRO} rad/s, accel {Q_ACCEL} m/s^2: gyro ARW from the rounding (q^2/12 per sample)",
        "imu_increments": "trapezoid rule on rates: dtheta_k = (w_{k-1} + w_k) / 2 * dt_k",
        "skew_s": skew,
        "skew": "estimated from the GT attitude rates (t_GT = t_IMU + skew_s)" if residual is not None else "given",
        "skew_fit_rms_dps": None if residual is None else math.degrees(residual),
        "dvl": f"DERIVED beams: Janus tilt {math.degrees(DVL_TILT):g} deg, layout {DVL_LAYOUT!r}, from the recorded "
               "body-frame DVL velocity (also given as velocity_d); DVL frame = body frame, lever arm 0 (unknown)",
        "dvl_std_mps": DVL_STD_MPS,
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
