"""The vehicle's own acceleration in body axes, ``a_b`` [m/s^2, FRD], from a velocity source: the input that
takes it out of the attitude filter's gravity reference (zennav.attitude.complementary, item 0).

Physics (n = NED, b = FRD): the accelerometer measures ``f_b = C_bn (a_n - g_n)`` with
``a_n = dv_n/dt + (2 omega_ie_n + omega_en_n) x v_n`` (Groves 2013, section 5.4). With the velocity in body
axes ``v_b = C_bn v_n``, ``d(C_bn)/dt = -[omega_nb_b x] C_bn`` and ``omega_nb = omega_ib - omega_ie - omega_en``:

    a_b = C_bn a_n = dv_b/dt + (omega_nb_b + 2 omega_ie_b + omega_en_b) x v_b
        = dv_b/dt + (omega_ib_b + omega_ie_b) x v_b

The rotation term comes from the gyro at IMU rate (less the filter's bias estimate), so a turn's centripetal
acceleration is compensated without the velocity source's delay, as in Euston, Coote, Mahony, Kim & Hamel,
"A complementary filter for attitude estimation of a fixed-wing UAV", IROS 2008 (there ``v_b`` from the
airspeed along x). ``omega_ie_b x v_b`` is left out: at most 7.3e-5 rad/s |v|, 2e-3 m/s^2 (0.01 deg) at 30 m/s.
``dv_b/dt`` is the difference of the newest velocity sample and the newest one at least ``min_span_s`` older,
exact at its span's midpoint for a constant jerk, and held in b until the next sample, ``v_b`` integrated with it
from its sample. A vehicle's along-track and centripetal accelerations are fixed in b, so holding there is right
where it would be wrong in n in a turn. For a low-rate source (``jerk=True``: GNSS) it is extrapolated from its
midpoint to the IMU sample with the jerk between it and the newest difference at least ``min_span_s`` older: the
held difference lags by half its span plus the time since the sample, which at 1 Hz GNSS made the tilt error of
braking on sim:car 3.5 deg instead of 2.2 (benchmarks/attitude_accel.py). A high-rate source (the ins, differenced
over 0.1 s) lags 0.05 s, and the jerk of its velocity steps at GNSS updates costs more than that (rtklibexplorer:
2.1 deg instead of 1.8).

Sources (the functions below give ``v_b``): the ins solution, ``v_b = C_bn v_n`` with the ins's own attitude
(the attitude filter's yaw is free, so its own C_bn could not resolve v_n); GNSS velocity, ``v_b = [|v_n|, 0, 0]``:
a vehicle that moves along its forward axis with the IMU aligned to it (car, fixed-wing without sideslip; not a
multirotor; reversing flips the sign of the rotation term).

Time checks: a sample is used from the IMU time of its own time on (one that arrives ahead of the IMU stream, from
an ins the attitude service lags, waits in a queue); an estimate older than ``max_age_s`` at the IMU sample is
stale and not used (counted); two samples further apart than ``max_age_s`` are not differenced (a gap: the
difference restarts); non-finite or non-increasing samples are rejected (counted).
"""
from __future__ import annotations

import math
from collections import deque

NS = 1_000_000_000
ZERO3 = (0.0, 0.0, 0.0)


def body_velocity_of_solution(q_nb, v_n) -> tuple:
    """v_b = C_bn v_n [m/s, FRD] from an ins solution's q_nb (scalar first) and NED velocity v_n [m/s]."""
    q0, q1, q2, q3 = (float(x) for x in q_nb)
    vn, ve, vd = (float(x) for x in v_n)
    return ((q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) * vn + 2.0 * (q1 * q2 + q0 * q3) * ve
            + 2.0 * (q1 * q3 - q0 * q2) * vd,
            2.0 * (q1 * q2 - q0 * q3) * vn + (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) * ve
            + 2.0 * (q2 * q3 + q0 * q1) * vd,
            2.0 * (q1 * q3 + q0 * q2) * vn + 2.0 * (q2 * q3 - q0 * q1) * ve
            + (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) * vd)


