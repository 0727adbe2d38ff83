"""The navigation engine: strapdown mechanization + error-state Kalman filter (15 INS states, augmented states after
them: the IMU scale factors of the 21-state option, a source's own states through ``add_states``), aided by a list
of sources
(zennav.nav.aid: GNSS position and velocity, learned pseudo-measurements). Step-wise API (``on_imu``, ``on_gnss``,
``on_correction``), no transport: the same object serves the ins service, replay, benchmarks and tests.

The engine keeps the mechanization, the covariance propagation (every cov_interval_s), the one measurement update
(Joseph form, chi-square gate, the source's adaptive R) and the feedback; each source owns its checks, its control
and its measurement model and fills one status record (AidReport) per attempt. The alignment (coarse while the
heading is unknown, then fine and aligned) is zennav.nav.alignment.Alignment.

GNSS fixes are queued by ``on_gnss`` and fused when the IMU stream reaches their time: the IMU interval that
contains a fix time is split there (increments shared linearly), so the update happens at the exact fix time. A
fix older than the current IMU time is fused at once with its position propagated by the velocity over the
(sub-interval) age.

Augmented states (``add_states``): their values live here (``aug_value``), estimate minus truth, corrected
additively by the feedback (value -= dx); Gauss-Markov with their own time constant; no coupling into the INS
states except the scale factors, which the engine applies to the IMU increments: omega = (omega_meas - bg) /
(1 + sg), the same for the accelerometer (eskf's module docstring).

``get_state`` / ``set_state``: everything that determines the future output, as plain numbers, strings, lists and
dicts (msgpack-safe), restored bit for bit into a Navigator built with the same config and initial state.
"""
from __future__ import annotations

import logging
import math
import types
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import earth, kernels
from .aid import MAX_FIX_AGE_S, AidReport, AidSource, FixContext, GnssPosition, Measurement, build_sources
from .alignment import Alignment, coarse_initial
from .eskf import (
    ATT,
    BG,
    N_STATES,
    POS,
    VEL,
    ErrorStateKF,
    chi2_quantile,
    initial_covariance,
    process_noise_psd,
)
from .learning import LearningTap, LearnQuery, LearnSample
from .rotation import euler_to_quat, quat_multiply, quat_to_euler, rotvec_quat_xyz
from .strapdown import NavState, mechanize
from .types import NS, GnssFix, GnssState, InitialState, NavConfig

if TYPE_CHECKING:
    from .smoother import Recorder

__all__ = ["AidReport", "NavSolution", "Navigator", "correct_nav"]

log = logging.getLogger("zennav.nav")

LEARN_SETTLE_S = 10.0  # no training samples for this long after an outage or a covariance reset [s]
STATE_FORMAT = "zennav.nav.Navigator/4"


@dataclass
class NavSolution:
    """Navigation solution of the IMU at t_ns: llh [rad, rad, m], v_n [m/s, NED], q_nb, euler (roll, pitch, yaw)
    [rad], bias estimates [rad/s, m/s^2, body], 1-sigma of position [m, NED], velocity [m/s] and attitude error
    about N, E, D [rad]; gnss_state a GnssState."""

    t_ns: int
    llh: np.ndarray
    v_n: np.ndarray
    q_nb: np.ndarray
    euler: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    std_pos_ned: np.ndarray
    std_v_n: np.ndarray
    std_euler: np.ndarray
    gnss_state: str


def correct_nav(lat, lon, h, v_n, q_nb, dx):
    """Closed-loop correction of navigation states by their estimated errors dx (zennav.nav.eskf order, estimate
    minus truth): one state (lat, lon [rad], h [m] floats, v_n (3,) [m/s, NED], q_nb (4,), dx (n,)) or N states
    (lat, lon, h (N,), v_n (3, N), q_nb (4, N), dx (n, N)). Returns the corrected (lat, lon, h, v_n, q_nb); the
    engine's feedback and the smoother apply their corrections with it."""
    if isinstance(lat, float):
        out = correct_state(lat, lon, h, *(float(x) for x in (*v_n, *q_nb)), np.asarray(dx).tolist())
        return out[0], out[1], out[2], np.array(out[3:6]), np.array(out[6:])
    r_m, r_n = earth.radii(lat)
    lat = lat - dx[0] / (r_m + h)
    lon = lon - dx[1] / ((r_n + h) * np.cos(lat))  # at the corrected latitude
    q = quat_multiply(np.array([rotvec_quat_xyz(*rv) for rv in dx[ATT].T.tolist()]).T, q_nb)
    return lat, lon, h + dx[2], v_n - dx[VEL], q / np.sqrt(np.sum(q * q, axis=0))


def correct_state(lat, lon, h, vn, ve, vd, q0, q1, q2, q3, dx) -> tuple:
    """correct_nav of one state on Python floats (the engine's feedback): lat, lon [rad], h [m], v_n [m/s, NED],
    q_nb and the error dx (a sequence of floats, zennav.nav.eskf order). Returns the 10 corrected values."""
    r_m, r_n = earth.radii(lat)
    lat1 = lat - dx[0] / (r_m + h)
    lon1 = lon - dx[1] / ((r_n + h) * math.cos(lat1))  # at the corrected latitude
    p0, p1, p2, p3 = rotvec_quat_xyz(dx[6], dx[7], dx[8])
    t0 = p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3
    t1 = p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2
    t2 = p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1
    t3 = p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0
    norm = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3)
    return (lat1, lon1, h + dx[2], vn - dx[3], ve - dx[4], vd - dx[5], t0 / norm, t1 / norm, t2 / norm, t3 / norm)


