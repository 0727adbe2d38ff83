"""Simulated datasets with exact truth for the demo and the tests of the navigation core.

``make_dataset`` returns a ``Dataset`` like the loaders do (IMU increments, GNSS fixes, truth at IMU rate,
a NavConfig whose ImuNoise is the simulated one, and a perturbed InitialState), plus in ``notes`` the
true bias series (``true_biases``) and the trajectory object (exact truth at any time).
IMU grades are named presets in human units, converted to SI once here.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from ..nav import earth
from ..nav.rotation import wrap_angle
from ..nav.types import NS, Dataset, FixType, ImuData, ImuNoise, InitialState, NavConfig, Truth
from . import cache
from .sensors import ImuErrors, gauss_markov, simulate_gnss, simulate_imu, simulate_odometer
from .trajectory import Trajectory, make_trajectory

_DEG_PER_H = math.radians(1.0) / 3600.0  # rad/s
_PER_RT_H = 1.0 / 60.0  # 1 / sqrt(h) in 1 / sqrt(s)
_MG = 1e-3 * earth.G0  # m/s^2
_PPM = 1e-6  # scale factor [-]


@dataclass(frozen=True)
class ImuGrade:
    """IMU error preset in human units; the bias is first-order Gauss-Markov with 1-sigma and tau."""

    arw_deg_rt_h: float  # angle random walk [deg/sqrt(h)]
    vrw_mps_rt_h: float  # velocity random walk [m/s/sqrt(h)]
    gyro_bias_deg_h: float  # gyro bias 1-sigma [deg/h]
    accel_bias_mg: float  # accelerometer bias 1-sigma [mg]
    bias_tau_s: float  # bias correlation time [s]
    att_std_deg: tuple[float, float]  # initial attitude 1-sigma (roll/pitch, yaw) [deg]

    def noise(self) -> ImuNoise:
        """The same model in SI units."""
        return ImuNoise(
            arw=math.radians(self.arw_deg_rt_h) * _PER_RT_H,
            vrw=self.vrw_mps_rt_h * _PER_RT_H,
            gyro_bias_std=self.gyro_bias_deg_h * _DEG_PER_H,
            accel_bias_std=self.accel_bias_mg * _MG,
            gyro_bias_tau=self.bias_tau_s,
            accel_bias_tau=self.bias_tau_s,
        )


IMU_GRADES = {
    "ideal": ImuGrade(0.0, 0.0, 0.0, 0.0, 3600.0, (0.5, 2.0)),
    "navigation": ImuGrade(0.003, 0.005, 0.01, 0.025, 3600.0, (0.02, 0.1)),
    "tactical": ImuGrade(0.1, 0.05, 1.0, 0.1, 3600.0, (0.1, 0.5)),
    "mems": ImuGrade(0.3, 0.2, 10.0, 1.0, 3600.0, (0.5, 2.0)),
    "consumer": ImuGrade(1.0, 0.5, 100.0, 5.0, 1800.0, (1.0, 5.0)),
}
INITIAL_STD_POS_NED = np.array([1.0, 1.0, 1.0])  # [m]
INITIAL_STD_V_N = np.array([0.1, 0.1, 0.1])  # [m/s]


def _gnss_times(t0_ns: int, t_end_ns: int, rate_hz: float) -> np.ndarray:
    """GNSS epochs [ns] in [t0_ns, t_end_ns] on the grid of multiples of 1/rate_hz of GPS time."""
    period_ns = NS / rate_hz
    m = np.arange(math.ceil(t0_ns / period_ns - 1e-6), math.floor(t_end_ns / period_ns + 1e-6) + 1)
    return np.round(m * period_ns).astype(np.int64)


def make_dataset(kind: str = "car", duration_s: float = 600.0, imu_rate_hz: float = 200.0,
                 gnss_rate_hz: float = 1.0, seed: int = 0, imu_grade: str = "mems", gnss_std_ned=(0.5, 0.5, 1.0),
                 gnss_vel_std: float | None = 0.05, lever_arm_b=(0.5, 0.2, -1.0), perturb_initial: bool = True,
                 start_llh_deg=(30.53, 114.36, 30.0), t0_s: float = 356400.0, gnss_fix: FixType | None = None,
                 num_sats: int = 12, scale_ppm: float | tuple[float, float] = 0.0, odo_rate_hz: float = 10.0,
                 odo_scale_error: float = 0.02, odo_std_mps: float = 0.05, **kw) -> Dataset:
    """Simulated dataset of a "car", "multirotor" or "static" trajectory (kw go to its generator in
    zennav.sim.trajectory, e.g. max_speed, or euler [rad] / yaw_rate [rad/s] for "static").

    IMU samples at imu_rate_hz from t0_s (GPS seconds, the first sample) over duration_s; GNSS fixes of the
    antenna at lever_arm_b [m, FRD] at gnss_rate_hz on whole-second-aligned epochs with white noise
    gnss_std_ned [m] and gnss_vel_std [m/s] (None: no velocity); fix type RTK_FIXED when every std is
    <= 0.1 m, else SINGLE, unless gnss_fix is given. scale_ppm: 1-sigma of the gyro and accelerometer
    scale-factor errors [ppm] (one value: both), told to the filter (ImuNoise scale std with the bias correlation
    time: a KF-GINS-style 21-state filter estimates them) and simulated as that model says: first-order
    Gauss-Markov per axis, started from its stationary distribution as the biases (notes["gyro_scale"],
    notes["accel_scale"]: the series (N, 3) at the IMU samples); 0: none (zeros).
    start_llh_deg: (lat [deg], lon [deg], h [m]).
    Everything random derives from seed (trajectory, IMU errors, GNSS noise and initial errors each from
    their own stream). The initial state is the truth at the first IMU sample, plus (perturb_initial)
    an error drawn from its stated std. A car also has an odometer at the IMU (odo_rate_hz, scale-factor error
    odo_scale_error [ratio], white noise odo_std_mps [m/s]; notes["odo_scale_error"])."""
    params = dict(locals())  # every argument: the key of the generated series in zennav.sim.cache
    if imu_grade not in IMU_GRADES:
        raise ValueError(f"unknown IMU grade {imu_grade!r}; choose from {sorted(IMU_GRADES)}")
    grade = IMU_GRADES[imu_grade]
    noise = grade.noise()
    ss_traj, ss_imu, ss_gnss, ss_init, ss_scale, ss_odo = np.random.SeedSequence(seed).spawn(6)  # first 5: spawn(5)'s
    start_llh = np.array([math.radians(start_llh_deg[0]), math.radians(start_llh_deg[1]), float(start_llh_deg[2])])
    traj = make_trajectory(kind, duration_s, ss_traj, start_llh, **kw)

    t0_ns = int(round(t0_s * NS))
    n_imu = int(round(duration_s * imu_rate_hz)) + 1
    imu_t_ns = t0_ns + np.arange(n_imu, dtype=np.int64) * int(round(NS / imu_rate_hz))
    sg_ppm, sa_ppm = (float(scale_ppm), float(scale_ppm)) if isinstance(scale_ppm, (int, float)) else scale_ppm
    if sg_ppm or sa_ppm:
        noise = replace(noise, gyro_scale_std=sg_ppm * _PPM, accel_scale_std=sa_ppm * _PPM,
                        gyro_scale_tau=noise.gyro_bias_tau, accel_scale_tau=noise.accel_bias_tau)

    def generate() -> dict[str, np.ndarray]:
        return _imu_and_truth(traj, imu_t_ns, t0_ns, int(round(NS / imu_rate_hz)) / NS, noise, ss_imu, ss_scale)

    series = cache.load_or_make(params, generate) if n_imu >= cache.MIN_SAMPLES else generate()
    gyro_scale, accel_scale = (series.get(k, np.zeros((n_imu, 3))) for k in ("gyro_scale", "accel_scale"))
    imu = ImuData(imu_t_ns, series["dtheta"], series["dvel"])
    errors = ImuErrors(series["gyro_bias"], series["accel_bias"])
    if gnss_fix is None:
        gnss_fix = FixType.RTK_FIXED if max(gnss_std_ned) <= 0.1 else FixType.SINGLE
    gnss = simulate_gnss(traj, _gnss_times(t0_ns, int(imu_t_ns[-1]), gnss_rate_hz), t0_ns, lever_arm_b, gnss_std_ned,
                         gnss_vel_std, np.random.default_rng(ss_gnss), gnss_fix, num_sats)

    llh, v_n, euler = series["llh"], series["v_n"], series["euler"]
    truth = Truth(imu_t_ns, llh, v_n, euler, source="simulator (exact)")

    std_euler = np.radians([grade.att_std_deg[0], grade.att_std_deg[0], grade.att_std_deg[1]])
    rng = np.random.default_rng(ss_init)
    err_pos_ned, err_v_n, err_euler = (s * rng.standard_normal(3) * perturb_initial
                                       for s in (INITIAL_STD_POS_NED, INITIAL_STD_V_N, std_euler))
    llh0 = llh[0] + earth.dr_to_dllh(llh[0, 0], llh[0, 2]) * err_pos_ned
    euler0 = euler[0] + err_euler
    euler0[2] = wrap_angle(euler0[2])
    initial = InitialState(
        t_ns=int(imu_t_ns[0]), llh=llh0, v_n=v_n[0] + err_v_n, euler=euler0,
        std_pos_ned=INITIAL_STD_POS_NED.copy(), std_v_n=INITIAL_STD_V_N.copy(), std_euler=std_euler,
        std_gyro_bias=np.full(3, noise.gyro_bias_std), std_accel_bias=np.full(3, noise.accel_bias_std),
    )
    config = NavConfig(imu_noise=noise, lever_arm_b=np.asarray(lever_arm_b, dtype=float),
                       start_t_ns=int(imu_t_ns[0]), end_t_ns=int(imu_t_ns[-1]))
    notes = {
        "generator": "zennav.sim", "kind": kind, "seed": seed, "imu_grade": imu_grade,
        "imu_grade_human_units": asdict(grade), "duration_s": duration_s, "imu_rate_hz": imu_rate_hz,
        "gnss_rate_hz": gnss_rate_hz,
        "gyro_bias_mean_deg_h": (errors.gyro_bias.mean(axis=0) / _DEG_PER_H).tolist(),
        "gyro_bias_std_deg_h": (errors.gyro_bias.std(axis=0) / _DEG_PER_H).tolist(),
        "accel_bias_mean_mg": (errors.accel_bias.mean(axis=0) / _MG).tolist(),
        "accel_bias_std_mg": (errors.accel_bias.std(axis=0) / _MG).tolist(),
        "initial_error": {"pos_ned_m": err_pos_ned.tolist(), "v_n_mps": err_v_n.tolist(),
                          "euler_rad": err_euler.tolist()},
        "imu_errors": errors,
        "gyro_scale": gyro_scale, "accel_scale": accel_scale,  # true scale-factor errors [-] (N, 3)
        "trajectory": traj,
    }
    odometer = None
    if kind == "car":
        odometer = simulate_odometer(traj, _gnss_times(t0_ns, int(imu_t_ns[-1]), odo_rate_hz), t0_ns, odo_scale_error,
                                     odo_std_mps, np.random.default_rng(ss_odo))
        notes.update(odo_scale_error=odo_scale_error, odo_std_mps=odo_std_mps, odo_rate_hz=odo_rate_hz)
    name = f"sim-{kind}-{imu_grade}-seed{seed}"
    return Dataset(name, imu, gnss, config, initial, truth, notes, odometer)


def _imu_and_truth(traj: Trajectory, imu_t_ns: np.ndarray, t0_ns: int, dt: float, noise: ImuNoise,
                   ss_imu: np.random.SeedSequence, ss_scale: np.random.SeedSequence) -> dict[str, np.ndarray]:
    """The long series of a dataset, each (N, 3) at the IMU samples imu_t_ns [ns] (t0_ns: trajectory time 0, dt: their
    period [s]): IMU increments dtheta, dvel [rad, m/s], true biases gyro_bias, accel_bias [rad/s, m/s^2],
    scale-factor errors gyro_scale, accel_scale [-] (only where noise has them; ss_scale's stream) and the truth llh
    [rad, rad, m], v_n [m/s], euler [rad] (yaw wrapped); the IMU errors from ss_imu's stream. Each C-contiguous, as
    read from the cache (zennav.sim.cache)."""
    n_imu = len(imu_t_ns)
    out = {}
    gyro_scale = accel_scale = np.zeros((n_imu, 3))
    if noise.gyro_scale_std or noise.accel_scale_std:
        rng_scale = np.random.default_rng(ss_scale)
        out["gyro_scale"] = gyro_scale = gauss_markov(n_imu, dt, noise.gyro_scale_std, noise.gyro_scale_tau, rng_scale)
        out["accel_scale"] = accel_scale = gauss_markov(n_imu, dt, noise.accel_scale_std, noise.accel_scale_tau,
                                                        rng_scale)
    imu, errors = simulate_imu(traj, imu_t_ns, t0_ns, noise, np.random.default_rng(ss_imu), gyro_scale=gyro_scale,
                               accel_scale=accel_scale)
    st = traj.state((imu_t_ns - t0_ns) / NS)
    euler = st.euler.copy()
    euler[:, 2] = wrap_angle(euler[:, 2])
    out.update(dtheta=imu.dtheta, dvel=imu.dvel, gyro_bias=errors.gyro_bias, accel_bias=errors.accel_bias,
               llh=st.llh, v_n=st.v_n, euler=euler)
    return {k: np.ascontiguousarray(a) for k, a in out.items()}


def true_biases(dataset: Dataset) -> ImuErrors:
    """The simulated gyro [rad/s] and accelerometer [m/s^2] bias series (N, 3) at the IMU samples."""
    if "imu_errors" not in dataset.notes:
        raise ValueError(f"{dataset.name} is not a simulated dataset")
    return dataset.notes["imu_errors"]
