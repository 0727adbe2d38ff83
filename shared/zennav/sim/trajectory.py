"""Smooth trajectories with exact truth, evaluated at arbitrary times.

Frames and units (README.md, Conventions): n = NED, b = FRD, SI and radians, Euler ZYX (roll, pitch, yaw).
Time ``t`` is in seconds since the trajectory start (t = 0 at ``start_llh``).

Construction
- The kinematics (v_n, its derivative a_n, the Euler angles and their rates) are closed-form
  functions of time built from scalar profiles of smooth steps (``SmoothSteps``): each transition is
  the C3 septic smooth step S(u) = 35u^4 - 84u^5 + 70u^6 - 20u^7, whose value, three derivatives and
  integral are exact polynomials. Velocity is therefore C3, the Euler rates C2 (car) or C1 (multirotor,
  whose tilt follows the acceleration).
- Position (lat, lon, h) integrates lat' = v_N/(R_M+h), lon' = v_E/((R_N+h) cos lat), h' = -v_D with
  5-point Gauss-Legendre on a 0.05 s node grid (fixed-point iterated for the radii), then is the C2
  quintic Hermite interpolant of the node values and their first two derivatives: over 30 min the
  position agrees with the integral of v_n to ~1e-8 m.
- ``knots`` lists the times where the kinematics are not analytic (transition ends); exact quadratures
  (the IMU increments) split their intervals there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..nav import earth
from ..nav.rotation import euler_to_dcm

PAD_S = 1.0  # trajectories are defined on [-PAD_S, duration_s + PAD_S] (the first IMU interval ends at t = 0)
_NODE_STEP_S = 0.05  # position node spacing [s]
_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)
_S_MAX_SLOPE = 35.0 / 16.0  # max of S'(u), at u = 1/2: peak rate of a transition = delta * _S_MAX_SLOPE / T


def _septic(u: np.ndarray, order: int) -> np.ndarray:
    """Septic smooth step S(u) on [0, 1] (order 0) and its derivatives dS^k/du^k (order 1..3)."""
    uv = u * (1.0 - u)
    if order == 0:
        u2 = u * u
        return u2 * u2 * (35.0 + u * (-84.0 + u * (70.0 - 20.0 * u)))
    if order == 1:
        return 140.0 * uv * uv * uv
    if order == 2:
        return 420.0 * uv * uv * (1.0 - 2.0 * u)
    return 840.0 * uv * (1.0 - 5.0 * uv)


def _septic_integral(u: np.ndarray) -> np.ndarray:
    """Integral of S from 0 to u for u >= 0 (S = 1 beyond u = 1)."""
    w = np.minimum(u, 1.0)
    return w**5 * (7.0 - 14.0 * w + 10.0 * w * w - 2.5 * w**3) + np.maximum(u - 1.0, 0.0)


class SmoothSteps:
    """Scalar profile x(t) = x0 + sum_i delta_i S((t - start_i) / T_i) with non-overlapping transitions.

    Exact value, derivatives up to order 3 and integral from t = 0, vectorised over t [s]."""

    def __init__(self, x0: float, starts=(), durations=(), deltas=()):
        starts, durations, deltas = (np.asarray(a, dtype=float).reshape(-1) for a in (starts, durations, deltas))
        if np.any(durations <= 0.0) or np.any(starts[1:] < starts[:-1] + durations[:-1] - 1e-9):
            raise ValueError("transitions need positive durations and must not overlap")
        # A zero-size transition far in the past makes every time have a "current" transition.
        self.starts = np.concatenate([[-1e9], starts])
        self.durations = np.concatenate([[1.0], durations])
        self.deltas = np.concatenate([[0.0], deltas])
        self.levels = x0 + np.concatenate([[0.0], np.cumsum(self.deltas[:-1])])  # value before each transition
        # Integral of all completed transitions m < i at time t: t * sum(delta_m) - sum(delta_m (start_m + T_m/2)).
        self._c1 = np.concatenate([[0.0], np.cumsum(self.deltas[:-1])])
        self._c2 = np.concatenate([[0.0], np.cumsum((self.deltas * (self.starts + 0.5 * self.durations))[:-1])])
        self.x0 = float(x0)
        self._f0 = float(self._antiderivative(np.zeros(1))[0])

    @property
    def knots(self) -> np.ndarray:
        """Times [s] where the profile is not analytic: the starts and ends of its transitions."""
        return np.concatenate([self.starts[1:], self.starts[1:] + self.durations[1:]])

    def _locate(self, t):
        i = np.searchsorted(self.starts, t, side="right") - 1
        return i, (t - self.starts[i]) / self.durations[i]

    def derivs(self, t, order: int = 0) -> list[np.ndarray]:
        """[x, dx/dt, ..., d^order x/dt^order] at times t [s], order <= 3."""
        t = np.asarray(t, dtype=float)
        i, u = self._locate(t)
        uc = np.clip(u, 0.0, 1.0)
        out = [self.levels[i] + self.deltas[i] * _septic(uc, 0)]
        for k in range(1, order + 1):
            out.append(self.deltas[i] * _septic(uc, k) / self.durations[i] ** k)
        return out

    def _antiderivative(self, t):
        i, u = self._locate(t)
        done = t * self._c1[i] - self._c2[i]
        return self.x0 * t + done + self.deltas[i] * self.durations[i] * _septic_integral(np.maximum(u, 0.0))

    def integral(self, t) -> np.ndarray:
        """Integral of x from 0 to t [s]."""
        return self._antiderivative(np.asarray(t, dtype=float)) - self._f0


def _ramp(w_peak: float, total: float, ramp_s: float) -> tuple[float, float, float]:
    """(peak, ramp, hold) of a 0 -> peak -> 0 rate bump whose integral is total; shortens the peak if needed."""
    if total < w_peak * ramp_s:
        return total / ramp_s, ramp_s, 0.0
    return w_peak, ramp_s, total / w_peak - ramp_s


@dataclass
class TrajectoryState:
    """Exact kinematics at times t_s [s] (N,): llh [rad, rad, m], v_n and a_n = dv_n/dt [m/s, m/s^2] (NED),
    euler (roll, pitch, yaw) [rad] (yaw unwrapped) and euler_rate [rad/s], C_nb (N, 3, 3),
    omega_nb_b: body rate relative to n, resolved in b [rad/s]."""

    t_s: np.ndarray
    llh: np.ndarray
    v_n: np.ndarray
    a_n: np.ndarray
    euler: np.ndarray
    euler_rate: np.ndarray
    C_nb: np.ndarray
    omega_nb_b: np.ndarray


def _radii_slopes(lat):
    """Radii R_M, R_N [m] and their derivatives with respect to latitude [m/rad]."""
    r_m, r_n = earth.radii(lat)
    k = earth.E2 * np.sin(lat) * np.cos(lat) / (1.0 - earth.E2 * np.sin(lat) ** 2)
    return r_m, r_n, 3.0 * r_m * k, r_n * k


def _omega_nb_b(euler, euler_rate) -> np.ndarray:
    """ZYX Euler angles and rates [rad, rad/s] -> omega_nb_b [rad/s] (N, 3)."""
    roll, pitch = euler[:, 0], euler[:, 1]
    dr, dp, dy = euler_rate.T
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    return np.stack([dr - dy * sp, dp * cr + dy * sr * cp, -dp * sr + dy * cr * cp], axis=-1)


class Trajectory:
    """Base class: subclasses define ``_motion(t) -> (v_n, a_n, euler, euler_rate)``, each (N, 3).

    start_llh: (lat, lon, h) [rad, rad, m] at t = 0; duration_s: nominal length [s]; queries are valid
    on [-PAD_S, duration_s + PAD_S]."""

    def __init__(self, start_llh, duration_s: float):
        self.start_llh = np.asarray(start_llh, dtype=float)
        self.duration_s = float(duration_s)
        self._build_position_nodes()

    def _motion(self, t: np.ndarray):
        raise NotImplementedError

    def _build_position_nodes(self) -> None:
        """Exact (lat, lon, h) and their first two time derivatives on the node grid."""
        j0 = int(round(PAD_S / _NODE_STEP_S))
        n_nodes = j0 + int(math.ceil((self.duration_s + PAD_S) / _NODE_STEP_S)) + 1
        t_nodes = (np.arange(n_nodes) - j0) * _NODE_STEP_S
        H = _NODE_STEP_S
        x = 0.5 * (_GL_X + 1.0)  # GL abscissae on [0, 1]
        v_gl = self._motion((t_nodes[:-1, None] + H * x[None, :]).ravel())[0].reshape(n_nodes - 1, x.size, 3)
        wH = 0.5 * H * _GL_W

        def cumulative(increments):
            c = np.concatenate([[0.0], np.cumsum(increments)])
            return c - c[j0]

        lat0, lon0, h0 = self.start_llh
        h = h0 + cumulative(-v_gl[:, :, 2] @ wH)

        def at_gl(nodes):  # linear interpolation of node values at the GL abscissae (only enters the radii)
            return nodes[:-1, None] + (nodes[1:] - nodes[:-1])[:, None] * x[None, :]

        h_gl = at_gl(h)
        lat = np.full(n_nodes, lat0)
        for _ in range(3):  # fixed point for R_M(lat); contracts by ~1e-5 per pass
            r_m, _ = earth.radii(at_gl(lat))
            lat = lat0 + cumulative((v_gl[:, :, 0] / (r_m + h_gl)) @ wH)
        lat_gl = at_gl(lat)
        _, r_n = earth.radii(lat_gl)
        lon = lon0 + cumulative((v_gl[:, :, 1] / ((r_n + h_gl) * np.cos(lat_gl))) @ wH)

        v_n, a_n = self._motion(t_nodes)[:2]
        r_m, r_n, dr_m, dr_n = _radii_slopes(lat)
        m, nc = r_m + h, (r_n + h) * np.cos(lat)
        dlat, dlon, dh = v_n[:, 0] / m, v_n[:, 1] / nc, -v_n[:, 2]
        ddlat = (a_n[:, 0] - dlat * (dr_m * dlat + dh)) / m
        dnc = (dr_n * dlat + dh) * np.cos(lat) - (r_n + h) * np.sin(lat) * dlat
        ddlon = (a_n[:, 1] - dlon * dnc) / nc
        # Quintic Hermite coefficients per node interval, p(u) = sum_m c_m u^m, u in [0, 1], of the offsets
        # from the start (which keeps full precision in the interpolation).
        p = np.stack([lat - lat0, lon - lon0, h - h0], axis=-1)
        v = H * np.stack([dlat, dlon, dh], axis=-1)
        a = H * H * np.stack([ddlat, ddlon, -a_n[:, 2]], axis=-1)
        p0, v0, a0, p1, v1, a1 = p[:-1], v[:-1], a[:-1], p[1:], v[1:], a[1:]
        self._t_nodes = t_nodes
        self._hermite = np.stack(  # (6, intervals, 3): contiguous per coefficient for fast gathers
            [
                p0,
                v0,
                0.5 * a0,
                -10.0 * p0 - 6.0 * v0 - 1.5 * a0 + 10.0 * p1 - 4.0 * v1 + 0.5 * a1,
                15.0 * p0 + 8.0 * v0 + 1.5 * a0 - 15.0 * p1 + 7.0 * v1 - a1,
                -6.0 * p0 - 3.0 * v0 - 0.5 * a0 + 6.0 * p1 - 3.0 * v1 + 0.5 * a1,
            ]
        )

    @property
    def knots(self) -> np.ndarray:
        """Sorted times [s] where the kinematics are not analytic (ends of smooth-step transitions):
        quadratures that must be exact split their intervals there."""
        return np.zeros(0)

    def llh(self, t) -> np.ndarray:
        """Geodetic position (lat, lon, h) [rad, rad, m] at times t [s], (N, 3)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.size and (t.min() < -PAD_S - 1e-9 or t.max() > self.duration_s + PAD_S + 1e-9):
            raise ValueError(f"times outside [{-PAD_S}, {self.duration_s + PAD_S}] s")
        j = np.clip(np.floor((t - self._t_nodes[0]) / _NODE_STEP_S).astype(np.int64), 0, len(self._t_nodes) - 2)
        u = ((t - self._t_nodes[j]) / _NODE_STEP_S)[:, None]
        p = np.take(self._hermite[5], j, axis=0)
        for m in range(4, -1, -1):
            p *= u
            p += np.take(self._hermite[m], j, axis=0)
        return p + self.start_llh

    def state(self, t) -> TrajectoryState:
        """Full exact kinematic state at times t [s]."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        llh = self.llh(t)
        v_n, a_n, euler, euler_rate = self._motion(t)
        return TrajectoryState(t, llh, v_n, a_n, euler, euler_rate, euler_to_dcm(euler), _omega_nb_b(euler, euler_rate))


class StaticTrajectory(Trajectory):
    """Fixed position and attitude euler [rad]; optionally a constant yaw rate [rad/s] (a turntable)."""

    def __init__(self, start_llh, duration_s: float, euler=(0.0, 0.0, 0.0), yaw_rate: float = 0.0):
        self.euler0 = np.asarray(euler, dtype=float)
        self.yaw_rate = float(yaw_rate)
        super().__init__(start_llh, duration_s)

    def _motion(self, t):
        zeros = np.zeros((t.size, 3))
        euler = np.tile(self.euler0, (t.size, 1))
        euler[:, 2] += self.yaw_rate * t
        rate = zeros.copy()
        rate[:, 2] = self.yaw_rate
        return zeros, zeros.copy(), euler, rate


class CarTrajectory(Trajectory):
    """Land vehicle without sideslip: speed s(t) [m/s], turn rate r(t) = yaw' [rad/s] and road grade
    gamma(t) [rad] as smooth-step profiles. v_n = s (cos g cos y, cos g sin y, -sin g); pitch = grade;
    yaw = yaw0 + integral of r; roll = -roll_gain * s * r (body roll away from the turn) [rad per m/s^2]."""

    def __init__(self, start_llh, duration_s, speed: SmoothSteps, turn_rate: SmoothSteps, grade: SmoothSteps,
                 yaw0: float = 0.0, roll_gain: float = np.deg2rad(0.5)):
        self.speed, self.turn_rate, self.grade = speed, turn_rate, grade
        self.yaw0, self.roll_gain = float(yaw0), float(roll_gain)
        super().__init__(start_llh, duration_s)

    @property
    def knots(self) -> np.ndarray:
        return np.unique(np.concatenate([p.knots for p in (self.speed, self.turn_rate, self.grade)]))

    def _motion(self, t):
        s, ds = self.speed.derivs(t, 1)
        r, dr = self.turn_rate.derivs(t, 1)
        g, dg = self.grade.derivs(t, 1)
        yaw = self.yaw0 + self.turn_rate.integral(t)
        cg, sg, cy, sy = np.cos(g), np.sin(g), np.cos(yaw), np.sin(yaw)
        u = np.stack([cg * cy, cg * sy, -sg], axis=-1)
        du = dg[:, None] * np.stack([-sg * cy, -sg * sy, -cg], axis=-1) + r[:, None] * np.stack(
            [-cg * sy, cg * cy, np.zeros_like(cg)], axis=-1
        )
        v_n = s[:, None] * u
        a_n = ds[:, None] * u + s[:, None] * du
        euler = np.stack([-self.roll_gain * s * r, g, yaw], axis=-1)
        euler_rate = np.stack([-self.roll_gain * (ds * r + s * dr), dg, r], axis=-1)
        return v_n, a_n, euler, euler_rate


class MultirotorTrajectory(Trajectory):
    """Multirotor: a sequence of manoeuvres, each from hover to hover, plus an independent yaw profile.

    Manoeuvre k starts at seg_start[k]; along it the path parameter W (metres for lines, radians for
    circles/eights) has rate w(t) = dW/dt (one SmoothSteps over all manoeuvres, zero while hovering), and
    the velocity is v_n = P'(W) w with P'(W) = d0 + a1 cos W + b1 sin W + a2 cos 2W + b2 sin 2W
    (paths[k] = [d0, a1, b1, a2, b2], each a NED 3-vector). The tilt puts the thrust axis (-z_b) along
    a_n - g_n (g_n with the normal gravity at the start), so f_b is along -z_b up to earth-rate terms."""

    def __init__(self, start_llh, duration_s, path_rate: SmoothSteps, seg_start, paths, yaw: SmoothSteps):
        self.path_rate, self.yaw = path_rate, yaw
        self.seg_start = np.asarray(seg_start, dtype=float)
        self.paths = np.asarray(paths, dtype=float).reshape(-1, 5, 3)
        self._W_start = path_rate.integral(self.seg_start)
        self._g = earth.gravity(start_llh[0], start_llh[2])
        super().__init__(start_llh, duration_s)

    @property
    def knots(self) -> np.ndarray:
        return np.unique(np.concatenate([self.path_rate.knots, self.yaw.knots]))

    def _motion(self, t):
        w, dw, ddw = self.path_rate.derivs(t, 2)
        k = np.clip(np.searchsorted(self.seg_start, t, side="right") - 1, 0, None)
        W = self.path_rate.integral(t) - self._W_start[k]
        c1, s1, c2, s2 = np.cos(W), np.sin(W), np.cos(2.0 * W), np.sin(2.0 * W)
        one, zero = np.ones_like(W), np.zeros_like(W)
        basis = np.array([[one, c1, s1, c2, s2], [zero, -s1, c1, -2.0 * s2, 2.0 * c2],
                          [zero, -c1, -s1, -4.0 * c2, -4.0 * s2]]).transpose(2, 0, 1)  # (N, 3, 5)
        p1, p2, p3 = np.moveaxis(basis @ np.take(self.paths, k, axis=0), 1, 0)  # dP/dW, d2P/dW2, d3P/dW3 (N, 3) each
        w, dw, ddw = w[:, None], dw[:, None], ddw[:, None]
        v_n = p1 * w
        a_n = p2 * w * w + p1 * dw
        j_n = p3 * w**3 + 3.0 * p2 * w * dw + p1 * ddw
        yaw, dyaw = self.yaw.derivs(t, 1)
        # Thrust direction z_b (down) along g_n - a_n, expressed in the yaw-rotated frame: p = Rz(-yaw) (g_n - a_n).
        cy, sy = np.cos(yaw), np.sin(yaw)
        qx, qy, qz = -a_n[:, 0], -a_n[:, 1], self._g - a_n[:, 2]
        dqx, dqy, dqz = -j_n[:, 0], -j_n[:, 1], -j_n[:, 2]
        px, py = cy * qx + sy * qy, -sy * qx + cy * qy
        dpx = cy * dqx + sy * dqy + dyaw * py
        dpy = -sy * dqx + cy * dqy - dyaw * px
        rho2 = px * px + qz * qz
        rho = np.sqrt(rho2)
        pitch = np.arctan2(px, qz)
        roll = np.arctan2(-py, rho)
        dpitch = (qz * dpx - px * dqz) / rho2
        drho = (px * dpx + qz * dqz) / rho
        droll = (py * drho - rho * dpy) / (rho2 + py * py)
        return v_n, a_n, np.stack([roll, pitch, yaw], axis=-1), np.stack([droll, dpitch, dyaw], axis=-1)


def car_trajectory(duration_s: float, seed=0, start_llh=(0.5328, 1.9959, 30.0), yaw0: float | None = None,
                   max_speed: float = 25.0, max_lat_accel: float = 3.0, roll_gain: float = np.deg2rad(0.5)
                   ) -> CarTrajectory:
    """Random drive of duration_s [s] picked by seed: stand, accelerate, cruise, left/right turns of radius
    15-300 m, gentle hills (grade up to 6 deg), speed changes and stops; ends braked to a standstill a few
    seconds before duration_s. Speeds [m/s] up to max_speed, lateral acceleration [m/s^2] up to max_lat_accel."""
    rng = np.random.default_rng(seed)
    # transitions (start, duration, delta) per profile
    tr: dict[str, list[tuple[float, float, float]]] = {"speed": [], "turn": [], "grade": []}
    t, v, height = min(rng.uniform(8.0, 15.0), 0.1 * duration_s), 0.0, 0.0

    def speed_to(v1, accel):
        nonlocal t, v
        T = max(_S_MAX_SLOPE * abs(v1 - v) / accel, 1.0)
        tr["speed"].append((t, T, v1 - v))
        t, v = t + T, v1

    def braking_time():  # stop at 2 m/s^2 peak and stand 3 s
        return max(_S_MAX_SLOPE * v / 2.0, 1.0) + 3.0 if v > 0.0 else 0.0

    while True:
        saved = (t, v, height, {k: len(x) for k, x in tr.items()})
        if v == 0.0:
            action = "start"
        else:
            action = rng.choice(["cruise", "turn", "hill", "speed", "stop"], p=[0.25, 0.35, 0.15, 0.15, 0.10])
        if action == "start":
            speed_to(rng.uniform(8.0, max_speed), rng.uniform(1.0, 2.0))
        elif action == "cruise":
            t += rng.uniform(5.0, 40.0)
        elif action == "speed":
            speed_to(rng.uniform(5.0, max_speed), rng.uniform(1.0, 2.5))
        elif action == "stop":
            speed_to(0.0, rng.uniform(1.5, 3.0))
            t += rng.uniform(3.0, 15.0)
        elif action == "turn":
            radius = rng.choice([15.0, 30.0, 60.0, 120.0, 300.0])
            if v * v / radius > max_lat_accel:
                speed_to(0.9 * math.sqrt(max_lat_accel * radius), 2.0)
            rate = v / radius
            angle = min(np.deg2rad(rng.uniform(30.0, 180.0)), 45.0 * rate)  # at most ~45 s in one turn
            rate, ramp, hold = _ramp(rate, angle, rng.uniform(1.5, 3.0))
            sign = rng.choice([-1.0, 1.0])
            tr["turn"] += [(t, ramp, sign * rate), (t + ramp + hold, ramp, -sign * rate)]
            t += 2.0 * ramp + hold
        else:  # hill: grade ramps up, holds, ramps back; the sign prefers to bring the height back
            g = np.deg2rad(rng.uniform(1.0, 6.0)) * (1.0 if rng.uniform() < 0.5 - 0.005 * height else -1.0)
            ramp, hold = rng.uniform(5.0, 10.0), rng.uniform(5.0, 30.0)
            tr["grade"] += [(t, ramp, g), (t + ramp + hold, ramp, -g)]
            t += 2.0 * ramp + hold
            height += v * math.sin(g) * (ramp + hold)
        if t + braking_time() > duration_s:  # no room: undo, cruise on, brake to a stop before the end
            t, v, height, lengths = saved
            for k, n in lengths.items():
                del tr[k][n:]
            if v > 0.0:
                t = max(t, duration_s - braking_time())
                speed_to(0.0, 2.0)
            break

    def profile(name):
        return SmoothSteps(0.0, *np.array(tr[name]).reshape(-1, 3).T)

    yaw0 = rng.uniform(-np.pi, np.pi) if yaw0 is None else yaw0
    return CarTrajectory(start_llh, duration_s, profile("speed"), profile("turn"), profile("grade"), yaw0, roll_gain)


def multirotor_trajectory(duration_s: float, seed=0, start_llh=(0.5328, 1.9959, 30.0), max_speed: float = 10.0,
                          max_accel: float = 2.0, max_yaw_rate: float = np.deg2rad(45.0)) -> MultirotorTrajectory:
    """Random flight of duration_s [s] picked by seed: on the ground, take-off, hovers, climbs and descents
    (10-80 m above the start), horizontal legs, circles and figure-eights, yaw rotations independent of
    the flight direction, and a landing back at the start height a few seconds before duration_s.
    Speeds [m/s] up to max_speed, accelerations [m/s^2] up to about max_accel, yaw rate [rad/s] up to max_yaw_rate."""
    rng = np.random.default_rng(seed)
    rate_tr, seg_start, paths = [], [], []
    t, alt = min(rng.uniform(5.0, 10.0), 0.1 * duration_s), 0.0
    zero = np.zeros(3)

    def maneuver(path, w_peak, total, ramp):
        nonlocal t
        w, ramp, hold = _ramp(w_peak, total, ramp)
        seg_start.append(t)
        paths.append(path)
        rate_tr.extend([(t, ramp, w), (t + ramp + hold, ramp, -w)])
        t += 2.0 * ramp + hold

    def vertical(dalt, speed):
        nonlocal alt
        up = np.array([0.0, 0.0, -1.0 if dalt > 0 else 1.0])
        maneuver([up, zero, zero, zero, zero], speed, abs(dalt), max(_S_MAX_SLOPE * speed / max_accel, 2.0))
        alt += dalt

    def landing_time():  # 3 s hover, descent at 1.5 m/s, 3 s on the ground
        return alt / 1.5 + max(_S_MAX_SLOPE * 1.5 / max_accel, 2.0) + 6.0 if alt > 0.0 else 0.0

    def horizontal(x, y):
        return np.array([x, y, 0.0])

    while True:
        saved = (t, alt, len(seg_start))
        action = rng.choice(["hover", "climb", "leg", "circle", "eight"], p=[0.2, 0.15, 0.3, 0.2, 0.15])
        if not seg_start:
            vertical(rng.uniform(10.0, 30.0), rng.uniform(1.0, 3.0))  # take-off
        elif action == "hover":
            t += rng.uniform(3.0, 15.0)
        elif action == "climb":
            vertical(rng.uniform(10.0, 80.0) - alt, rng.uniform(1.0, 3.0))
        else:
            heading = rng.uniform(-np.pi, np.pi)
            ch, sh = math.cos(heading), math.sin(heading)
            if action == "leg":
                speed = rng.uniform(3.0, max_speed)
                maneuver([horizontal(ch, sh), zero, zero, zero, zero], speed, rng.uniform(20.0, 300.0),
                         max(_S_MAX_SLOPE * speed / max_accel, 2.0))
            else:
                radius, sense = rng.uniform(10.0, 40.0), rng.choice([-1.0, 1.0])
                e1, e2 = horizontal(ch, sh), sense * horizontal(-sh, ch)
                speed = min(rng.uniform(2.0, 8.0), 0.9 * math.sqrt(max_accel * radius), max_speed)
                if action == "circle":  # P(W) = R (cos W e1 + sin W e2) about the centre
                    path, w_peak = [zero, radius * e2, -radius * e1, zero, zero], speed / radius
                else:  # Gerono lemniscate P(W) = R (sin W e1 + sin W cos W e2)
                    path, w_peak = [zero, radius * e1, zero, radius * e2, zero], speed / (radius * math.sqrt(2.0))
                loops = rng.uniform(0.75, 2.0) if action == "circle" else 1.0
                maneuver(path, w_peak, 2.0 * np.pi * loops, max(_S_MAX_SLOPE * speed / max_accel, 3.0))
        if t + landing_time() > duration_s:  # no room: undo and land
            t, alt, n = saved
            del seg_start[n:], paths[n:], rate_tr[2 * n:]
            break
    t_land = t
    if alt > 0.0:
        t += 3.0
        vertical(-alt, 1.5)

    # Yaw rotations between the end of the take-off and the landing, independent of the path.
    yaw_tr = []
    ty = rate_tr[1][0] + rate_tr[1][1] if rate_tr else t  # end of the take-off
    while True:
        dyaw = rng.uniform(-np.pi, np.pi)
        T = max(_S_MAX_SLOPE * abs(dyaw) / max_yaw_rate, 2.0)
        if ty + T > t_land:
            break
        yaw_tr.append((ty, T, dyaw))
        ty += T + rng.uniform(5.0, 30.0)

    rate = SmoothSteps(0.0, *np.array(rate_tr).reshape(-1, 3).T)
    yaw = SmoothSteps(rng.uniform(-np.pi, np.pi), *np.array(yaw_tr).reshape(-1, 3).T)
    seg = np.array(seg_start) if seg_start else np.zeros(1)
    path_arr = np.array(paths) if paths else np.zeros((1, 5, 3))
    return MultirotorTrajectory(start_llh, duration_s, rate, seg, path_arr, yaw)


def auv_trajectory(duration_s: float, seed=0, start_llh=(0.5328, 1.9959, 0.0), surface_s: float = 120.0,
                   max_depth_m: float = 50.0, min_speed: float = 1.0, max_speed: float = 3.0,
                   max_turn_rate: float = np.deg2rad(5.0), dive_pitch: float = np.deg2rad(15.0)) -> CarTrajectory:
    """Random AUV mission of duration_s [s] picked by seed, starting at the surface (start_llh's height is the water
    surface): 3 s still, speed-up to 1.5 m/s, surface manoeuvres (turns of 20-60 m radius) until surface_s [s], then
    a dive at dive_pitch [rad] to 40-100 % of max_depth_m [m], and under water: straight legs, turns of 90-180 deg at
    up to max_turn_rate [rad/s], speed changes within [min_speed, max_speed] [m/s] and depth changes of 5-15 m at
    5-10 deg pitch, between 5 m and max_depth_m. The vehicle flies without sideslip (pitch = flight-path angle, a small
    roll into turns): a CarTrajectory whose "grade" is the flight-path angle (negative: diving)."""
    rng = np.random.default_rng(seed)
    tr: dict[str, list[tuple[float, float, float]]] = {"speed": [], "turn": [], "grade": []}
    t, v, height = 3.0, 0.0, 0.0

    def speed_to(v1, accel):
        nonlocal t, v
        T = max(_S_MAX_SLOPE * abs(v1 - v) / accel, 1.0)
        tr["speed"].append((t, T, v1 - v))
        t, v = t + T, v1

    def turn(angle, radius):
        nonlocal t
        rate, ramp, hold = _ramp(min(v / radius, max_turn_rate), abs(angle), 3.0)
        sign = math.copysign(1.0, angle)
        tr["turn"] += [(t, ramp, sign * rate), (t + ramp + hold, ramp, -sign * rate)]
        t += 2.0 * ramp + hold

    def climb(dh, pitch):  # height change dh [m] at flight-path angle pitch [rad] (its sign from dh)
        nonlocal t, height
        g = math.copysign(pitch, dh)
        ramp = 5.0
        hold = max(abs(dh) / (v * math.sin(pitch)) - ramp, 1.0)
        tr["grade"] += [(t, ramp, g), (t + ramp + hold, ramp, -g)]
        t += 2.0 * ramp + hold
        height += v * math.sin(g) * (ramp + hold)

    speed_to(1.5, 0.2)
    while t < surface_s - 40.0:  # surface manoeuvres
        t += rng.uniform(5.0, 15.0)
        if t < surface_s - 40.0:
            turn(np.deg2rad(rng.uniform(45.0, 120.0)) * rng.choice([-1.0, 1.0]), rng.uniform(20.0, 60.0))
    t = max(t, surface_s)
    climb(-rng.uniform(0.4, 1.0) * max_depth_m, dive_pitch)
    while True:
        saved = (t, v, height, {k: len(x) for k, x in tr.items()})
        action = rng.choice(["leg", "turn", "speed", "depth"], p=[0.3, 0.3, 0.2, 0.2])
        if action == "leg":
            t += rng.uniform(20.0, 60.0)
        elif action == "turn":
            turn(np.deg2rad(rng.choice([90.0, 180.0])) * rng.choice([-1.0, 1.0]), rng.uniform(15.0, 40.0))
        elif action == "speed":
            speed_to(rng.uniform(min_speed, max_speed), rng.uniform(0.1, 0.3))
        else:
            target = -rng.uniform(5.0, max_depth_m)
            if abs(target - height) >= 5.0:
                climb(float(np.clip(target - height, -15.0, 15.0)), np.deg2rad(rng.uniform(5.0, 10.0)))
        if t > duration_s:  # no room: undo and cruise to the end
            t, v, height, lengths = saved
            for k, n in lengths.items():
                del tr[k][n:]
            break

    def profile(name):
        return SmoothSteps(0.0, *np.array(tr[name]).reshape(-1, 3).T)

    return CarTrajectory(start_llh, duration_s, profile("speed"), profile("turn"), profile("grade"),
                         rng.uniform(-np.pi, np.pi), np.deg2rad(0.2))


def make_trajectory(kind: str, duration_s: float, seed=0, start_llh=(0.5328, 1.9959, 30.0), **kw) -> Trajectory:
    """Trajectory of kind "car", "multirotor", "auv" or "static"; start_llh (lat, lon [rad], h [m]); seed an int or
    SeedSequence (unused by "static"); kw go to car_trajectory / multirotor_trajectory / auv_trajectory /
    StaticTrajectory."""
    if kind == "car":
        return car_trajectory(duration_s, seed, start_llh, **kw)
    if kind == "auv":
        return auv_trajectory(duration_s, seed, start_llh, **kw)
    if kind == "multirotor":
        return multirotor_trajectory(duration_s, seed, start_llh, **kw)
    if kind == "static":
        return StaticTrajectory(start_llh, duration_s, **kw)
    raise ValueError(f"unknown trajectory kind {kind!r}")
