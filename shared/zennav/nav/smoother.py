"""Fixed-interval Rauch-Tung-Striebel smoother of the engine's closed-loop error-state filter (post-processing).

The forward filter (zennav.nav.navigator) feeds every correction back into its nominal state, so its posterior
error mean is always zero and the corrections themselves carry the information. Form followed: the RTS smoother
(Rauch, Tung & Striebel 1965) written for the error of the nominal trajectory with the forward filter's feedback
(the closed-loop error-state smoother of Shin 2005 and Groves 2013 chapter 14), derived here:

    epoch k (a covariance propagation of the engine, every cov_interval_s): nominal x_k+ after the feedback,
    its error dx_k = x_k+ - x (estimate minus truth, zennav.nav.eskf order), forward posterior N(0, P_k+);
    the nominal mechanized on to t_k+1 is x_k+1-, its error dx_k+1- = Phi_k dx_k + w_k ~ N(0, P_k+1-);
    the updates at k+1 estimate that error as u_k+1 (the sum of the corrections fed back at k+1), so
    dx_k+1 = dx_k+1- - u_k+1 (exact for additive states, first order for position and attitude).
    RTS with the forward means 0 (relative to x_k+) and 0 (relative to x_k+1-):
        C_k   = P_k+ Phi_k' (P_k+1-)^-1
        s_k   = C_k (s_k+1 + u_k+1)                      smoothed error of x_k+
        Ps_k  = P_k+ + C_k (Ps_k+1 - P_k+1-) C_k'
    from s_K = 0, Ps_K = P_K+ at the last epoch; the smoothed state is x_k+ corrected by s_k with the engine's own
    feedback formulas (navigator.correct_nav; biases and other additive states: value - s_k).

Stored during the forward pass (Recorder), per epoch: Phi_k and P_k+1- (n x n each), P_k+ (a third n x n matrix
only where an update happened, else the same array as the prior), u_k, the additive states' values and the time:
memory grows linearly with the run's length and with 1/cov_interval_s, as does the backward pass (one n x n solve
and three n x n products per epoch; the rows, one correction each, grow with length and IMU rate only).

A covariance the engine replaces outside its propagation and update is handled by where it happens. At the
current epoch (the GNSS gate reset, between the propagation and the fix's update: the INS taken as wrong,
position and velocity widened and decorrelated so that the fix is taken) the epoch stays linked by the propagated
prior P_k- and its posterior is the filter's (after the reset and the updates): the backward pass takes the
epoch's result N(u_k, P_k+) as given, which is the exact smoother with the epoch's measurements replaced by the
pseudo-measurement of information (P_k+)^-1 - (P_k-)^-1 (tested), and the fix's correction flows back through the
error dynamics into the outage before it. (Taking the reset covariance as the prior instead decorrelates the outage
from the fix and leaves it near the forward error: rtklibexplorer, 30 s outages every 90 s, RMS of the outage
peaks 91 m forward, 84 m that way, 2.3 m bridged.) Anywhere else (the filter's start after coarse alignment) a
new segment starts and nothing is smoothed across.

Between epochs the output rows lie on one mechanized nominal trajectory from x_k+ to x_k+1-, whose smoothed errors
at the ends are s_k and s_k+1 + u_k+1: the row's error is interpolated linearly in time between them (continuous
at the epochs, using both ends; over cov_interval_s the error moves by its smooth dynamics and little noise), its
1-sigma likewise. Rows before the first epoch (coarse alignment) or after the last one of a segment keep the
forward solution.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .navigator import correct_nav
from .types import NS

N_NAV = 9  # position, velocity and attitude errors come first; the states after them are additive (value -= dx)


class Recorder:
    """What the backward pass needs, collected from the engine (``Navigator.recorder = Recorder()``): the engine
    calls on_propagate at each covariance propagation and on_update at each fused update; a replay calls mark_row
    after each output row. Times in ns; values: the nominal values of the additive states (error-state indices 9
    on: gyro and accel biases, augmented states) after the event."""

    def __init__(self) -> None:
        self.t_ns: list[int] = []
        self.Phi: list[np.ndarray | None] = []  # transition from the previous epoch (None: a segment starts)
        self.P_prior: list[np.ndarray | None] = []
        self.P_post: list[np.ndarray] = []
        self.u: list[np.ndarray] = []  # corrections fed back at the epoch, summed
        self.values: list[np.ndarray] = []
        self.u_at_row: dict[int, np.ndarray] = {}  # an epoch's sum when its row was output, if updates followed
        self.segments = 0
        self.bridged = 0
        self._row_t_ns = -1
        self._zero: np.ndarray | None = None  # the u of the epochs without an update (one shared, read-only)

    def on_propagate(self, t_ns: int, dt: float, Phi: np.ndarray, P_before: np.ndarray, P_after: np.ndarray,
                     values: np.ndarray) -> None:
        """Covariance propagated over dt [s] to t_ns with the transition Phi: P_after = Phi P_before Phi' + Qd."""
        if not self.P_post or not np.array_equal(P_before, self.P_post[-1]):
            self._start_segment(t_ns - int(round(dt * NS)), P_before, values)
        P = P_after.copy()  # the engine's own array, which a covariance reset changes in place
        last = self.values[-1]
        self._append(t_ns, Phi, P, P, last if np.array_equal(values, last) else np.array(values, dtype=float))

    def on_update(self, t_ns: int, dx: np.ndarray, P_before: np.ndarray, P_after: np.ndarray,
                  values: np.ndarray) -> None:
        """A fused update at t_ns (the time of the last propagation) whose correction dx was fed back. A covariance
        replaced since the last event is bridged at the epoch (counted in ``bridged``), or starts a new segment
        when its epoch is not the current one (module docstring)."""
        if not self.P_post or not np.array_equal(P_before, self.P_post[-1]):
            if self.P_post and self.t_ns[-1] == t_ns:
                self.bridged += 1
            else:
                self._start_segment(t_ns, P_before, values)
        k = len(self.t_ns) - 1
        if self._row_t_ns == self.t_ns[k] and k not in self.u_at_row:
            self.u_at_row[k] = self.u[k].copy()
        self.u[k] = self.u[k] + dx
        self.P_post[k] = P_after.copy()
        self.values[k] = np.array(values, dtype=float)

    def on_inflate(self, t_ns: int, P_inflated: np.ndarray) -> None:
        """The engine scaled its covariance at t_ns before an update (the fading memory of zennav.nav.consistency:
        extra process noise). Before any update at the current epoch it is the epoch's prior (stored as such, the
        smoother then sees the enlarged process noise); after one, the next update bridges it like a reset."""
        k = len(self.t_ns) - 1
        if k >= 0 and self.t_ns[k] == t_ns and self.P_post[k] is self.P_prior[k] and self.P_prior[k] is not None:
            self.P_prior[k] = self.P_post[k] = P_inflated.copy()

    def mark_row(self, t_ns: int) -> None:
        """An output row of the nominal state at t_ns was taken (after the events so far)."""
        self._row_t_ns = t_ns

    @property
    def n_epochs(self) -> int:
        return len(self.t_ns)

    def nbytes(self) -> int:
        """Bytes held by the stored arrays (each array counted once)."""
        arrays = {id(a): a.nbytes for lst in (self.Phi, self.P_prior, self.P_post, self.u, self.values)
                  for a in lst if a is not None}
        return sum(arrays.values()) + sum(a.nbytes for a in self.u_at_row.values()) + 8 * len(self.t_ns)

    def _start_segment(self, t_ns: int, P: np.ndarray, values) -> None:
        self.segments += 1
        self._append(t_ns, None, None, P.copy(), np.array(values, dtype=float))

    def _append(self, t_ns: int, Phi, P_prior, P_post, values: np.ndarray) -> None:
        """A new epoch (values: the previous epoch's array where unchanged, which the engine's propagation leaves
        them)."""
        if self._zero is None or len(self._zero) != P_post.shape[0]:
            self._zero = np.zeros(P_post.shape[0])
            self._zero.flags.writeable = False
        self.t_ns.append(int(t_ns))
        self.Phi.append(Phi)
        self.P_prior.append(P_prior)
        self.P_post.append(P_post)
        self.u.append(self._zero)
        self.values.append(values)


