"""What the navigation engine gives to and takes from the learned INS-error models (shared/ARCHITECTURE.md section 3).

Four target variants; the first three have N and E components:
- "position" (seed 000): the filter's position correction at each fused GNSS fix, as a rate over the
  interval since the previous fix [m/s];
- "velocity" (seed 002, increments of INS minus filter over one interval): the velocity correction, as a
  rate [m/s^2];
- "drift" (seed 002's INS-minus-filter over the outage horizon): free-running shadow INSs are started from
  the filter every `shadow_every_s` and kept for `horizon_s`, each with the bias estimates frozen at its
  start, as the INS is during an outage; at fused fixes each yields (shadow position - filter position) [m].
  This is what a model must predict during an outage, and it grows well above the GNSS noise, unlike the
  one-interval corrections of the first two variants.
- "body_velocity" (forward, right, down): the filter's velocity in the body frame, v_b = C_bn v_n [m/s], at each
  fused fix: a learned motion model of the vehicle (a car's lateral and vertical
  velocity follow its yaw rate and mounting, a multirotor's horizontal velocity its rotor drag, which the
  accelerometer feels), fused during an outage as a body-velocity pseudo-measurement: the INS error it observes
  is the INS's C_bn v_n minus the prediction. The pattern of learned pseudo-measurements of TLIO (Liu et al.,
  IEEE RA-L 2020) and AI-IMU dead reckoning (Brossard, Barrau, Bonnabel, IEEE T-IV 2020); the drag model of a
  multirotor: Leishman, Macdonald, Beard, McLain, IEEE CSM 2014.
Rate features (11): mean specific force f_b [m/s^2] and angular rate omega_ib_b [rad/s] over the interval,
v_n [m/s], sin and cos of the yaw. Drift features (13): time since the start tau [s], mean f_b and omega_ib_b
since the start, v_n of the free INS, sin and cos of the yaw at the start, yaw change since the start [rad].
Body-velocity features (12): mean f_b [m/s^2] and omega_ib_b [rad/s] over the last `body_every_s` (a sample: the
whole GNSS intervals that cover it; a query: exactly that long) and their standard deviations over it: the
vibration, which grows with a car's speed on the road (and a rotor's speed); not the INS's own velocity, which a
model would learn to echo (it equals the target while GNSS is good).
"dvl_beam" (seed 003, steps 2-4): per DVL beam, its error [m/s]: the measured beam velocity minus the beam velocity
the reference motion gives. The seed takes the reference from a PHINS aided by GPS; here, at the surface, the
GNSS-aided filter's own state is the reference, its DVL calibration states (beam biases, scale, mounting) included,
so the target is the error those states do not model (zennav.nav.aid.dvl_learned). Features (3), per beam i at a DVL
update: the innovation of beam i [m/s], the Mahalanobis distance lambda_k = v' S^-1 v of the whole DVL innovation
and the variational-Bayes estimate of R_ii [(m/s)^2]. Standardised as seed 003 step 3.1: the innovation z-scored,
lambda and R min-max scaled to [0, 1] over the training samples (MINMAX_FEATURES). One model for the four beams (the
seed's ANFIS has these three inputs), one query per beam (LearnQuery.beam). Samples only while GNSS is valid,
queries only while it is lost (zennav.nav.aid.dvl_learned emits both).
Samples are emitted only after the filter converged; queries only while no GNSS is fused, every 1.5 GNSS
intervals (rate targets), every second (drift) and every `body_every_s` once 1.5 GNSS intervals passed without
a fix (body velocity), with the same features as the samples.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .earth import dllh_to_ned
from .rotation import wrap_angle
from .strapdown import NavState, mechanize

TARGETS = ("position", "velocity", "drift", "body_velocity", "dvl_beam")
RATE_FEATURES = ("f_x", "f_y", "f_z", "w_x", "w_y", "w_z", "v_n", "v_e", "v_d", "sin_yaw", "cos_yaw")
DRIFT_FEATURES = ("tau",) + RATE_FEATURES[:-2] + ("sin_yaw0", "cos_yaw0", "dyaw")
BODY_FEATURES = RATE_FEATURES[:6] + ("sd_f_x", "sd_f_y", "sd_f_z", "sd_w_x", "sd_w_y", "sd_w_z")
DVL_BEAM_FEATURES = ("innovation", "lambda", "r_vb")
FEATURES = {"position": RATE_FEATURES, "velocity": RATE_FEATURES, "drift": DRIFT_FEATURES,
            "body_velocity": BODY_FEATURES, "dvl_beam": DVL_BEAM_FEATURES}
OUTPUTS = {"position": ("n", "e"), "velocity": ("n", "e"), "drift": ("n", "e"), "body_velocity": ("x", "y", "z"),
           "dvl_beam": ("error",)}
# feature columns scaled min-max to [0, 1] instead of z-scored (seed 003 step 3.1: lambda and R)
MINMAX_FEATURES = {"dvl_beam": (1, 2)}
BODY_EVERY_S = 1.0
QUERY_MARGIN_S = 1e-3  # LearningTap.next_query_ns: far above the rounding of a window's summed dt [s]
# Time between two answers of a target, for the correlation of their errors (zennav.learn.sigma.answer_lag); 0: the
# next sample (rate targets: queries about as often as fixes; drift: samples of several shadows interleave).
ANSWER_PERIOD_S = {"position": 0.0, "velocity": 0.0, "drift": 0.0, "body_velocity": BODY_EVERY_S, "dvl_beam": 0.0}


@dataclass
class LearnSample:
    """One training pair of a target variant: features and the target value (OUTPUTS[target])."""

    t_ns: int
    target: str
    features: np.ndarray
    value: np.ndarray


@dataclass
class LearnQuery:
    """A request for the predicted value of a target variant; dt_s is the interval of a rate target; beam: the
    DVL beam (0-3) of a dvl_beam query (-1 otherwise)."""

    t_ns: int
    target: str
    features: np.ndarray
    dt_s: float
    beam: int = -1


class FeatureWindow:
    """Sums of bias-corrected increments [rad, m/s], of their squares over dt (for the spread of the rates) and
    the yaw [rad] at the window start."""

    def __init__(self, yaw0: float = 0.0):
        self.dtheta = [0.0, 0.0, 0.0]
        self.dvel = [0.0, 0.0, 0.0]
        self.sq = [0.0] * 6  # sums of dvel^2 / dt, then dtheta^2 / dt
        self.dt = 0.0
        self.yaw0 = yaw0

    def add(self, dtheta, dvel, dt: float) -> None:
        a, v, q = self.dtheta, self.dvel, self.sq
        a[0] += dtheta[0]
        a[1] += dtheta[1]
        a[2] += dtheta[2]
        v[0] += dvel[0]
        v[1] += dvel[1]
        v[2] += dvel[2]
        if dt > 0.0:
            q[0] += dvel[0] * dvel[0] / dt
            q[1] += dvel[1] * dvel[1] / dt
            q[2] += dvel[2] * dvel[2] / dt
            q[3] += dtheta[0] * dtheta[0] / dt
            q[4] += dtheta[1] * dtheta[1] / dt
            q[5] += dtheta[2] * dtheta[2] / dt
            self.dt += dt

    def add_block(self, terms: np.ndarray) -> None:
        """add() of n intervals at once: terms (n, 13) the rows of block_terms; the same floats (np.add.accumulate
        sums in order, as add does)."""
        start = np.array([*self.dtheta, *self.dvel, *self.sq, self.dt])
        end = np.add.accumulate(np.vstack([start, terms]), axis=0)[-1].tolist()
        self.dtheta[:], self.dvel[:], self.sq[:], self.dt = end[0:3], end[3:6], end[6:12], end[12]

    def get_state(self) -> dict:
        return {"dtheta": list(self.dtheta), "dvel": list(self.dvel), "sq": list(self.sq), "dt": self.dt,
                "yaw0": float(self.yaw0)}

    @classmethod
    def from_state(cls, st: dict) -> FeatureWindow:
        w = cls(float(st["yaw0"]))
        w.dtheta, w.dvel, w.sq = ([float(x) for x in st[k]] for k in ("dtheta", "dvel", "sq"))
        w.dt = float(st["dt"])
        return w

    def means(self) -> list[float]:
        return [x / self.dt for x in self.dvel] + [x / self.dt for x in self.dtheta]

    def body_features(self) -> np.ndarray:
        """Mean f_b [m/s^2] and omega_ib_b [rad/s] and their standard deviations over the window (time-weighted)."""
        return _body_features(self.dvel + self.dtheta, self.sq, self.dt)

    def rate_features(self, s: NavState) -> np.ndarray:
        yaw = s.euler[2]
        return np.array([*self.means(), s.vn, s.ve, s.vd, math.sin(yaw), math.cos(yaw)])

    def drift_features(self, s: NavState) -> np.ndarray:
        dyaw = float(wrap_angle(s.euler[2] - self.yaw0))
        return np.array([self.dt, *self.means(), s.vn, s.ve, s.vd, math.sin(self.yaw0), math.cos(self.yaw0), dyaw])


class Shadow:
    """A free-running INS started from the filter, its biases frozen [rad/s, m/s^2], with its feature window."""

    def __init__(self, t_ns: int, state: NavState, gyro_bias, accel_bias, prev_dtheta, prev_dvel):
        self.t0_ns, self.state = t_ns, state.copy()
        self.bg, self.ba = list(gyro_bias), list(accel_bias)
        self.prev = (prev_dtheta, prev_dvel)
        self.window = FeatureWindow(state.euler[2])
        self.last_sample_ns = t_ns

    def advance(self, dtheta_raw, dvel_raw, dt: float) -> None:
        bg, ba = self.bg, self.ba
        dth = (dtheta_raw[0] - bg[0] * dt, dtheta_raw[1] - bg[1] * dt, dtheta_raw[2] - bg[2] * dt)
        dv = (dvel_raw[0] - ba[0] * dt, dvel_raw[1] - ba[1] * dt, dvel_raw[2] - ba[2] * dt)
        mechanize(self.state, dth, dv, *self.prev, dt)
        self.prev = (dth, dv)
        self.window.add(dth, dv, dt)

    def get_state(self) -> dict:
        s = self.state
        return {"t0_ns": int(self.t0_ns), "state": [s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3],
                "bg": list(self.bg), "ba": list(self.ba), "prev": [list(self.prev[0]), list(self.prev[1])],
                "window": self.window.get_state(), "last_sample_ns": int(self.last_sample_ns)}

    @classmethod
    def from_state(cls, st: dict) -> Shadow:
        sh = cls.__new__(cls)
        sh.t0_ns, sh.state = int(st["t0_ns"]), NavState(*(float(x) for x in st["state"]))
        sh.bg, sh.ba = [float(x) for x in st["bg"]], [float(x) for x in st["ba"]]
        sh.prev = (tuple(float(x) for x in st["prev"][0]), tuple(float(x) for x in st["prev"][1]))
        sh.window, sh.last_sample_ns = FeatureWindow.from_state(st["window"]), int(st["last_sample_ns"])
        return sh


class LearningTap:
    """The engine's side of the learning loop: windows, shadow INSs, samples and queries (see module docstring).

    horizon_s: longest drift horizon [s]; shadow_every_s: period of shadow starts [s]; sample_every_s: period
    of drift samples per shadow [s]; body_every_s: span of the body-velocity features and period of its queries [s];
    drift: start shadow INSs (the drift target's samples; each advances with every IMU sample)."""

    def __init__(self, horizon_s: float = 60.0, shadow_every_s: float = 10.0, sample_every_s: float = 1.0,
                 body_every_s: float = BODY_EVERY_S, drift: bool = True):
        self.horizon_ns = int(horizon_s * 1e9)
        self.every_ns = int(shadow_every_s * 1e9)
        self.sample_ns = int(sample_every_s * 1e9)
        self.body_every_s = body_every_s
        self.drift = drift
        self.rate_window = FeatureWindow()
        self.body_window = FeatureWindow()  # since the last fix or body-velocity query
        self.body_chunks: deque[FeatureWindow] = deque()  # the last GNSS intervals' windows, back to back
        self.since_fix = FeatureWindow()  # the navigator's own free run since the last fused fix
        self.last_query_ns = 0
        self.shift_ne = np.zeros(2)  # position shift applied by learned drift corrections since the last fix [m]
        self.shadows: list[Shadow] = []
        self.samples: list[LearnSample] = []
        self.queries: list[LearnQuery] = []

    def on_step(self, dtheta_raw, dvel_raw, dtheta, dvel, dt: float) -> None:
        """One IMU interval: raw and bias-corrected increments [rad, m/s] over dt [s]."""
        self.rate_window.add(dtheta, dvel, dt)
        self.body_window.add(dtheta, dvel, dt)
        self.since_fix.add(dtheta, dvel, dt)
        for sh in self.shadows:
            sh.advance(dtheta_raw, dvel_raw, dt)

    def on_block(self, dtheta: np.ndarray, dvel: np.ndarray, dt: np.ndarray) -> None:
        """on_step over n IMU intervals at once while no shadow INS runs (Navigator.run_imu): bias-corrected
        increments (n, 3) [rad, m/s] over dt (n,) [s], each > 0."""
        assert not self.shadows  # a shadow INS needs every sample (on_step)
        terms = block_terms(dtheta, dvel, dt)
        for w in (self.rate_window, self.body_window, self.since_fix):
            w.add_block(terms)

    def next_query_ns(self, t_ns: int, gnss_interval_s: float | None) -> int:
        """A time [ns] before which maybe_query does nothing at the IMU samples after t_ns, whatever they are: each
        window's dt grows by the time elapsed, so each condition of maybe_query is reached no earlier than its
        shortfall after t_ns (less QUERY_MARGIN_S for the rounding of the sums). Navigator.run_imu runs the samples
        before it in its block loop, without maybe_query."""
        if not gnss_interval_s:
            return 2**62
        interval, since = gnss_interval_s, self.since_fix.dt

        def after(s: float) -> float:  # t_ns + s [s] in ns, as a float
            return t_ns + s * 1e9

        rate = after(1.5 * interval - self.rate_window.dt)
        drift = max(float(self.last_query_ns + self.sample_ns), after(interval - since))
        body = max(after(self.body_every_s - self.body_window.dt), after(1.5 * interval - since))
        return int(min(rate, drift, body) - QUERY_MARGIN_S * 1e9)

    def on_fix(self, t_ns: int, s: NavState, dx: np.ndarray, converged: bool, gyro_bias, accel_bias,
               prev_dtheta, prev_dvel) -> None:
        """A fused GNSS position fix at t_ns; dx: the error-state corrections of this fix; s: the filter state."""
        win = self.rate_window
        if converged and win.dt > 0.0:
            features = win.rate_features(s)
            self.samples.append(LearnSample(t_ns, "position", features, dx[0:2] / win.dt))
            self.samples.append(LearnSample(t_ns, "velocity", features, dx[3:5] / win.dt))
        self._body_sample(t_ns, s, converged)
        if converged:
            for sh in self.shadows:
                if t_ns - sh.last_sample_ns >= self.sample_ns:
                    sh.last_sample_ns = t_ns
                    d = sh.state
                    self.samples.append(LearnSample(t_ns, "drift", sh.window.drift_features(d), _ne_offset(d, s)))
        self.shadows = [sh for sh in self.shadows if t_ns - sh.t0_ns < self.horizon_ns] if converged else []
        if converged and self.drift and (not self.shadows or t_ns - self.shadows[-1].t0_ns >= self.every_ns):
            self.shadows.append(Shadow(t_ns, s, gyro_bias, accel_bias, prev_dtheta, prev_dvel))
        self.rate_window = FeatureWindow()
        self.body_window = FeatureWindow()
        self.since_fix = FeatureWindow(s.euler[2])
        self.last_query_ns = t_ns
        self.shift_ne = np.zeros(2)

    def get_state(self) -> dict:
        """Windows, shadow INSs and the samples and queries not yet popped (plain, msgpack-safe)."""
        return {"rate_window": self.rate_window.get_state(), "body_window": self.body_window.get_state(),
                "body_chunks": [c.get_state() for c in self.body_chunks], "since_fix": self.since_fix.get_state(),
                "last_query_ns": int(self.last_query_ns), "shift_ne": self.shift_ne.tolist(),
                "shadows": [sh.get_state() for sh in self.shadows],
                "samples": [[int(x.t_ns), x.target, x.features.tolist(), np.asarray(x.value).tolist()]
                            for x in self.samples],
                "queries": [[int(q.t_ns), q.target, q.features.tolist(), float(q.dt_s), int(q.beam)]
                            for q in self.queries]}

    def set_state(self, st: dict) -> None:
        self.rate_window = FeatureWindow.from_state(st["rate_window"])
        self.body_window = FeatureWindow.from_state(st["body_window"])
        self.body_chunks = deque(FeatureWindow.from_state(c) for c in st["body_chunks"])
        self.since_fix = FeatureWindow.from_state(st["since_fix"])
        self.last_query_ns, self.shift_ne = int(st["last_query_ns"]), np.array(st["shift_ne"], dtype=float)
        self.shadows = [Shadow.from_state(sh) for sh in st["shadows"]]
        self.samples = [LearnSample(int(t), target, np.array(f, dtype=float), np.array(v, dtype=float))
                        for t, target, f, v in st["samples"]]
        self.queries = [LearnQuery(int(q[0]), q[1], np.array(q[2], dtype=float), float(q[3]),
                                   int(q[4]) if len(q) > 4 else -1) for q in st["queries"]]

    def _body_sample(self, t_ns: int, s: NavState, converged: bool) -> None:
        """At a fused fix: slide the body-velocity window by this GNSS interval and sample it once it spans
        body_every_s. An interval that a rate query split (an outage) restarts the window."""
        chunks, win = self.body_chunks, self.rate_window
        if abs(win.dt - self.since_fix.dt) > 1e-9:
            chunks.clear()
        chunks.append(win)
        while len(chunks) > 1 and sum(c.dt for c in chunks) - chunks[0].dt >= self.body_every_s:
            chunks.popleft()
        dt = sum(c.dt for c in chunks)
        if converged and dt >= self.body_every_s:
            sums = [sum(c.dvel[i] for c in chunks) for i in range(3)] + [sum(c.dtheta[i] for c in chunks)
                                                                         for i in range(3)]
            features = _body_features(sums, [sum(c.sq[i] for c in chunks) for i in range(6)], dt)
            self.samples.append(LearnSample(t_ns, "body_velocity", features, s.C_nb.T @ s.v_n))

    def maybe_query(self, t_ns: int, s: NavState, gnss_interval_s: float | None) -> None:
        """While no fix is fused: a rate query every 1.5 GNSS intervals, a drift query every second and a
        body-velocity query every body_every_s."""
        if gnss_interval_s and self.rate_window.dt >= 1.5 * gnss_interval_s:
            features = self.rate_window.rate_features(s)
            for target in ("position", "velocity"):
                self.queries.append(LearnQuery(t_ns, target, features, self.rate_window.dt))
            self.rate_window = FeatureWindow()
        if gnss_interval_s and t_ns - self.last_query_ns >= self.sample_ns and self.since_fix.dt > gnss_interval_s:
            self.last_query_ns = t_ns
            self.queries.append(LearnQuery(t_ns, "drift", self.since_fix.drift_features(s), self.since_fix.dt))
        if gnss_interval_s and self.body_window.dt >= self.body_every_s and self.since_fix.dt >= 1.5 * gnss_interval_s:
            self.queries.append(LearnQuery(t_ns, "body_velocity", self.body_window.body_features(),
                                           self.body_window.dt))
            self.body_window = FeatureWindow()


def block_terms(dtheta: np.ndarray, dvel: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Per interval (n rows), what FeatureWindow.add adds: dtheta, dvel (n, 3) [rad, m/s], their squares over dt
    (n,) [s] (dvel first, as FeatureWindow.sq) and dt: (n, 13)."""
    dt_col = dt[:, None]
    return np.hstack([dtheta, dvel, dvel * dvel / dt_col, dtheta * dtheta / dt_col, dt_col])


def _body_features(sums, sq_sums, dt: float) -> np.ndarray:
    """Means and standard deviations of the rates from the sums of their increments and of increment^2 / dt."""
    mean = np.array(sums) / dt
    return np.concatenate([mean, np.sqrt(np.maximum(np.array(sq_sums) / dt - mean * mean, 0.0))])


def _ne_offset(a: NavState, b: NavState) -> np.ndarray:
    """North and east offset [m] of a from b (small-offset form at b)."""
    return np.array(dllh_to_ned((a.lat - b.lat, a.lon - b.lon, a.h - b.h), b.lat, b.h)[:2])
