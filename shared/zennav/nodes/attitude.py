"""The attitude service's core, transport-free: seed 000's adaptive PI complementary filter
(zennav.attitude.complementary) over the sensor stream, one attitude message per IMU sample.

IMU increments become rates over the sample's interval: ``omega_ib_b = dtheta / dt``, ``f_b = dvel / dt`` with
``dt = dt_ns / 1e9``. Samples come strictly in the ingest's ``cseq`` order, through zennav.stream.StreamFollower
(one stream; a late joiner joins at its first IMU sample and levels from there). Until the filter is levelled the
samples of the first ``level_time_s`` are held and then run as one ``batch`` (levelling from their mean, as the
batch API does), then every sample is one ``step``; every sample is run with ``omega_in_n`` given (zeros when
none), so the published stream equals ``AdaptiveComplementaryFilter(cfg).batch(omega, f, dt=dt,
omega_in_n=<the published omega_in_n>)`` over the same samples bit for bit
(tests/integration/test_attitude_status.py checks it).

Rate of the navigation frame (seed 000's projected rate): ``omega_in_n`` is computed from the latest
nav/solution (latitude, height, NED velocity) when its sample time is within ``rate_max_age_s`` of the IMU
sample, else zeros (no ins, or a dead one). The rate changes slowly (the earth rate with latitude; the transport
rate is about 1 deg/h at 30 m/s), so a solution tens of seconds old is still a good value: the default limit of
60 s leaves room for the ins to lag behind when a recording is streamed as fast as possible (each consumer's
queue holds about 40 s of 200 Hz data). The value applied is published with each sample, so a consumer can
reproduce the output whatever the arrival timing of the solutions was.

Gravity reference (zennav.attitude.acceleration): with a velocity source the filter takes the vehicle's own
acceleration out of the specific force, ``f_b - a_b`` with ``a_b = dv_b/dt + omega x v_b``. Sources: ``ins`` (the
default: nav/solution's v_n resolved in b with the solution's q_nb), ``gnss`` (the GNSS fixes' speed along the
forward axis, for when no ins runs; its differences extrapolated with the jerk), ``none`` (the accelerometer
alone, as before). Velocity samples are taken in sample-time order as the IMU stream reaches them; an estimate
older than ``accel_max_age_s`` at an IMU sample is not used (counted as stale). The levelling window is
compensated with its mean acceleration: the velocity change across it (AccelerationReference.window). The a_b and
v_b applied are published with each sample (zeros when none was fresh), so a consumer can reproduce the output.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from .. import messages as M
from ..stream import StreamFollower

if TYPE_CHECKING:  # the filter is imported when a stream starts
    from ..attitude.acceleration import AccelerationReference
    from ..attitude.complementary import AdaptiveComplementaryFilter

ZERO3 = (0.0, 0.0, 0.0)
VELOCITY_SOURCES = ("ins", "gnss", "none")
# AccelerationReference.counts -> the service's counters
ACCEL_COUNTERS = {"velocity": "velocity_samples", "not_finite": "velocity_not_finite",
                  "not_increasing": "velocity_not_increasing", "queue_full": "velocity_queue_full",
                  "gap": "velocity_gap", "applied": "accel_applied", "stale": "accel_stale", "none": "accel_none"}


def omega_in_n_of(llh, v_n) -> tuple:
    """omega_in_n = omega_ie_n + omega_en_n [rad/s, NED] at llh [rad, rad, m] moving at v_n [m/s]."""
    from ..nav import earth

    lat, h = float(llh[0]), float(llh[2])
    w = earth.omega_ie_n(lat) + earth.omega_en_n(lat, h, np.asarray(v_n, dtype=float))
    return tuple(float(x) for x in w)


class AttitudeNode:
    """The attitude service's core: feed validated sensor messages with ``on_sensor`` and
    nav solutions with ``on_solution``; it calls ``publish(msg)`` with one attitude message per IMU sample."""

    def __init__(self, publish, log, config, imu_key: str, rate_max_age_s: float = 60.0, on_state=None,
                 fetch_start=None, velocity_source: str = "ins", gnss_key: str | None = None,
                 accel_min_span_s: float = 0.1, accel_max_age_s: float = 1.5):
        if velocity_source not in VELOCITY_SOURCES:
            raise ValueError(f"velocity_source {velocity_source!r} not in {VELOCITY_SOURCES}")
        if velocity_source == "gnss" and gnss_key is None:
            raise ValueError("velocity_source 'gnss' needs gnss_key")
        if not 0.0 < accel_min_span_s < accel_max_age_s:
            raise ValueError("need 0 < accel_min_span_s < accel_max_age_s")
        self.velocity_source = velocity_source
        self.gnss_key = gnss_key
        self.accel_span_age = (accel_min_span_s, accel_max_age_s)
        self.accel: AccelerationReference | None = None  # built at each stream's start, unless source 'none'
        self._bias = ZERO3  # the filter's latest gyro-bias estimate [rad/s], for a_b's rotation term
        self.publish = publish
        self.log = log
        self.on_state = on_state or (lambda detail: None)
        self.config = config
        self.imu_key = imu_key
        self.rate_max_age_ns = int(rate_max_age_s * 1e9)
        self.filter: AdaptiveComplementaryFilter | None = None  # built at each stream's start
        self.follower = StreamFollower(self._start, self._sample, self._end, fetch_start, log)
        self.on_sensor = self.follower.on_message  # every sensor message (GNSS too: the cseq merge needs them)
        self._levelled = False
        self._held: list = []  # (t_ns, dt, omega, f, w_in) until levelled
        self._held_s = 0.0
        self._rate: tuple | None = None  # (t_ns, omega_in_n) of the latest nav solution
        self.counts = {"imu": 0, "published": 0, "rate_applied": 0, "bad_dt": 0, "solutions": 0,
                       "velocity_missing": 0}
        self.cost_s = 0.0  # time spent in the filter and building the messages [s]
        self.publish_s = 0.0  # time spent in publish (encode + zenoh put, incl. back-pressure waits) [s]

    def reference(self) -> str:
        """Which gravity reference the filter uses, in words (the status detail)."""
        return {"ins": "ins velocity (nav/solution) compensated", "gnss": f"GNSS speed ({self.gnss_key}) compensated",
                "none": "accelerometer alone (no velocity source)"}[self.velocity_source]

    def on_solution(self, msg: dict) -> None:
        """nav_solution -> omega_in_n for the IMU samples that follow, and (source 'ins') a velocity sample."""
        self.counts["solutions"] += 1
        self._rate = (msg["t_ns"], omega_in_n_of(msg["llh"], msg["v_n"]))
        if self.velocity_source == "ins" and self.accel is not None:
            from ..attitude.acceleration import body_velocity_of_solution

            self._velocity(msg["t_ns"], body_velocity_of_solution(msg["q_nb"], msg["v_n"]))

    def _velocity(self, t_ns: int, v_b) -> None:
        assert self.accel is not None
        reason = self.accel.add(t_ns, v_b)
        if reason:
            n = self.accel.counts[reason]
            if n <= 5 or n % 1000 == 0:
                self.log.warning("velocity sample at t=%d ns rejected (#%d %s)", t_ns, n, reason)

    def _start(self, start: dict, join: dict | None) -> None:
        from ..attitude.acceleration import AccelerationReference
        from ..attitude.complementary import AdaptiveComplementaryFilter

        self.filter = AdaptiveComplementaryFilter(self.config)
        self._levelled, self._held, self._held_s = False, [], 0.0
        self._rate = None
        self._bias = ZERO3
        self.accel = None if self.velocity_source == "none" else AccelerationReference(
            *self.accel_span_age, jerk=self.velocity_source == "gnss")
        self.log.info("stream %s from %s%s: filter reset; gravity reference: %s", start["dataset"], start["src"],
                      " (joined late: levelling from here)" if join else "", self.reference())
        self.on_state(f"filtering stream {start['dataset']} from {start['src']}; gravity reference: "
                      f"{self.reference()}")

    def _sample(self, key: str, msg: dict) -> None:
        if key == self.imu_key and msg["schema"] == "imu":
            self._imu(msg)
        elif key == self.gnss_key and msg["schema"] == "gnss" and self.velocity_source == "gnss":
            if msg["v_n"] is None:
                self.counts["velocity_missing"] += 1
            else:
                from ..attitude.acceleration import body_velocity_of_speed

                self._velocity(msg["t_ns"], body_velocity_of_speed(msg["v_n"]))

    def _end(self, msg: dict) -> None:
        if self._held:  # a stream shorter than the levelling time: level from what there is
            self._run_held()
        n = self.counts["imu"]
        self.log.info("end of stream %s: %d IMU, %d attitudes published, omega_in_n applied to %d; "
                      "%.2f us per sample in the filter + message, %.2f us publishing; stream %s",
                      self.follower.dataset, n, self.counts["published"], self.counts["rate_applied"],
                      self.cost_us(), 1e6 * self.publish_s / max(n, 1), self.follower.status())
        a = self.accel.counts if self.accel is not None else {}
        self.log.info("gravity reference: %s; a_b applied to %d IMU samples, stale %d, none yet %d; velocity "
                      "samples %d", self.reference(), a.get("applied", 0), a.get("stale", 0), a.get("none", 0),
                      a.get("velocity", 0))
        self.on_state(f"stream {self.follower.dataset} done: {self.counts['published']} attitudes, "
                      f"{self.cost_us():.1f} us per sample; gravity reference: {self.reference()}")

    def _imu(self, msg: dict) -> None:
        t0 = time.perf_counter()
        dt_ns = msg["dt_ns"]
        if dt_ns <= 0:
            self.counts["bad_dt"] += 1
            return
        self.counts["imu"] += 1
        dt = dt_ns / 1e9
        omega = [x / dt for x in msg["dtheta"]]
        f = [x / dt for x in msg["dvel"]]
        t_ns = msg["t_ns"]
        r = self._rate
        if r is not None and abs(t_ns - r[0]) <= self.rate_max_age_ns:
            w_in = r[1]
            self.counts["rate_applied"] += 1
        else:
            w_in = ZERO3
        if not self._levelled:
            # hold the levelling window, then run it as one batch (levels from its mean, as batch does)
            self._held.append((t_ns, dt, omega, f, w_in))
            self._held_s += dt
            if self._held_s > self.config.level_time_s * (1.0 + 1e-9):
                self._run_held()
        else:
            assert self.filter is not None  # the follower hands samples only after on_start (_start) built it
            a_b, v_b = self._accel_at(t_ns, omega)
            s = self.filter.step(dt, omega, f, w_in, a_b, v_b)
            assert s.q_nb is not None  # levelled by the held batch (_run_held)
            self._bias = bias = s.bias_b.tolist()
            self._emit(t_ns, s.q_nb.tolist(), bias, s.weight, w_in, a_b, v_b)
        self.cost_s += time.perf_counter() - t0

    def _accel_at(self, t_ns: int, omega: list, known_ns: int | None = None) -> tuple:
        """(a_b, v_b) for the IMU sample at t_ns: None, None without a velocity source; zeros when none is fresh."""
        if self.accel is None:
            return None, None
        b = self._bias
        r = self.accel.at(t_ns, (omega[0] - b[0], omega[1] - b[1], omega[2] - b[2]), known_ns)
        return r if r is not None else (ZERO3, ZERO3)

    def _run_held(self) -> None:
        held, self._held, self._levelled = self._held, [], True
        assert self.filter is not None  # samples are held only after on_start (_start) built it
        refs: list[tuple] = [(None, None)] * len(held)  # (a_b, v_b) of each held sample
        if self.accel is not None:
            bg = self._bias
            refs = [r if r is not None else (ZERO3, ZERO3) for r in self.accel.window(
                [h[0] for h in held], [(w[0] - bg[0], w[1] - bg[1], w[2] - bg[2]) for w in (h[2] for h in held)])]
        a_b, v_b = (None, None) if self.accel is None else (np.array([r[0] for r in refs]),
                                                            np.array([r[1] for r in refs]))
        b = self.filter.batch(np.array([h[2] for h in held]), np.array([h[3] for h in held]),
                              dt=np.array([h[1] for h in held]), omega_in_n=np.array([h[4] for h in held]),
                              a_b=a_b, v_b=v_b)
        q, bias, w = b.q_nb.tolist(), b.bias_b.tolist(), b.weight.tolist()
        self._bias = bias[-1]
        for i, h in enumerate(held):
            self._emit(h[0], q[i], bias[i], w[i], h[4], *refs[i])

    def _emit(self, t_ns: int, q: list, bias: list, weight: float, w_in, a_b=None, v_b=None) -> None:
        msg = M.attitude_msg(t_ns, q, bias, weight, w_in, a_b, v_b)
        t0 = time.perf_counter()
        self.publish(msg)
        self.publish_s += time.perf_counter() - t0
        self.counts["published"] += 1

    def cost_us(self) -> float:
        """Filter + message building per IMU sample [us] (publishing excluded)."""
        return 1e6 * (self.cost_s - self.publish_s) / max(self.counts["imu"], 1)

    def counters(self) -> dict:
        n = max(self.counts["imu"], 1)
        accel = {} if self.accel is None else {ACCEL_COUNTERS[k]: v for k, v in self.accel.counts.items()}
        return {**self.counts, **self.follower.counts, "velocity_source": self.velocity_source, **accel,
                "cost_us_per_sample": round(self.cost_us(), 2),
                "publish_us_per_sample": round(1e6 * self.publish_s / n, 2), "done": int(self.follower.done)}
