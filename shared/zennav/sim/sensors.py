"""Sensors riding a Trajectory: ideal and noisy IMU increments, GNSS antenna fixes, odometer, DVL beams, depth.

Frames and units (README.md, Conventions): n = NED, b = FRD, SI and radians; times t_s in seconds since the
trajectory start, message times t_ns in integer GPS nanoseconds with t0_ns the time of t_s = 0.

Ideal IMU: omega_ib_b = omega_nb_b + C_bn (omega_ie_n + omega_en_n) and
f_b = C_bn (a_n + (2 omega_ie_n + omega_en_n) x v_n - g_n), g_n = (0, 0, normal gravity). The increments
are their plain integrals over each sample interval (what a real IMU outputs; no coning or sculling
terms), by Gauss-Legendre quadrature on pieces split at the trajectory's knots, so that every piece is
analytic and the quadrature is exact to rounding.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import accumulate

import numpy as np

from ..nav import earth
from ..nav.types import NS, DepthData, DvlData, FixType, GnssData, ImuData, ImuNoise, OdometerData
from .trajectory import Trajectory, TrajectoryState


def _to_body(C_nb: np.ndarray, x_n: np.ndarray) -> np.ndarray:
    """C_bn x_n for stacks C_nb (N, 3, 3), x_n (N, 3)."""
    return np.einsum("nji,nj->ni", C_nb, x_n)


def body_rates(st: TrajectoryState) -> tuple[np.ndarray, np.ndarray]:
    """What an ideal IMU measures along st: omega_ib_b [rad/s] and f_b [m/s^2], each (N, 3)."""
    lat, h = st.llh[:, 0], st.llh[:, 2]
    omega_ie_n = earth.omega_ie_n(lat)
    omega_en_n = earth.omega_en_n(lat, h, st.v_n)
    f_n = st.a_n + np.cross(2.0 * omega_ie_n + omega_en_n, st.v_n)
    f_n[:, 2] -= earth.gravity(lat, h)
    return st.omega_nb_b + _to_body(st.C_nb, omega_ie_n + omega_en_n), _to_body(st.C_nb, f_n)


def ideal_increments(traj: Trajectory, t_edges_s, n_nodes: int = 3, chunk: int = 10_000):
    """Exact angle and velocity increments [rad, m/s] (N-1, 3) over [t_edges_s[k], t_edges_s[k+1]] [s] (increasing):
    n_nodes-point Gauss-Legendre on each analytic piece, chunk pieces at a time (bounded memory)."""
    t_edges_s = np.asarray(t_edges_s, dtype=float)
    knots = traj.knots
    inside = knots[(knots > t_edges_s[0]) & (knots < t_edges_s[-1])]
    bp = np.union1d(t_edges_s, inside)  # piece boundaries: interval edges plus knots
    x, w = np.polynomial.legendre.leggauss(n_nodes)
    pieces = np.empty((len(bp) - 1, 6))
    for c in range(0, len(bp) - 1, chunk):
        a, b = bp[:-1][c : c + chunk], bp[1:][c : c + chunk]
        half, mid = 0.5 * (b - a), 0.5 * (a + b)
        t = (mid[:, None] + half[:, None] * x[None, :]).ravel()
        rates = np.concatenate(body_rates(traj.state(t)), axis=1).reshape(len(a), n_nodes, 6)
        pieces[c : c + len(a)] = np.einsum("pnk,n->pk", rates, w) * half[:, None]
    sums = np.add.reduceat(pieces, np.searchsorted(bp, t_edges_s[:-1]), axis=0)
    return sums[:, :3], sums[:, 3:]


def gauss_markov(n: int, dt: float, sigma: float, tau: float, rng: np.random.Generator, dim: int = 3) -> np.ndarray:
    """First-order Gauss-Markov series (n, dim), started from its stationary distribution N(0, sigma^2):
    b_k = exp(-dt/tau) b_(k-1) + sigma sqrt(1 - exp(-2 dt/tau)) w_k (exact discretisation; tau = inf
    gives a random constant). sigma in the unit of the output, dt and tau [s]. The recursion runs in Python floats:
    the same floats as scipy.signal.lfilter([1], [1, -phi], e, axis=0), without importing scipy.signal (about
    1.2 s of a simulated replay's start, issue 17)."""
    phi = float(np.exp(-dt / tau))
    e = sigma * np.sqrt(-np.expm1(-2.0 * dt / tau)) * rng.standard_normal((n, dim))
    e[0] = sigma * rng.standard_normal(dim)
    cols = [list(accumulate(col, lambda b, w: b * phi + w)) for col in e.T.tolist()]
    return np.array(cols, dtype=float).T.copy()


@dataclass
class ImuErrors:
    """True IMU biases at each sample (N, 3): gyro [rad/s] and accelerometer [m/s^2], body frame."""

    gyro_bias: np.ndarray
    accel_bias: np.ndarray


def _seconds(t_ns, t0_ns: int) -> np.ndarray:
    return (np.asarray(t_ns, dtype=np.int64) - np.int64(t0_ns)) / NS


def simulate_imu(traj: Trajectory, t_ns, t0_ns: int, noise: ImuNoise, rng: np.random.Generator,
                 gyro_bias_offset=(0.0, 0.0, 0.0), accel_bias_offset=(0.0, 0.0, 0.0), n_nodes: int = 3,
                 gyro_scale=(0.0, 0.0, 0.0), accel_scale=(0.0, 0.0, 0.0)) -> tuple[ImuData, ImuErrors]:
    """IMU samples at uniformly spaced t_ns (each the end of its interval, the first one's interval
    starting one period earlier): (1 + scale) * ideal increments + bias * dt + white noise, scale the
    scale-factor errors [-] (gyro_scale, accel_scale): per axis (3,), constant, or per sample and axis (N, 3).

    Bias = optional constant offset [rad/s, m/s^2] + Gauss-Markov(noise.*_bias_std, noise.*_bias_tau)
    drawn from its stationary distribution, so its value at the first sample is the turn-on bias.
    White noise per increment: arw sqrt(dt) [rad] and vrw sqrt(dt) [m/s]."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    steps = np.diff(t_ns)
    if len(t_ns) < 2 or np.any(steps != steps[0]):
        raise ValueError("simulate_imu needs at least two uniformly spaced sample times")
    dt = steps[0] / NS
    t_s = _seconds(t_ns, t0_ns)
    dtheta, dvel = ideal_increments(traj, np.concatenate([[t_s[0] - dt], t_s]), n_nodes)
    n = len(t_ns)
    gyro_bias = np.asarray(gyro_bias_offset, float) + gauss_markov(n, dt, noise.gyro_bias_std, noise.gyro_bias_tau, rng)
    accel_bias = np.asarray(accel_bias_offset, float) + gauss_markov(n, dt, noise.accel_bias_std,
                                                                     noise.accel_bias_tau, rng)
    dtheta *= 1.0 + np.asarray(gyro_scale, dtype=float)
    dvel *= 1.0 + np.asarray(accel_scale, dtype=float)
    dtheta += gyro_bias * dt + noise.arw * np.sqrt(dt) * rng.standard_normal((n, 3))
    dvel += accel_bias * dt + noise.vrw * np.sqrt(dt) * rng.standard_normal((n, 3))
    return ImuData(t_ns, dtheta, dvel), ImuErrors(gyro_bias, accel_bias)


def antenna_truth(traj: Trajectory, t_s, lever_arm_b) -> tuple[np.ndarray, np.ndarray]:
    """Exact antenna position llh [rad, rad, m] and NED velocity [m/s] (N, 3) for the lever arm l_b [m] (FRD).

    r_ant = r_imu + C_nb l_b, mapped to llh with the local radii (second-order error ~|l|^2/R < 1e-6 m);
    v_ant = v_n + C_nb (omega_eb_b x l_b), omega_eb_b = omega_nb_b + C_bn omega_en_n (the rate of b
    relative to the earth; the omega_en_n part is below 1e-5 m/s for lever arms of metres)."""
    st = traj.state(t_s)
    lever_arm_b = np.asarray(lever_arm_b, dtype=float)
    lat, h = st.llh[:, 0], st.llh[:, 2]
    llh = st.llh + earth.dr_to_dllh(lat, h) * (st.C_nb @ lever_arm_b)
    omega_eb_b = st.omega_nb_b + _to_body(st.C_nb, earth.omega_en_n(lat, h, st.v_n))
    v_n = st.v_n + np.einsum("nij,nj->ni", st.C_nb, np.cross(omega_eb_b, lever_arm_b))
    return llh, v_n


def simulate_gnss(traj: Trajectory, t_ns, t0_ns: int, lever_arm_b, std_ned, vel_std: float | None,
                  rng: np.random.Generator, fix: FixType = FixType.SINGLE, num_sats: int = 12) -> GnssData:
    """GNSS fixes of the antenna at times t_ns: truth + white noise of std_ned (N, E, D) [m] and vel_std
    [m/s] per axis (None: no velocity); the reported std equal the simulated ones."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    m = len(t_ns)
    llh, v_n = antenna_truth(traj, _seconds(t_ns, t0_ns), lever_arm_b)
    std_ned = np.tile(np.asarray(std_ned, dtype=float), (m, 1))
    llh = llh + earth.dr_to_dllh(llh[:, 0], llh[:, 2]) * std_ned * rng.standard_normal((m, 3))
    v_meas = std_v_n = None
    if vel_std is not None:
        std_v_n = np.full((m, 3), float(vel_std))
        v_meas = v_n + std_v_n * rng.standard_normal((m, 3))
    return GnssData(t_ns, llh, std_ned, v_meas, std_v_n, np.full(m, int(fix), dtype=np.int64),
                    np.full(m, int(num_sats), dtype=np.int64))


def simulate_odometer(traj: Trajectory, t_ns, t0_ns: int, scale_error: float, std_mps: float,
                      rng: np.random.Generator, lever_arm_b=(0.0, 0.0, 0.0)) -> OdometerData:
    """Odometer at times t_ns: (1 + scale_error) times the exact forward speed of the point at lever_arm_b [m, FRD]
    (the body frame is the vehicle frame of the simulated car) plus white noise of std_mps [m/s]:
    v_b = C_bn v_n + omega_nb_b x l_b, its x component."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    st = traj.state(_seconds(t_ns, t0_ns))
    v_b = _to_body(st.C_nb, st.v_n) + np.cross(st.omega_nb_b, np.asarray(lever_arm_b, dtype=float))
    speed = (1.0 + scale_error) * v_b[:, 0] + std_mps * rng.standard_normal(len(t_ns))
    return OdometerData(t_ns, speed)


@dataclass
class DvlErrors:
    """What a simulated DVL injects (simulate_dvl): per-beam constant bias [m/s] (4,), scale-factor error [-], white
    noise 1-sigma [m/s]; per sample and beam: dropout probability, outlier probability and size [m/s] (uniform
    +-1..2 times it). Events at given times (bottom loss, noise bursts, a bias jump) are
    zennav.datasets.dvl_anomalies events (zennav.sim.auv)."""

    bias_mps: np.ndarray
    scale_error: float = 0.0
    noise_mps: float = 0.0
    dropout_prob: float = 0.0
    outlier_prob: float = 0.0
    outlier_mps: float = 1.0


def dvl_velocity(traj: Trajectory, t_s, C_db: np.ndarray, lever_b) -> np.ndarray:
    """Exact velocity over the bottom of the DVL point at lever_b [m, FRD] in the DVL frame d (N, 3) [m/s]:
    v_d = C_db (C_bn v_n + omega_nb_b x l_b) (zennav.nav.beams)."""
    st = traj.state(t_s)
    return (_to_body(st.C_nb, st.v_n) + np.cross(st.omega_nb_b, np.asarray(lever_b, dtype=float))) @ C_db.T


def simulate_dvl(traj: Trajectory, t_ns, t0_ns: int, B: np.ndarray, C_db: np.ndarray, lever_b, errors: DvlErrors,
                 rng: np.random.Generator) -> tuple[DvlData, np.ndarray]:
    """Janus DVL beams at times t_ns: v_beam = (1 + scale) B v_d + bias + noise, with dropouts and outliers as
    ``errors`` says (B: beam unit vectors in d (4 x 3), C_db, lever_b [m]); an invalid beam is NaN. Returns the data
    and the exact beam velocities (N, 4) [m/s] (the truth the learned compensation targets)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    t_s = _seconds(t_ns, t0_ns)
    n = len(t_ns)
    true_beams = dvl_velocity(traj, t_s, C_db, lever_b) @ B.T
    bias = np.tile(np.asarray(errors.bias_mps, dtype=float), (n, 1))
    beams = (1.0 + errors.scale_error) * true_beams + bias + errors.noise_mps * rng.standard_normal((n, 4))
    outlier = rng.uniform(size=(n, 4)) < errors.outlier_prob
    beams += outlier * errors.outlier_mps * rng.uniform(1.0, 2.0, (n, 4)) * rng.choice([-1.0, 1.0], (n, 4))
    valid = rng.uniform(size=(n, 4)) >= errors.dropout_prob
    return DvlData(t_ns, np.where(valid, beams, np.nan), valid), true_beams


def simulate_depth(traj: Trajectory, t_ns, t0_ns: int, h_surface: float, bias_m: float, std_m: float,
                   rng: np.random.Generator) -> DepthData:
    """Pressure depth of the IMU point at times t_ns: h_surface - h + bias_m + white noise std_m [m]."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    h = traj.llh(_seconds(t_ns, t0_ns))[:, 2]
    return DepthData(t_ns, h_surface - h + bias_m + std_m * rng.standard_normal(len(t_ns)))