@dataclass
class Smoothed:
    """The backward pass's result per epoch: t_ns (K,), s (K, n) smoothed error of the forward posterior nominal
    (zennav.nav.eskf order and units), std (K, n) smoothed 1-sigma, values (K, n - 9) smoothed additive states
    (biases [rad/s, m/s^2, body], augmented), u (K, n) the corrections fed back at each epoch, linked (K,)
    whether epoch k follows k-1 by a propagation; u_at_row as in the Recorder; stats: epochs, segments, bridged
    covariance resets, singular priors, stored bytes, wall time of the backward pass [s]."""

    t_ns: np.ndarray
    s: np.ndarray
    std: np.ndarray
    values: np.ndarray
    u: np.ndarray
    linked: np.ndarray
    u_at_row: dict[int, np.ndarray] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


def smooth(rec: Recorder) -> Smoothed:
    """The backward RTS recursion over a Recorder's epochs (see the module docstring)."""
    wall0 = time.perf_counter()
    K = rec.n_epochs
    n = rec.P_post[0].shape[0] if K else N_NAV
    s = np.zeros((K, n))
    var = np.zeros((K, n))
    linked = np.array([phi is not None for phi in rec.Phi], dtype=bool)
    singular = 0
    s_next = np.zeros(n)
    Ps_next = np.zeros((n, n))
    for k in range(K - 1, -1, -1):
        P_post = rec.P_post[k]
        if k == K - 1 or not linked[k + 1]:  # the last epoch of a segment: the forward posterior
            s_k, Ps = np.zeros(n), P_post
        else:
            P_prior = rec.P_prior[k + 1]
            assert P_prior is not None  # linked
            try:
                G = np.linalg.solve(P_prior, rec.Phi[k + 1] @ P_post)  # C_k' = P-^-1 Phi P+
            except np.linalg.LinAlgError:
                singular += 1
                linked[k + 1] = False
                s_k, Ps = np.zeros(n), P_post
            else:
                s_k = G.T @ (s_next + rec.u[k + 1])
                Ps = P_post + G.T @ (Ps_next - P_prior) @ G
                Ps = 0.5 * (Ps + Ps.T)
        s[k] = s_k
        var[k] = np.diag(Ps)
        s_next, Ps_next = s_k, Ps
    values = np.array(rec.values).reshape(K, n - N_NAV) - s[:, N_NAV:]
    stats = {"epochs": K, "segments": rec.segments, "bridged_resets": rec.bridged, "singular_priors": singular,
             "stored_bytes": rec.nbytes(), "backward_wall_s": time.perf_counter() - wall0}
    return Smoothed(np.array(rec.t_ns, dtype=np.int64), s, np.sqrt(np.maximum(var, 0.0)), values,
                    np.array(rec.u).reshape(K, n), linked, dict(rec.u_at_row), stats)