class Navigator:
    """GNSS/INS navigation engine for one vehicle (see the module docstring)."""

    def __init__(self, config: NavConfig, initial: InitialState):
        self.config = config
        self.t_ns = int(initial.t_ns)
        coarse = not initial.heading_is_known()
        if coarse:
            initial = coarse_initial(initial)
        self.state = NavState.from_arrays(initial.llh, initial.v_n, euler_to_quat(initial.euler))
        self.gyro_bias = [float(x) for x in initial.gyro_bias]
        self.accel_bias = [float(x) for x in initial.accel_bias]
        self.kf = ErrorStateKF(initial_covariance(initial, config))
        self._prior_var = np.diag(self.kf.P).copy()  # the 1-sigma^2 each state starts from (_fade's cap)
        # the per-sample arithmetic: zennav.nav.kernels, or its compiled() namespace once run_imu ran compiled (the
        # same floats; the step-wise samples of a compiled replay, its GNSS epochs, then call the compiled kernels)
        self.kernels: types.ModuleType | types.SimpleNamespace = kernels
        self.counters: Counter[str] = Counter()
        self.lever_b = np.asarray(config.lever_arm_b, dtype=float)
        self._q_psd = process_noise_psd(config.imu_noise)
        # F diagonal of the gyro and accelerometer bias Gauss-Markov processes [1/s]
        self._bias_decay = (-1.0 / config.imu_noise.gyro_bias_tau, -1.0 / config.imu_noise.accel_bias_tau)
        self._gates: dict[int, float | None] = {}
        self._prev_dtheta: tuple[float, ...] = (0.0, 0.0, 0.0)
        self._prev_dvel: tuple[float, ...] = (0.0, 0.0, 0.0)
        # the last bias-corrected angle increment [rad] and its interval [s]
        self._omega_dt: tuple[tuple[float, ...], float] = ((0.0, 0.0, 0.0), 1.0)
        self._cov_dt = 0.0
        self._cov_dvel = [0.0, 0.0, 0.0]
        self._cov_dtheta = [0.0, 0.0, 0.0]
        self._imu_sample: tuple[list, list, float] = ([0.0] * 3, [0.0] * 3, 1.0)  # raw increments, interval [s]
        self._pending: list[GnssFix] = []
        self._reports: list[AidReport] = []
        self.tap = LearningTap(config.learn_horizon_s, drift=config.learn_drift) if config.learning else None
        self._dx_since_fix = np.zeros(N_STATES)  # corrections of the GNSS fix being fused
        self.last_dx = np.zeros(N_STATES)  # correction of the last fused update
        self._learn_start_t_ns = self.t_ns + int(config.learn_after_s * NS)
        # zennav.nav.smoother.Recorder (or None): told of every covariance propagation and fused update
        self.recorder: Recorder | None = None
        self._aug_x = np.zeros(0)  # values of the augmented states (estimate minus truth convention as dx)
        self._aug_decay = np.zeros(0)  # their F diagonal: -1/tau [1/s] (0: random constant / random walk)
        self.aug_blocks: dict[str, slice] = {}
        self._scale: tuple[slice, slice] | None = None  # gyro and accelerometer scale factors (21 states)
        if config.scale_factors and (config.imu_noise.has_scale_factors() or any(
                std is not None and np.any(np.asarray(std) > 0)
                for std in (initial.std_gyro_scale, initial.std_accel_scale))):
            self._add_scale_factor_states(initial)
        self.sources: dict[str, AidSource] = {}
        self._inputs: dict[str, list[AidSource]] = {"gnss": []}
        self._step_sources: list[AidSource] = []
        for src in build_sources(config, self.t_ns):
            self.add_source(src)
        # the GNSS state and the outage clock
        self.gnss_pos = next(s for s in self.sources.values() if isinstance(s, GnssPosition))
        self.alignment = Alignment(config, initial, coarse)
        self.alignment.start(self)
        self._update_stds()

    # ------------------------------------------------------------------ inputs
    def on_imu(self, t_ns: int, dtheta_b, dvel_b) -> bool:
        """Process the increments [rad, m/s, body] of the IMU interval ending at t_ns. Returns False when the
        sample is rejected (counted under its reason); the solution is then `solution()`."""
        dtheta, dvel = ([float(x) for x in d] if not isinstance(d, np.ndarray) else d.astype(float).tolist()
                        for d in (dtheta_b, dvel_b))
        if not all(map(math.isfinite, dtheta + dvel)) or len(dtheta) != 3 or len(dvel) != 3:
            return self._reject_imu("imu_nonfinite", t_ns)
        if t_ns <= self.t_ns:
            return self._reject_imu("imu_duplicate" if t_ns == self.t_ns else "imu_out_of_order", t_ns)
        self._imu_sample = (dtheta, dvel, (t_ns - self.t_ns) / NS)
        while self._pending and self._pending[0].t_ns <= t_ns:
            fix = self._pending.pop(0)
            if fix.t_ns > self.t_ns:
                frac = (fix.t_ns - self.t_ns) / (t_ns - self.t_ns)
                self._advance(fix.t_ns, [frac * x for x in dtheta], [frac * x for x in dvel])
                dtheta = [(1.0 - frac) * x for x in dtheta]
                dvel = [(1.0 - frac) * x for x in dvel]
            self._fuse_gnss(fix)
        self._advance(t_ns, dtheta, dvel)
        for src in self._step_sources:
            src.on_step(self)
        if self.tap is not None:
            self.tap.maybe_query(self.t_ns, self.state, self.gnss_pos.interval_s)
        return True

    def run_imu(self, t_ns: np.ndarray, dtheta_b: np.ndarray, dvel_b: np.ndarray, k0: int, k1: int, stop_ns: int,
                out_nav: np.ndarray, out_std: np.ndarray, jit: bool = False) -> int:
        """Process IMU samples k0, k0 + 1, ... of (t_ns (N,) int64 [ns], dtheta_b, dvel_b (N, 3) [rad, m/s, body]) as
        on_imu would, in one loop (zennav.nav.kernels.run_block; compiled by numba with jit), until k1 or before the
        first sample that needs the step-wise engine: one at or after stop_ns or a queued GNSS fix (to fuse in it),
        one that a source's on_step acts on (the outage declaration, a constraint's update), one to reject.
        Row k of out_nav (N, 10: lat, lon, h, v_n, q_nb) and out_std (N, 9: the 1-sigma of position [m, NED], velocity
        [m/s, NED] and attitude error [rad], as std_pos_ned, std_v_n, std_att) is the solution after sample k. With
        learning, also before the first sample at which the tap may query (LearningTap.next_query_ns); the tap's
        windows take the stretch's increments at once (LearningTap.on_block).
        Returns the index of the first sample not processed; k0 (none) while the engine takes every sample step-wise:
        coarse alignment, a shadow INS of the learning tap, a smoother recorder, a source acting at any sample."""
        tap = self.tap
        if k0 >= k1 or self.alignment.coarse or (tap is not None and tap.shadows) or self.recorder is not None:
            return k0
        gp = self.gnss_pos
        if self._pending:
            stop_ns = min(stop_ns, self._pending[0].t_ns)
        if tap is not None:
            stop_ns = min(stop_ns, tap.next_query_ns(self.t_ns, gp.interval_s))
        for src in self._step_sources:
            if src is not gp:
                due = src.next_step_ns(self)
                if due is None:
                    return k0
                stop_ns = min(stop_ns, due)
        if t_ns[k0] >= stop_ns:  # the first sample goes step by step (run_block would stop at it)
            return k0
        s = self.state
        nav = np.array([s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3])
        prev = np.array([*self._prev_dtheta, *self._prev_dvel])
        cov = np.array([self._cov_dt, *self._cov_dvel, *self._cov_dtheta])
        P = np.ascontiguousarray(self.kf.P)
        sg0, sa0 = (-1, -1) if self._scale is None else (self._scale[0].start, self._scale[1].start)
        if jit and self.kernels is kernels:
            self.kernels = kernels.compiled()
        run_block = (self.kernels if jit else kernels).run_block
        k = run_block(t_ns, dtheta_b, dvel_b, int(k0), int(k1), int(self.t_ns), int(stop_ns),
                      int(gp.valid_t_ns) if gp.gnss_state is GnssState.VALID else -1,
                      float(self.config.outage_timeout_s), nav, np.array(self.gyro_bias + self.accel_bias),
                      self._aug_x, sg0, sa0, prev, cov, P, self._q_psd, self._aug_decay, *self._bias_decay,
                      float(self.config.cov_interval_s), out_nav, out_std)
        if k == k0:
            return k0
        if tap is not None:  # the increments as _advance corrects them
            dt_k = np.diff(np.concatenate(([self.t_ns], t_ns[k0:k]))) / NS
            dth, dv = (d[k0:k] - np.array(b) * dt_k[:, None] for d, b in ((dtheta_b, self.gyro_bias),
                                                                          (dvel_b, self.accel_bias)))
            if self._scale is not None:
                dth, dv = (d / (1.0 + self.aug_value(sl)) for d, sl in zip((dth, dv), self._scale))
            tap.on_block(dth, dv, dt_k)
        t_before = int(t_ns[k - 2]) if k - 1 > k0 else self.t_ns
        self.t_ns = int(t_ns[k - 1])
        dt = (self.t_ns - t_before) / NS
        self.state = NavState(*nav.tolist())
        self._prev_dtheta, self._prev_dvel = tuple(prev[:3].tolist()), tuple(prev[3:].tolist())
        self._cov_dt, self._cov_dvel, self._cov_dtheta = float(cov[0]), cov[1:4].tolist(), cov[4:7].tolist()
        self._imu_sample = (dtheta_b[k - 1].tolist(), dvel_b[k - 1].tolist(), dt)
        self._omega_dt = (self._prev_dtheta, dt)
        self.kf.P = P
        self._update_stds()
        return int(k)

    def on_gnss(self, fix: GnssFix) -> None:
        """Check a GNSS fix and queue it; it is fused when the IMU stream reaches its time (at once if it is
        already past)."""
        if not all(src.admit(self, fix) for src in self._inputs["gnss"]):
            return
        if fix.t_ns <= self.t_ns:
            self._fuse_gnss(fix)
            return
        k = len(self._pending)
        while k > 0 and self._pending[k - 1].t_ns > fix.t_ns:
            k -= 1
        self._pending.insert(k, fix)

    def on_correction(self, query: LearnQuery, value, std) -> bool:
        """Fuse a compensator's answer (value and its 1-sigma std, in the units of the query's target; see
        zennav.nav.aid.learned) to one of this engine's queries; False when not fused (counted)."""
        src = self.sources.get(f"learned_{query.target}")
        if src is None:
            self.count_rejection("correction_malformed", query.t_ns, "")
            return False
        return src.on_input(self, (query, value, std))

    def on_refusal(self, query: LearnQuery, reason: str) -> None:
        """The compensator refused one of this engine's queries (reason: its code): a source holding data for the
        answer stops waiting for it (zennav.nav.aid.dvl_learned); nothing else changes."""
        src = self.sources.get(f"learned_{query.target}")
        if src is not None:
            src.on_refusal(self, query, reason)

    def learning_started(self, t_ns: int) -> bool:
        """Whether training samples may be taken at t_ns (after learn_after_s, and settled after an outage)."""
        return t_ns >= self._learn_start_t_ns

    def on_aid(self, kind: str, data) -> bool:
        """Hand data of an input kind (one that no dedicated method above takes) to the sources that take it, now;
        returns whether any of them fused a measurement."""
        fused = [src.on_input(self, data) for src in self._inputs.get(kind, ()) if src.admit(self, data)]
        return any(fused)

    def add_source(self, source: AidSource) -> None:
        """Run another aiding source (after those of zennav.nav.aid.build_sources): its inputs are routed to it
        and its on_step runs after every IMU sample; its state is part of get_state."""
        if source.name in self.sources:
            raise ValueError(f"an aiding source named {source.name!r} exists")
        self.sources[source.name] = source
        source.attach(self)
        for kind in source.inputs:
            self._inputs.setdefault(kind, []).append(source)
        if type(source).on_step is not AidSource.on_step:
            self._step_sources.append(source)

    def add_states(self, name: str, std0, q_psd, tau_s: float, x0=None) -> slice:
        """Append len(std0) augmented states to the error state: initial 1-sigma std0 and value x0 (default 0),
        Gauss-Markov with time constant tau_s [s] (math.inf: random constant, or random walk with q_psd) and
        process-noise PSD q_psd [unit^2/s]. Returns their slice in the error state (H columns, dx, P). Call it
        before the first IMU sample; the states are part of get_state."""
        if name in self.aug_blocks:
            raise ValueError(f"augmented states named {name!r} exist")
        std0 = np.atleast_1d(np.asarray(std0, dtype=float))
        k, n = len(std0), self.n_states
        q = np.broadcast_to(np.asarray(q_psd, dtype=float), (k,))
        if not (np.all(np.isfinite(std0)) and np.all(std0 >= 0) and np.all(np.isfinite(q)) and np.all(q >= 0)
                and tau_s > 0):
            raise ValueError(f"augmented states {name!r}: std0 and q_psd must be finite and >= 0, tau_s > 0")
        sl = slice(n, n + k)
        P = np.zeros((n + k, n + k))
        P[:n, :n] = self.kf.P
        P[sl, sl] = np.diag(np.square(std0))
        self.kf.P = P
        self._prior_var = np.concatenate([self._prior_var, np.square(std0)])
        self._q_psd = np.concatenate([self._q_psd, q])
        self._aug_decay = np.concatenate([self._aug_decay, np.full(k, 0.0 if math.isinf(tau_s) else -1.0 / tau_s)])
        self._aug_x = np.concatenate([self._aug_x, np.zeros(k) if x0 is None else np.asarray(x0, dtype=float)])
        self._dx_since_fix = np.zeros(n + k)
        self.last_dx = np.zeros(n + k)
        self.aug_blocks[name] = sl
        return sl

    def reset_states(self, sl: slice, std) -> None:
        """Restart augmented states (sl as returned by add_states): value 0, 1-sigma std, uncorrelated with every
        other state (a new draw of a random constant, e.g. a learned model's error in a new outage)."""
        P = self.kf.P.copy()
        P[sl, :] = 0.0
        P[:, sl] = 0.0
        P[sl, sl] = np.diag(np.square(np.asarray(std, dtype=float)))
        self.kf.P = P
        self._prior_var[sl] = np.diag(P)[sl]
        self._aug_x[sl.start - N_STATES:sl.stop - N_STATES] = 0.0
        if self.recorder is not None:
            self.recorder.on_inflate(self.t_ns, self.kf.P)

    def aug_value(self, sl: slice) -> np.ndarray:
        """The current values of augmented states (a view; read only), sl as returned by add_states."""
        return self._aug_x[sl.start - N_STATES:sl.stop - N_STATES]

    @property
    def n_states(self) -> int:
        """Length of the error state: 15 INS states plus the augmented ones."""
        return self.kf.P.shape[0]

    def on_attitude(self, t_ns: int, roll: float, pitch: float, std: float) -> bool:
        """Roll and pitch [rad] with their 1-sigma std [rad] from an attitude source (e.g. the zennav.attitude filter)
        at t_ns. Taken only during coarse alignment, when at most as uncertain as the tilt known so far; returns
        whether it was taken."""
        return self.alignment.on_attitude(self, t_ns, roll, pitch, std, MAX_FIX_AGE_S)

    def pop_samples(self) -> list[LearnSample]:
        """Training samples produced since the last call (only with config.learning)."""
        if self.tap is None:
            return []
        samples, self.tap.samples = self.tap.samples, []
        return samples

    def pop_queries(self) -> list[LearnQuery]:
        """Prediction requests produced since the last call (only with config.learning)."""
        if self.tap is None:
            return []
        queries, self.tap.queries = self.tap.queries, []
        return queries

    def pop_reports(self) -> list[AidReport]:
        """Aiding status records produced since the last call."""
        reports, self._reports = self._reports, []
        return reports

    # ------------------------------------------------------------------ outputs
    @property
    def gnss_state(self):
        """GnssState of the GNSS position source ("valid" / "outage")."""
        return self.gnss_pos.gnss_state

    @property
    def last_fused_t_ns(self) -> int:
        """Time of the last fused (or, in coarse alignment, tracked) GNSS position fix; the start time before any."""
        return self.gnss_pos.valid_t_ns

    @property
    def align_state(self):
        """AlignState: "coarse", "fine" or "aligned"."""
        return self.alignment.state

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    def imu_rates(self, corrected: bool = True) -> tuple[np.ndarray, np.ndarray, float]:
        """Body rate omega_ib_b [rad/s] and specific force f_b [m/s^2] of the IMU sample being processed, corrected
        with the estimated biases and scale factors (corrected=False: as measured), and its interval [s] (for the
        sources' on_step; the sample's whole interval, however a GNSS fix split it)."""
        dtheta, dvel, dt = self._imu_sample
        if not corrected:
            return np.array(dtheta) / dt, np.array(dvel) / dt, dt
        omega_ib_b = np.array(dtheta) / dt - np.array(self.gyro_bias)
        f_b = np.array(dvel) / dt - np.array(self.accel_bias)
        if self._scale is not None:
            omega_ib_b /= 1.0 + self.aug_value(self._scale[0])
            f_b /= 1.0 + self.aug_value(self._scale[1])
        return omega_ib_b, f_b, dt

    def solution(self) -> NavSolution:
        s = self.state
        q_nb = s.q_nb
        return NavSolution(
            self.t_ns, s.llh, s.v_n, q_nb, quat_to_euler(q_nb), np.array(self.gyro_bias), np.array(self.accel_bias),
            self.std_pos_ned, self.std_v_n, self.std_att, self.gnss_state,
        )

    def status(self) -> dict:
        return {
            "t_ns": self.t_ns,
            "gnss_state": self.gnss_state,
            "last_fused_t_ns": self.last_fused_t_ns,
            "pending_fixes": len(self._pending),
            "counters": dict(self.counters),
            "alignment": self.alignment.status(self),
            "adaptive_r": self.config.adaptive_r,
            "measurement_noise": {name: src.status() for name, src in self.sources.items() if src.R_used is not None},
            "consistency": {name: src.consistency.status() for name, src in self.sources.items()
                            if src.consistency is not None},
        }

    # ------------------------------------------------------------------ for the sources
    def update(self, source: AidSource, m: Measurement) -> bool:
        """The engine's one measurement update of a source's measurement: the source's adaptive R, its
        variational-Bayes R and consistency monitor (gated only; the monitor may scale P first, counted
        {name}_inflated), Joseph form with the chi-square gate, feedback; counted ({name}_fused / {name}_gate) and
        reported."""
        name, z, H, R = source.name, m.z, m.H, m.R
        if H.shape[1] < self.n_states:  # a model of the INS states only: the augmented states do not enter
            H = np.hstack([H, np.zeros((H.shape[0], self.n_states - H.shape[1]))])
        gate = self.gate_threshold(len(z)) if m.gated else None
        PHt = self.kf.P @ H.T
        HPHt = H @ PHt  # the predicted part of the innovation covariance
        est = source.adaptive if m.gated else None
        if est is not None:
            R = est.update(z, HPHt, R)
        vb = source.vb if m.gated else None
        if vb is not None:  # variational-Bayes R (zennav.nav.vbkf), then the update with it
            R = vb.update(z, HPHt, R, m.channels, gate)
        source.R_used = R
        reason, faults = "", list(m.faults)
        # consistency monitoring once aligned or started by a coarse alignment (Alignment.monitored)
        monitor = source.consistency if m.gated and self.alignment.monitored() else None
        if monitor is not None and (factor := monitor.factor(z, HPHt, R)) > 1.0:
            self._fade(factor)  # overconfident on small, steady innovations: fading memory (nav.consistency)
            PHt = self.kf.P @ H.T
            self.counters[f"{name}_inflated"] += 1
            faults.append("inflated")
            if self.recorder is not None:
                self.recorder.on_inflate(self.t_ns, self.kf.P)
        P_before = self.kf.P
        res = self.kf.update(z, H, R, gate, m.gain_states, PHt)
        if res.fused:
            self.feedback(res.dx)
            if self.recorder is not None:
                self.recorder.on_update(self.t_ns, res.dx, P_before, self.kf.P, self._additive_values())
            self.last_dx = res.dx
            self._dx_since_fix += res.dx
            self.counters[f"{name}_fused"] += 1
            source.last_fused_t_ns = int(m.t_ns)
        else:
            reason = f"{name}_gate"
            faults.append("gate")
            self.count_rejection(reason, m.t_ns, f"test ratio {res.test_ratio:.1f}, innovation {np.round(z, 2)}")
        source.report(self, m.t_ns, m.observation.tolist(), res.innovation.tolist(), res.S.diagonal().tolist(),
                      res.test_ratio, res.fused, reason, faults)
        return res.fused

    def gate_threshold(self, dof: int) -> float | None:
        """Chi-square gate of a dof-dimensional innovation (None: gating disabled)."""
        gate = self._gates.get(dof, 0.0)
        if gate == 0.0:
            p = self.config.gate_probability
            gate = self._gates[dof] = chi2_quantile(p, dof) if p > 0 else None
        return gate

    def propagate_covariance(self) -> None:
        """Propagate P over the IMU time summed since the last propagation."""
        dt = self._cov_dt
        if dt <= 0.0:
            return
        s = self.state
        (fx, fy, fz), (ox, oy, oz) = ([x / dt for x in v] for v in (self._cov_dvel, self._cov_dtheta))
        sg0, sa0 = (-1, -1) if self._scale is None else (self._scale[0].start, self._scale[1].start)
        Phi = self.kernels.transition(s.lat, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3, fx, fy, fz, ox, oy, oz,
                                      self._aug_decay, sg0, sa0, *self._bias_decay, dt)
        P_before = self.kf.P
        self.kf.propagate(Phi, self._q_psd, dt, self.kernels)
        if self.recorder is not None:
            self.recorder.on_propagate(self.t_ns, dt, Phi, P_before, self.kf.P, self._additive_values())
        self._cov_dt = 0.0
        self._cov_dvel = [0.0, 0.0, 0.0]
        self._cov_dtheta = [0.0, 0.0, 0.0]
        self._update_stds()

    def feedback(self, dx: np.ndarray) -> None:
        """Apply the estimated error to the navigation state (closed loop) and reset it to zero."""
        s = self.state
        d = dx.tolist()
        s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3 = correct_state(
            s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3, d)
        self.gyro_bias = [b - e for b, e in zip(self.gyro_bias, d[9:12])]
        self.accel_bias = [b - e for b, e in zip(self.accel_bias, d[12:15])]
        if len(dx) > N_STATES:
            self._aug_x -= dx[N_STATES:]
        self._update_stds()

    def start_filter(self, P0: np.ndarray, t_ns: int) -> None:
        """End of coarse alignment: the filter starts at t_ns with covariance P0 of the INS states (the augmented
        states keep their variances, uncorrelated with the new INS states)."""
        n = self.n_states
        if n > N_STATES:
            P = np.zeros((n, n))
            P[:N_STATES, :N_STATES] = P0
            P[N_STATES:, N_STATES:] = self.kf.P[N_STATES:, N_STATES:]
            P0 = P
        self.kf.P = P0
        self._cov_dt, self._cov_dvel, self._cov_dtheta = 0.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        self.hold_learning(t_ns)
        self._update_stds()

    def _fade(self, factor: float) -> None:
        """Fading memory (zennav.nav.consistency): P <- D P D, D = diag(d), d = sqrt(factor) on the navigation states
        (position, velocity, attitude) and, on the IMU biases and the augmented states, only as far as their 1-sigma
        stays within the one they started from (_prior_var); a congruence, so P stays positive semi-definite. Those
        are constants or slow Gauss-Markov processes with priors of their own (a gyro bias, a DVL's mounting): the
        INS's missing process noise is no reason to be less sure of them than before any measurement (scaled with
        the rest, a DVL's yaw mounting went from 0.5 to 8 deg after a coarse alignment, and the heading with it)."""
        var, prior = np.diag(self.kf.P)[BG.start:], self._prior_var[BG.start:]
        d = np.full(self.n_states, math.sqrt(factor))
        d[BG.start:] = np.sqrt(np.clip(np.divide(prior, var, out=np.ones_like(var), where=var > 0.0), 1.0, factor))
        self.kf.P *= np.outer(d, d)

    def hold_learning(self, t_ns: int) -> None:
        """No training samples until LEARN_SETTLE_S after t_ns (an outage, a covariance reset, a filter start)."""
        self._learn_start_t_ns = max(self._learn_start_t_ns, t_ns + int(LEARN_SETTLE_S * NS))

    def add_report(self, report: AidReport) -> None:
        self._reports.append(report)

    def count_rejection(self, reason: str, t_ns, detail: str) -> None:
        self.counters[reason] += 1
        n = self.counters[reason]
        if n <= 3 or n % 1000 == 0:
            log.warning("rejected (%s, #%d) at t=%.3f s %s", reason, n, float(t_ns) / NS, detail)

    # ------------------------------------------------------------------ internals
    def _advance(self, t_ns: int, dtheta: list, dvel: list) -> None:
        dt = (t_ns - self.t_ns) / NS
        bg, ba = self.gyro_bias, self.accel_bias
        dth = (dtheta[0] - bg[0] * dt, dtheta[1] - bg[1] * dt, dtheta[2] - bg[2] * dt)
        dv = (dvel[0] - ba[0] * dt, dvel[1] - ba[1] * dt, dvel[2] - ba[2] * dt)
        if self._scale is not None:
            sg, sa = (self.aug_value(sl).tolist() for sl in self._scale)
            dth = (dth[0] / (1.0 + sg[0]), dth[1] / (1.0 + sg[1]), dth[2] / (1.0 + sg[2]))
            dv = (dv[0] / (1.0 + sa[0]), dv[1] / (1.0 + sa[1]), dv[2] / (1.0 + sa[2]))
        if self.alignment.coarse:
            self._advance_coarse(t_ns, dth, dv, dt)
            return
        mechanize(self.state, dth, dv, self._prev_dtheta, self._prev_dvel, dt, self.kernels)
        if self.tap is not None:
            self.tap.on_step(dtheta, dvel, dth, dv, dt)
        self._prev_dtheta, self._prev_dvel = dth, dv
        self.t_ns = t_ns
        self._cov_dt += dt
        cd = self._cov_dvel
        cd[0] += dv[0]
        cd[1] += dv[1]
        cd[2] += dv[2]
        ct = self._cov_dtheta
        ct[0] += dth[0]
        ct[1] += dth[1]
        ct[2] += dth[2]
        self._omega_dt = (dth, dt)
        if self._cov_dt >= self.config.cov_interval_s:
            self.propagate_covariance()

    def _advance_coarse(self, t_ns: int, dth: tuple, dv: tuple, dt: float) -> None:
        """Coarse alignment step: the attitude from the gyro (roll and pitch hold; the yaw is unknown), the
        velocity held at the last GNSS velocity and the position dead-reckoned on it; the increments [rad, m/s]
        are summed for levelling and gyrocompassing, the horizontal velocity change they integrate to for the
        acceleration method."""
        s = self.state
        lat, lon, h, vn, ve, vd = s.lat, s.lon, s.h, s.vn, s.ve, s.vd
        mechanize(s, dth, dv, self._prev_dtheta, self._prev_dvel, dt)
        self.alignment.add(dth, dv, dt, s.vn - vn, s.ve - ve)
        d_lat, d_lon, d_h = earth.ned_to_dllh((vn * dt, ve * dt, vd * dt), lat, h)
        s.lat, s.lon, s.h = lat + d_lat, lon + d_lon, h + d_h
        s.vn, s.ve, s.vd = vn, ve, vd
        self._prev_dtheta, self._prev_dvel = dth, dv
        self.t_ns = t_ns
        self._omega_dt = (dth, dt)

    def _additive_values(self) -> np.ndarray:
        """Nominal values of the error states after the navigation states (gyro and accel biases, augmented
        states), in state order."""
        return np.concatenate([self.gyro_bias, self.accel_bias, self._aug_x])

    def _update_stds(self) -> None:
        """Refresh the 1-sigma of position [m], velocity [m/s] and attitude error [rad] from P."""
        sd = np.sqrt(self.kf.P.diagonal()[:9])
        self.std_pos_ned, self.std_v_n, self.std_att = sd[POS], sd[VEL], sd[ATT]

    def _add_scale_factor_states(self, initial: InitialState) -> None:
        """The 21-state option: gyro and accelerometer scale factors as Gauss-Markov states (ImuNoise), their
        initial values and 1-sigma from the initial state (default: the ImuNoise 1-sigma)."""
        noise = self.config.imu_noise
        blocks = []
        for name, std_gm, tau, x0, std0 in (
            ("gyro_scale", noise.gyro_scale_std, noise.gyro_scale_tau, initial.gyro_scale, initial.std_gyro_scale),
            ("accel_scale", noise.accel_scale_std, noise.accel_scale_tau, initial.accel_scale,
             initial.std_accel_scale),
        ):
            std0 = np.full(3, std_gm) if std0 is None else np.asarray(std0, dtype=float)
            blocks.append(self.add_states(name, std0, 2.0 * std_gm**2 / tau, tau, x0))
        self._scale = (blocks[0], blocks[1])

    def _fuse_gnss(self, fix: GnssFix) -> None:
        """A fix at the engine's time: each GNSS source in turn (position, then velocity), then the alignment
        check and the learning tap."""
        self.propagate_covariance()
        self._dx_since_fix = np.zeros(self.n_states)
        dth, dt = self._omega_dt
        ctx = FixContext(fix, (self.t_ns - fix.t_ns) / NS, np.array(dth) / dt, self.alignment.coarse)
        for src in self._inputs["gnss"]:
            src.on_input(self, ctx)
        if ctx.coarse:
            return
        self.alignment.check_aligned(self, fix.t_ns)
        if self.tap is not None and ctx.position_fused:
            self.tap.on_fix(fix.t_ns, self.state, self._dx_since_fix, fix.t_ns >= self._learn_start_t_ns,
                            self.gyro_bias, self.accel_bias, self._prev_dtheta, self._prev_dvel)

    def _reject_imu(self, reason: str, t_ns) -> bool:
        self.count_rejection(reason, t_ns, "")
        return False

    # ------------------------------------------------------------------ whole state
    def get_state(self) -> dict:
        """Everything that determines the future output, as plain numbers, strings, lists and dicts (msgpack-safe;
        floats exact). Restore with ``set_state`` into a Navigator built with the same config and initial state."""
        s = self.state
        return {
            "format": STATE_FORMAT,
            "t_ns": int(self.t_ns),
            "nav": [s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3],
            "gyro_bias": list(self.gyro_bias),
            "accel_bias": list(self.accel_bias),
            "P": self.kf.P.tolist(),
            "std": [self.std_pos_ned.tolist(), self.std_v_n.tolist(), self.std_att.tolist()],
            "prev_dtheta": list(self._prev_dtheta),
            "prev_dvel": list(self._prev_dvel),
            "omega_dt": [list(self._omega_dt[0]), self._omega_dt[1]],
            "cov_dt": self._cov_dt,
            "cov_dvel": list(self._cov_dvel),
            "cov_dtheta": list(self._cov_dtheta),
            "aug": {"blocks": {k: [v.start, v.stop] for k, v in self.aug_blocks.items()}, "x": self._aug_x.tolist()},
            "prior_var": self._prior_var.tolist(),
            "pending": [_fix_to_map(f) for f in self._pending],
            "reports": [vars(r).copy() for r in self._reports],
            "dx_since_fix": self._dx_since_fix.tolist(),
            "last_dx": self.last_dx.tolist(),
            "learn_start_t_ns": int(self._learn_start_t_ns),
            "counters": dict(self.counters),
            "alignment": self.alignment.get_state(),
            "sources": {name: src.get_state() for name, src in self.sources.items()},
            "tap": None if self.tap is None else self.tap.get_state(),
        }

    def set_state(self, state: dict) -> None:
        """Restore a ``get_state`` dict (also after a msgpack round trip). Raises ValueError for another format or a
        different set of sources (another config)."""
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"not a {STATE_FORMAT} state: {state.get('format')!r}")
        blocks = {k: [v.start, v.stop] for k, v in self.aug_blocks.items()}
        if (set(state["sources"]) != set(self.sources) or (state["tap"] is None) != (self.tap is None)
                or {k: list(v) for k, v in state["aug"]["blocks"].items()} != blocks):
            raise ValueError("the state's aiding sources, augmented states or learning differ from this navigator's "
                             "configuration")
        self.t_ns = int(state["t_ns"])
        self.state = NavState(*(float(x) for x in state["nav"]))
        self.gyro_bias = [float(x) for x in state["gyro_bias"]]
        self.accel_bias = [float(x) for x in state["accel_bias"]]
        self.kf.P = np.array(state["P"], dtype=float)
        self.std_pos_ned, self.std_v_n, self.std_att = (np.array(x, dtype=float) for x in state["std"])
        self._prev_dtheta = tuple(float(x) for x in state["prev_dtheta"])
        self._prev_dvel = tuple(float(x) for x in state["prev_dvel"])
        self._omega_dt = (tuple(float(x) for x in state["omega_dt"][0]), float(state["omega_dt"][1]))
        self._cov_dt = float(state["cov_dt"])
        self._cov_dvel = [float(x) for x in state["cov_dvel"]]
        self._cov_dtheta = [float(x) for x in state["cov_dtheta"]]
        self._aug_x = np.array(state["aug"]["x"], dtype=float)
        if "prior_var" in state:  # a checkpoint from before it: the configuration's
            self._prior_var = np.array(state["prior_var"], dtype=float)
        self._pending = [_fix_from_map(f) for f in state["pending"]]
        self._reports = [AidReport(**r) for r in state["reports"]]
        self._dx_since_fix = np.array(state["dx_since_fix"], dtype=float)
        self.last_dx = np.array(state["last_dx"], dtype=float)
        self._learn_start_t_ns = int(state["learn_start_t_ns"])
        self.counters = Counter({str(k): int(v) for k, v in state["counters"].items()})
        self.alignment.set_state(state["alignment"])
        for name, st in state["sources"].items():
            self.sources[name].set_state(st)
        if self.tap is not None:
            self.tap.set_state(state["tap"])


_FIX_ARRAYS = ("llh", "std_ned", "v_n", "std_v_n")


def _fix_to_map(fix: GnssFix) -> dict:
    out = {k: None if getattr(fix, k) is None else np.asarray(getattr(fix, k), dtype=float).tolist()
           for k in _FIX_ARRAYS}
    return {"t_ns": int(fix.t_ns), "fix": int(fix.fix), "num_sats": int(fix.num_sats), **out}


def _fix_from_map(m: dict) -> GnssFix:
    def optional(key: str) -> np.ndarray | None:
        return None if m[key] is None else np.array(m[key], dtype=float)

    return GnssFix(t_ns=int(m["t_ns"]), llh=np.array(m["llh"], dtype=float),
                   std_ned=np.array(m["std_ned"], dtype=float), v_n=optional("v_n"), std_v_n=optional("std_v_n"),
                   fix=int(m["fix"]), num_sats=int(m["num_sats"]))
