"""Seed 000's adaptive complementary attitude filter with PI feedback and accelerometer rejection.

Frames (README.md, Conventions): n = NED, b = forward-right-down; ``q_nb`` (scalar first) maps b to n.
Inputs: gyro rate ``omega_ib_b`` [rad/s], specific force ``f_b`` [m/s^2] (``[0, 0, -g]`` level at
rest), optionally the rate of n w.r.t. the inertial frame ``omega_in_n = omega_ie_n + omega_en_n``
[rad/s] from :mod:`zennav.nav.earth` when the ins service supplies position and velocity, and optionally
the vehicle's own acceleration ``a_b`` [m/s^2] and velocity ``v_b`` [m/s] resolved in b, from a velocity
source (:mod:`zennav.attitude.acceleration`).

The seed's formulas were lost; these are the standard forms, in the seed's structure:

0. Gravity reference (seed 000's high-dynamic claim): the accelerometer measures
   ``f_b = C_bn (a_n - g_n)`` with ``g_n = [0, 0, g]`` and
   ``a_n = dv_n/dt + (2 omega_ie_n + omega_en_n) x v_n`` (the local-navigation-frame velocity equation,
   Groves 2013, section 5.4, solved for the specific force), so the gravity part alone is
   ``-C_bn g_n = f_b - a_b`` with ``a_b = C_bn a_n``. Given ``a_b`` (from a velocity source), every use of
   ``f_b`` below is of ``f_b - a_b``: the error, the rejection deviation and the rest test watch gravity
   alone, and a sustained acceleration no longer tilts the estimate. This is the acceleration-compensated
   complementary filter of Euston, Coote, Mahony, Kim & Hamel, "A complementary filter for attitude
   estimation of a fixed-wing UAV", IROS 2008 (there ``a_b`` from the airspeed and the gyro,
   ``omega x v``). With the velocity the rest test (item 4) also requires ``|v_b| < rest_speed``: a
   vehicle cruising straight with slow pitch changes (a road's grade, below ``rest_gyro``) looks at rest to
   the IMU alone, and learning that rate as a bias tilts the estimate. Without them ``a_b = v_b = 0``: the
   filter alone, as before.
1. Gyro term (seed: projected rate): ``omega_nb_b = omega_ib_b - C_bn omega_in_n`` (0 when not given).
2. Error (seed: measured x predicted gravity): Mahony, Hamel & Pflimlin, "Nonlinear complementary
   filters on the special orthogonal group", IEEE TAC 53(5), 2008, eq. 32 (explicit complementary
   filter): ``e_b = f~_b / g x u_b`` with ``u_b = C_bn [0, 0, -1]`` the predicted specific-force ("up")
   direction, the sign that makes the loop converge. Two standard refinements, both measured on BROAD
   (benchmarks/broad_attitude.py): ``f~_b`` is the specific force low-passed in n
   (``f~_b = C_bn LP(C_nb f_b)``, time constant ``acc_lowpass_s``; as in Laidig & Seel, "VQF", Information
   Fusion 91, 2023, sec. 3.2), which makes the loop second order in the disturbing acceleration; and it
   is scaled by the constant g instead of normalised by ``|f_b|``, so a back-and-forth acceleration
   averages out instead of leaving a bias.
3. Rejection p(a): the piecewise-linear gain factor of Valenti, Dryanovski & Xiao, "Keeping a Good
   Attitude", Sensors 15(8), 2015, eq. 60, of ``d = LP(||f_b| - g|)`` (time constant ``reject_hold_s``):
   1 for ``d <= reject_start``, falling linearly to 0 at ``d = reject_full``.
4. PI correction: ``delta = k_p p e + k_i integral(p e) dt``. The PI acts on the weighted error, so the
   integral (the gyro-bias estimate ``bias_b = -k_i integral(p e) dt``) is held, not switched off,
   while the accelerometer is rejected. Its loop cannot see the bias about the vertical, so at rest
   (``|omega_nb_b - bias_b| < rest_gyro`` and ``||f_b| - g| < rest_acc`` for ``rest_time``) the integral
   also low-passes the rate residual (time constant ``tau_rest_bias_s``), as VQF's rest bias estimation.
5. Update: first-order (Euler) quaternion step
   ``q <- normalize(q + dt/2 q (x) [0, omega_nb_b - bias_b + k_p p e])``.

Gains in human units: ``k_p = 1 / tau_acc``; ``k_i = 1 / (tau_acc tau_bias)``, so the bias converges
with time constant ``tau_bias`` (slow root of ``s^2 + k_p s + k_i``, for ``tau_bias >> 4 tau_acc``).
All time constants must be much longer than the sample interval (Euler discretisation).
The error uses ``f_b`` rotated back over the sample interval by the gyro increment, so measured and
predicted directions refer to the same instant (without it a steady rotation biases the tilt by
about ``|omega| dt``).
Initialisation: levelled from the mean specific force of the first ``level_time_s`` seconds, yaw 0.
The recursion is scalar float math in one loop shared by step and batch, so a split run equals one run
bit for bit.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, fields
from itertools import repeat

import numpy as np

from zennav.nav import alignment
from zennav.nav.earth import G0
from zennav.nav.rotation import euler_to_quat

ZERO3 = (0.0, 0.0, 0.0)


def _velocity_reference(a_b, v_b) -> tuple:
    """(a_b, v_b) with zeros for None; v_b without a_b is refused (it would change nothing)."""
    if a_b is None and v_b is not None:
        raise ValueError("v_b is only used with a_b")
    return (ZERO3 if a_b is None else a_b), (ZERO3 if v_b is None else v_b)


@dataclass(frozen=True)
class ComplementaryConfig:
    """Gains in human units; converted to SI once by :meth:`gains`."""

    tau_acc_s: float = 2.0  # accelerometer correction time constant, k_p = 1 / tau [s]
    acc_lowpass_s: float = 2.0  # low-pass time constant of the specific force in n [s]
    tau_bias_s: float = 30.0  # gyro-bias convergence time constant of the integral [s]
    reject_start_mps2: float = 5.0  # deviation LP(||f| - g|) where p(a) starts to drop [m/s^2]
    reject_full_mps2: float = 40.0  # deviation where p(a) reaches 0 [m/s^2]
    reject_hold_s: float = 1.0  # low-pass time constant of that deviation [s]
    rest_gyro_dps: float = 2.0  # rest if |omega_nb_b - bias_b| below this [deg/s] ...
    rest_acc_mps2: float = 0.5  # ... and ||f| - g| below this [m/s^2] ...
    rest_time_s: float = 1.5  # ... for this long [s] (and |v_b| below rest_speed_mps when v_b is given)
    rest_speed_mps: float = 0.5  # rest needs the velocity reference's |v_b| below this when given [m/s]
    tau_rest_bias_s: float = 3.0  # bias low-pass time constant while at rest [s]
    gravity_mps2: float = G0  # local gravity magnitude g [m/s^2]
    level_time_s: float = 0.5  # accelerometer averaging time for levelling [s]

    def __post_init__(self):
        positive = ("tau_acc_s", "acc_lowpass_s", "tau_bias_s", "reject_hold_s", "tau_rest_bias_s", "gravity_mps2")
        if min(getattr(self, k) for k in positive) <= 0.0:
            raise ValueError(f"{', '.join(positive)} must be positive")
        if min(self.rest_gyro_dps, self.rest_acc_mps2, self.rest_time_s, self.rest_speed_mps) < 0.0:
            raise ValueError("rest thresholds must be non-negative")
        if not 0.0 <= self.reject_start_mps2 < self.reject_full_mps2:
            raise ValueError("need 0 <= reject_start_mps2 < reject_full_mps2")
        if self.level_time_s < 0.0:
            raise ValueError("level_time_s must be non-negative")

    @classmethod
    def from_mapping(cls, mapping: dict) -> ComplementaryConfig:
        """Build from a parameter-file mapping whose keys are the field names (unknown keys rejected)."""
        names = {f.name for f in fields(cls)}
        unknown = set(mapping) - names
        if unknown:
            raise ValueError(f"unknown attitude parameters: {sorted(unknown)}")
        return cls(**{k: float(v) for k, v in mapping.items()})

    def gains(self) -> tuple[float, float]:
        """(k_p [1/s], k_i [1/s^2])."""
        return 1.0 / self.tau_acc_s, 1.0 / (self.tau_acc_s * self.tau_bias_s)


@dataclass(frozen=True)
class AttitudeState:
    """Whole filter state; ``q_nb`` is None until levelled."""

    q_nb: np.ndarray | None  # (4,) scalar first
    bias_b: np.ndarray  # (3,) gyro-bias estimate, the integral term [rad/s]
    weight: float  # last rejection weight p(a) in [0, 1]
    f_lp_n: np.ndarray  # (2,) low-passed north and east specific force [m/s^2]
    deviation_mps2: float  # low-passed ||f| - g| fed to p(a) [m/s^2]
    rest_s: float  # time at rest so far [s]
    t_s: float | None  # last sample time if known [s]


@dataclass(frozen=True)
class AttitudeBatch:
    """Per-sample outputs of :meth:`AdaptiveComplementaryFilter.batch`."""

    q_nb: np.ndarray  # (N, 4)
    bias_b: np.ndarray  # (N, 3) [rad/s]
    weight: np.ndarray  # (N,)


def _run(q, b, m, w, h, r, rows, with_in, with_acc, k_p, k_i, a_lp, g, a_start, a_full, a_hold, rest_w2, rest_a,
         rest_t, a_rest, rest_v2):
    """Advance state (q, b, m, w, h, r) over rows (dt, wx, wy, wz, fx, fy, fz, nx, ny, nz, ax, ay, az, vx, vy, vz);
    return it and outputs (flat array('d'), 8 per row: q_nb, bias_b, weight). with_in: use (nx, ny, nz) =
    omega_in_n; with_acc: use (ax, ay, az) = a_b, the gravity reference being f_b - a_b, and (vx, vy, vz) = v_b,
    rest needing |v_b|^2 < rest_v2.

    a_lp, a_hold, a_rest: inverse time constants [1/s]; rest_w2 = rest gyro threshold^2 [(rad/s)^2].
    """
    q0, q1, q2, q3 = q
    bx, by, bz = b
    mn, me = m
    inv_span = 1.0 / (a_full - a_start)
    inv_g = 1.0 / g
    out = array("d")
    extend = out.extend
    sqrt = math.sqrt
    for dt, wx, wy, wz, fx, fy, fz, nx, ny, nz, ax, ay, az, vx, vy, vz in rows:
        still = True
        if with_acc:
            fx -= ax
            fy -= ay
            fz -= az
            still = vx * vx + vy * vy + vz * vz < rest_v2
        # C_nb from q.
        c11 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
        c12 = 2.0 * (q1 * q2 - q0 * q3)
        c13 = 2.0 * (q1 * q3 + q0 * q2)
        c21 = 2.0 * (q1 * q2 + q0 * q3)
        c22 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
        c23 = 2.0 * (q2 * q3 - q0 * q1)
        if with_in:
            c31 = 2.0 * (q1 * q3 - q0 * q2)
            c32 = 2.0 * (q2 * q3 + q0 * q1)
            c33 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
            wx -= c11 * nx + c21 * ny + c31 * nz
            wy -= c12 * nx + c22 * ny + c32 * nz
            wz -= c13 * nx + c23 * ny + c33 * nz
        # Gyro residual omega_nb_b - bias_b, before correction.
        ux = wx - bx
        uy = wy - by
        uz = wz - bz
        d = sqrt(fx * fx + fy * fy + fz * fz) - g
        if d < 0.0:
            d = -d
        # Rest: residual rate and |f| deviation below thresholds for rest_t seconds -> bias_b <- LP(omega).
        if d < rest_a and ux * ux + uy * uy + uz * uz < rest_w2 and still:
            r += dt
            if r >= rest_t:
                c = dt * a_rest
                bx += c * ux
                by += c * uy
                bz += c * uz
        else:
            r = 0.0
        # Rejection weight p(a) of the low-passed deviation h.
        h += (d - h) * dt * a_hold
        if h <= a_start:
            w = 1.0
        elif h < a_full:
            w = (a_full - h) * inv_span
        else:
            w = 0.0
        # f_b at the end of the interval seen in the start-of-interval frame: f_b + (u dt) x f_b.
        gx = fx + (uy * fz - uz * fy) * dt
        gy = fy + (uz * fx - ux * fz) * dt
        gz = fz + (ux * fy - uy * fx) * dt
        # Horizontal specific force in n, low-passed: (mn, me).
        c = dt * a_lp
        mn += (c11 * gx + c12 * gy + c13 * gz - mn) * c
        me += (c21 * gx + c22 * gy + c23 * gz - me) * c
        if w > 0.0:
            # p * e_b with e_b = C_bn (m_n / g x [0, 0, -1]) = C_bn (-me, mn, 0) / g.
            en = -w * inv_g * me
            ee = w * inv_g * mn
            ex = c11 * en + c21 * ee
            ey = c12 * en + c22 * ee
            ez = c13 * en + c23 * ee
            c = k_i * dt
            bx -= c * ex
            by -= c * ey
            bz -= c * ez
            wx += k_p * ex
            wy += k_p * ey
            wz += k_p * ez
        hd = 0.5 * dt
        rx = (wx - bx) * hd
        ry = (wy - by) * hd
        rz = (wz - bz) * hd
        p0 = q0 - q1 * rx - q2 * ry - q3 * rz
        p1 = q1 + q0 * rx + q2 * rz - q3 * ry
        p2 = q2 + q0 * ry - q1 * rz + q3 * rx
        p3 = q3 + q0 * rz + q1 * ry - q2 * rx
        n = 1.0 / sqrt(p0 * p0 + p1 * p1 + p2 * p2 + p3 * p3)
        q0 = p0 * n
        q1 = p1 * n
        q2 = p2 * n
        q3 = p3 * n
        extend((q0, q1, q2, q3, bx, by, bz, w))
    return (q0, q1, q2, q3), (bx, by, bz), (mn, me), w, h, r, out


class AdaptiveComplementaryFilter:
    """Seed 000 attitude filter; see the module docstring for the equations and references."""

    def __init__(self, config: ComplementaryConfig | None = None):
        self.config = config or ComplementaryConfig()
        self._k_p, self._k_i = self.config.gains()
        self._q: tuple | None = None
        self._b: tuple[float, ...] = (0.0, 0.0, 0.0)
        self._w = 1.0
        self._m: tuple[float, ...] = (0.0, 0.0)
        self._h = 0.0
        self._r = 0.0
        self._t: float | None = None

    # -- state -------------------------------------------------------------------------------------
    def get_state(self) -> AttitudeState:
        """A copy of the whole state."""
        return AttitudeState(
            q_nb=None if self._q is None else np.array(self._q),
            bias_b=np.array(self._b),
            weight=self._w,
            f_lp_n=np.array(self._m),
            deviation_mps2=self._h,
            rest_s=self._r,
            t_s=self._t,
        )

    def set_state(self, state: AttitudeState) -> None:
        """Restore a state from :meth:`get_state` (bit for bit)."""
        self._q = None if state.q_nb is None else tuple(float(v) for v in state.q_nb)
        self._b = tuple(float(v) for v in state.bias_b)
        self._w = float(state.weight)
        self._m = tuple(float(v) for v in state.f_lp_n)
        self._h = float(state.deviation_mps2)
        self._r = float(state.rest_s)
        self._t = None if state.t_s is None else float(state.t_s)

    def level(self, f_b) -> None:
        """Set roll and pitch from specific force f_b [m/s^2] ((3,) or (M, 3), averaged), yaw 0."""
        roll, pitch = alignment.level(np.mean(np.atleast_2d(np.asarray(f_b, dtype=float)), axis=0))
        self._q = tuple(float(v) for v in euler_to_quat((roll, pitch, 0.0)))

    # -- processing --------------------------------------------------------------------------------
    def step(self, dt: float, omega_ib_b, f_b, omega_in_n=None, a_b=None, v_b=None) -> AttitudeState:
        """One sample: interval dt [s], gyro [rad/s] and specific force [m/s^2] in b, optionally omega_in_n
        [rad/s] in n and the vehicle's acceleration a_b [m/s^2] and velocity v_b [m/s] in b (v_b only with a_b);
        levels on first use (from f_b - a_b)."""
        a, v = _velocity_reference(a_b, v_b)
        if self._q is None:
            self.level(np.subtract(f_b, a))
        n = ZERO3 if omega_in_n is None else tuple(float(x) for x in omega_in_n)
        row = (float(dt), *(float(x) for x in omega_ib_b), *(float(x) for x in f_b), *n, *(float(x) for x in a),
               *(float(x) for x in v))
        self._advance([row], omega_in_n is not None, a_b is not None)
        if self._t is not None:
            self._t += float(dt)
        return self.get_state()

    def batch(self, omega_ib_b, f_b, dt=None, t=None, omega_in_n=None, a_b=None, v_b=None) -> AttitudeBatch:
        """Process N samples: omega_ib_b (N, 3) [rad/s], f_b (N, 3) [m/s^2] in b.

        Give either dt [s] (scalar or (N,) sample intervals) or t [s] ((N,) sample times; the first
        interval runs from the state's last time, or is 0 when none is known). omega_in_n [rad/s] is
        (3,) or (N, 3) in n, or None; a_b [m/s^2] and v_b [m/s], the vehicle's acceleration and velocity in b,
        (3,) or (N, 3), or None (the filter alone; v_b only with a_b). Levels from the first level_time_s
        seconds (of f_b - a_b) if not levelled yet.
        """
        omega = np.asarray(omega_ib_b, dtype=float).reshape(-1, 3)
        f = np.asarray(f_b, dtype=float).reshape(-1, 3)
        n = len(omega)
        if len(f) != n:
            raise ValueError("omega_ib_b and f_b need the same number of samples")
        if (dt is None) == (t is None):
            raise ValueError("give exactly one of dt or t")
        if n == 0:
            return AttitudeBatch(q_nb=np.empty((0, 4)), bias_b=np.empty((0, 3)), weight=np.empty(0))
        if t is not None:
            t = np.asarray(t, dtype=float).reshape(n)
            dts = np.diff(t, prepend=self._t if self._t is not None else t[0])
        else:
            dts = np.broadcast_to(np.asarray(dt, dtype=float), (n,))
        acc, vel = (np.asarray(x, dtype=float) for x in _velocity_reference(a_b, v_b))
        if self._q is None:
            n_level = max(1, int(np.searchsorted(np.cumsum(dts), self.config.level_time_s * (1.0 + 1e-9),
                                                 side="right")))
            self.level(f[:n_level] - (acc if acc.shape == (3,) else np.broadcast_to(acc, (n, 3))[:n_level]))
        # Columns as Python floats (constant ones repeated without copies) zipped into rows.
        cols = [repeat(float(dts[0])) if np.ndim(dt) == 0 and t is None else dts.tolist()]
        cols += omega.T.tolist() + f.T.tolist()
        w_in = np.zeros(3) if omega_in_n is None else np.asarray(omega_in_n, dtype=float)
        for v3 in (w_in, acc, vel):
            cols += [repeat(float(v)) for v in v3] if v3.shape == (3,) else np.broadcast_to(v3, (n, 3)).T.tolist()
        out = self._advance(zip(*cols), omega_in_n is not None, a_b is not None)
        if t is not None:
            self._t = float(t[-1])
        elif self._t is not None:
            self._t += float(dts.sum())
        arr = np.frombuffer(out, dtype=float).reshape(n, 8)
        return AttitudeBatch(q_nb=arr[:, :4], bias_b=arr[:, 4:7], weight=arr[:, 7])

    def _advance(self, rows, with_in: bool, with_acc: bool) -> array:
        c = self.config
        self._q, self._b, self._m, self._w, self._h, self._r, out = _run(
            self._q,
            self._b,
            self._m,
            self._w,
            self._h,
            self._r,
            rows,
            with_in,
            with_acc,
            self._k_p,
            self._k_i,
            1.0 / c.acc_lowpass_s,
            c.gravity_mps2,
            c.reject_start_mps2,
            c.reject_full_mps2,
            1.0 / c.reject_hold_s,
            math.radians(c.rest_gyro_dps) ** 2,
            c.rest_acc_mps2,
            c.rest_time_s,
            1.0 / c.tau_rest_bias_s,
            c.rest_speed_mps**2,
        )
        return out