def row_errors(sm: Smoothed, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smoothed error (N, n) and 1-sigma (N, n) of the forward output rows at t_ns (N,) [ns] (rows taken after the
    engine's events at their time), interpolated between epochs (module docstring); covered (N,): rows inside a
    segment (elsewhere error 0 and 1-sigma NaN: the forward solution stands). t_ns increasing."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    N, K = len(t_ns), len(sm.t_ns)
    n = sm.s.shape[1]
    if K == 0:
        return np.zeros((N, n)), np.full((N, n), np.nan), np.zeros(N, dtype=bool)
    k = np.searchsorted(sm.t_ns, t_ns, side="right") - 1
    covered = k >= 0
    k = np.maximum(k, 0)
    # right end of the interval k..k+1: the next epoch's smoothed error relative to the nominal before its updates
    nxt = np.minimum(np.arange(K) + 1, K - 1)
    has_right = np.zeros(K, dtype=bool)
    has_right[:-1] = sm.linked[1:]
    s_right = np.where(has_right[:, None], sm.s[nxt] + sm.u[nxt], sm.s)
    std_right = np.where(has_right[:, None], sm.std[nxt], sm.std)
    covered &= has_right[k] | (t_ns == sm.t_ns[k])
    t_k = sm.t_ns[k]
    span = np.where(has_right, sm.t_ns[nxt] - sm.t_ns, 1)[k]
    w = ((t_ns - t_k) / span)[:, None]
    err = sm.s[k] + w * (s_right[k] - sm.s[k])
    std = sm.std[k] + w * (std_right[k] - sm.std[k])
    for j, u_row in sm.u_at_row.items():  # a row taken at an epoch before some of its updates
        i = int(np.searchsorted(t_ns, sm.t_ns[j]))
        if i < N and t_ns[i] == sm.t_ns[j]:
            err[i] += sm.u[j] - u_row
    err[~covered] = 0.0
    std[~covered] = np.nan
    return err, std, covered


def smooth_rows(sm: Smoothed, t_ns: np.ndarray, llh: np.ndarray, v_n: np.ndarray, q_nb: np.ndarray,
                chunk: int = 65536):
    """The forward rows (llh (N, 3) [rad, rad, m], v_n (N, 3) [m/s], q_nb (N, 4); t_ns increasing) corrected by
    their smoothed errors with the engine's feedback formulas, chunk rows at a time (bounded temporaries). Returns
    llh, v_n, q_nb, std (N, 9) [m NED, m/s, rad] and covered (N,)."""
    N = len(t_ns)
    llh_s, v_s, q_s = np.empty_like(llh), np.empty_like(v_n), np.empty_like(q_nb)
    std, covered = np.empty((N, N_NAV)), np.empty(N, dtype=bool)
    for a in range(0, N, chunk):
        b = min(a + chunk, N)
        err, sd, covered[a:b] = row_errors(sm, t_ns[a:b])
        lat, lon, h, v, q = correct_nav(llh[a:b, 0], llh[a:b, 1], llh[a:b, 2], v_n[a:b].T, q_nb[a:b].T,
                                        err[:, :N_NAV].T)
        llh_s[a:b, 0], llh_s[a:b, 1], llh_s[a:b, 2], v_s[a:b], q_s[a:b] = lat, lon, h, v.T, q.T
        std[a:b] = sd[:, :N_NAV]
    return llh_s, v_s, q_s, std, covered