def body_velocity_of_speed(v_n) -> tuple:
    """v_b = [|v_n|, 0, 0] [m/s]: a vehicle moving along its forward axis (GNSS velocity, no attitude)."""
    return (math.sqrt(sum(float(x) ** 2 for x in v_n)), 0.0, 0.0)


def _newest_span_apart(w: deque, item: tuple, span_ns: int) -> tuple | None:
    """Append item (t_ns, ...) to w, keep in w only what is needed to answer again; return the newest earlier
    item at least span_ns older than item (None if there is none)."""
    w.append(item)
    cut = item[0] - span_ns
    while len(w) > 1 and w[1][0] <= cut:
        w.popleft()
    return w[0] if w[0][0] <= cut else None


class AccelerationReference:
    """``a_b`` at IMU samples from a velocity source's ``v_b`` samples (see the module docstring).

    ``add(t_ns, v_b)`` queues a sample (returns '' or the rejection reason); ``at(t_ns, omega_b)`` gives
    ``(a_b, v_b)`` at an IMU sample with the bias-corrected gyro ``omega_b`` [rad/s], or None when there is no
    fresh estimate; ``window`` gives them over a held levelling window, with its mean acceleration.
    jerk: extrapolate dv_b/dt with the jerk (a low-rate source).
    ``counts``: velocity (accepted), not_finite, not_increasing, queue_full (rejected), gap (difference restarted),
    applied, stale (IMU samples with an estimate: used / too old), none (IMU samples before any estimate)."""

    def __init__(self, min_span_s: float = 0.1, max_age_s: float = 1.5, jerk: bool = False, queue: int = 4096):
        if not 0.0 < min_span_s < max_age_s:
            raise ValueError("need 0 < min_span_s < max_age_s")
        self.jerk = bool(jerk)
        self.min_span_ns = int(round(min_span_s * NS))
        self.max_age_ns = int(round(max_age_s * NS))
        self.queue_max = int(queue)
        self._queue: deque = deque()  # (t_ns, v_b) not yet reached by the IMU stream
        self._window: deque = deque()  # (t_ns, v_b) reached: the newest and the newest at least min_span older
        self._diffs: deque = deque()  # (t_mid_ns, dv_b/dt) of the differences, likewise, for the jerk
        self._last_t: int | None = None  # newest sample accepted [ns]
        self._est: tuple | None = None  # (t_ns, v_b, t_mid_ns, dv_b/dt, jerk) of the newest estimate
        self.counts = dict.fromkeys(("velocity", "not_finite", "not_increasing", "queue_full", "gap", "applied",
                                     "stale", "none"), 0)

    def add(self, t_ns: int, v_b) -> str:
        """Queue a velocity sample v_b [m/s, FRD] of time t_ns; '' or the reason it is rejected (counted)."""
        v = tuple(float(x) for x in v_b)
        if not all(math.isfinite(x) for x in v):
            reason = "not_finite"
        elif self._last_t is not None and t_ns <= self._last_t:
            reason = "not_increasing"
        elif len(self._queue) >= self.queue_max:
            reason = "queue_full"
        else:
            self._last_t = t_ns
            self._queue.append((t_ns, v))
            self.counts["velocity"] += 1
            return ""
        self.counts[reason] += 1
        return reason

    def _reach(self, t_ns: int, v: tuple) -> None:
        w = self._window
        if w and t_ns - w[-1][0] > self.max_age_ns:
            w.clear()
            self._diffs.clear()
            self.counts["gap"] += 1
        newest = _newest_span_apart(w, (t_ns, v), self.min_span_ns)
        if newest is None:
            return
        t0, v0 = newest
        t_mid = (t0 + t_ns) // 2
        inv = NS / (t_ns - t0)
        dv = ((v[0] - v0[0]) * inv, (v[1] - v0[1]) * inv, (v[2] - v0[2]) * inv)
        older = _newest_span_apart(self._diffs, (t_mid, dv), self.min_span_ns) if self.jerk else None
        jerk = ZERO3
        if older is not None:
            inv = NS / (t_mid - older[0])
            jerk = ((dv[0] - older[1][0]) * inv, (dv[1] - older[1][1]) * inv, (dv[2] - older[1][2]) * inv)
        self._est = (t_ns, v, t_mid, dv, jerk)

    def window(self, t_ns: list[int], omega_b: list) -> list[tuple | None]:
        """(a_b, v_b) at each IMU time of a levelling window (t_ns increasing) with the bias-corrected gyro
        omega_b [rad/s], from the velocity samples up to its end: dv_b/dt is the change of v_b from the newest
        sample at or before the window's start (the first one after it if none) to the newest at or before its
        end, over their span: the window's mean acceleration, whatever the velocity did inside it (the step of an
        ins velocity at a GNSS update counts once over the window, where the newest min_span_s difference of
        ``at`` would take it as an acceleration of its own); v_b is the newest sample at or before each time (the
        first before any) and a_b = dv_b/dt + omega_b x v_b, so the window's mean of a_b is that of the vehicle.
        A span shorter than min_span_s or a sample older than max_age_s: ``at`` with the estimate known at the
        end, as before. Counted as ``at``."""
        end = t_ns[-1]
        got = []
        q = self._queue
        while q and q[0][0] <= end:
            item = q.popleft()
            self._reach(*item)
            got.append(item)
        first = next((g for g in reversed(got) if g[0] <= t_ns[0]), got[0] if got else None)
        if first is None or got[-1][0] - first[0] < self.min_span_ns or any(
                b[0] - a[0] > self.max_age_ns for a, b in zip(got, got[1:])) or end - got[-1][0] > self.max_age_ns:
            return [self.at(t, w, end) for t, w in zip(t_ns, omega_b)]
        t0, v0 = first
        t1, v1 = got[-1]
        inv = NS / (t1 - t0)
        ax, ay, az = ((v1[0] - v0[0]) * inv, (v1[1] - v0[1]) * inv, (v1[2] - v0[2]) * inv)
        out: list[tuple | None] = []
        k = 0
        for t, (wx, wy, wz) in zip(t_ns, omega_b):
            while k + 1 < len(got) and got[k + 1][0] <= t:
                k += 1
            vx, vy, vz = got[k][1]
            self.counts["applied"] += 1
            out.append(((ax + wy * vz - wz * vy, ay + wz * vx - wx * vz, az + wx * vy - wy * vx), (vx, vy, vz)))
        return out

    def at(self, t_ns: int, omega_b, known_ns: int | None = None) -> tuple | None:
        """(a_b, v_b) at IMU time t_ns: a_b = dv_b/dt + omega_b x v_b [m/s^2] and the extrapolated v_b [m/s];
        None when there is no estimate yet, or it is stale. Velocity samples up to known_ns (default t_ns) are
        taken: a later known_ns lets a held levelling window use the estimate known at its end (whose difference
        spans the window), v_b extrapolated back."""
        q = self._queue
        known = t_ns if known_ns is None else known_ns
        while q and q[0][0] <= known:
            self._reach(*q.popleft())
        est = self._est
        if est is None:
            self.counts["none"] += 1
            return None
        age_ns = t_ns - est[0]
        if age_ns > self.max_age_ns:
            self.counts["stale"] += 1
            return None
        self.counts["applied"] += 1
        t1, (vx, vy, vz), t_mid, (ax, ay, az), (jx, jy, jz) = est
        # dv_b/dt extrapolated linearly from its value at t_mid, v_b integrated with it from t1
        tau, tau1 = (t_ns - t_mid) / NS, (t1 - t_mid) / NS
        age, half = age_ns / NS, 0.5 * (tau * tau - tau1 * tau1)
        vx += ax * age + jx * half
        vy += ay * age + jy * half
        vz += az * age + jz * half
        ax += jx * tau
        ay += jy * tau
        az += jz * tau
        wx, wy, wz = omega_b
        return (ax + wy * vz - wz * vy, ay + wz * vx - wx * vz, az + wx * vy - wy * vx), (vx, vy, vz)
