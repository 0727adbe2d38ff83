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
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from .. import messages as M
from ..stream import StreamFollower

if TYPE_CHECKING:  # the filter is imported when a stream starts
    from ..attitude.complementary import AdaptiveComplementaryFilter

ZERO3 = (0.0, 0.0, 0.0)


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
                 fetch_start=None):
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
        self.counts = {"imu": 0, "published": 0, "rate_applied": 0, "bad_dt": 0, "solutions": 0}
        self.cost_s = 0.0  # time spent in the filter and building the messages [s]
        self.publish_s = 0.0  # time spent in publish (encode + zenoh put, incl. back-pressure waits) [s]

    def on_solution(self, msg: dict) -> None:
        """nav_solution -> omega_in_n for the IMU samples that follow."""
        self.counts["solutions"] += 1
        self._rate = (msg["t_ns"], omega_in_n_of(msg["llh"], msg["v_n"]))

    def _start(self, start: dict, join: dict | None) -> None:
        from ..attitude.complementary import AdaptiveComplementaryFilter

        self.filter = AdaptiveComplementaryFilter(self.config)
        self._levelled, self._held, self._held_s = False, [], 0.0
        self._rate = None
        self.log.info("stream %s from %s%s: filter reset", start["dataset"], start["src"],
                      " (joined late: levelling from here)" if join else "")
        self.on_state(f"filtering stream {start['dataset']} from {start['src']}")

    def _sample(self, key: str, msg: dict) -> None:
        if key == self.imu_key and msg["schema"] == "imu":
            self._imu(msg)

    def _end(self, msg: dict) -> None:
        if self._held:  # a stream shorter than the levelling time: level from what there is
            self._run_held()
        n = self.counts["imu"]
        self.log.info("end of stream %s: %d IMU, %d attitudes published, omega_in_n applied to %d; "
                      "%.2f us per sample in the filter + message, %.2f us publishing; stream %s",
                      self.follower.dataset, n, self.counts["published"], self.counts["rate_applied"],
                      self.cost_us(), 1e6 * self.publish_s / max(n, 1), self.follower.status())
        self.on_state(f"stream {self.follower.dataset} done: {self.counts['published']} attitudes, "
                      f"{self.cost_us():.1f} us per sample")

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
            s = self.filter.step(dt, omega, f, w_in)
            assert s.q_nb is not None  # levelled by the held batch (_run_held)
            self._emit(t_ns, s.q_nb.tolist(), s.bias_b.tolist(), s.weight, w_in)
        self.cost_s += time.perf_counter() - t0

    def _run_held(self) -> None:
        held, self._held, self._levelled = self._held, [], True
        assert self.filter is not None  # samples are held only after on_start (_start) built it
        b = self.filter.batch(np.array([h[2] for h in held]), np.array([h[3] for h in held]),
                              dt=np.array([h[1] for h in held]), omega_in_n=np.array([h[4] for h in held]))
        q, bias, w = b.q_nb.tolist(), b.bias_b.tolist(), b.weight.tolist()
        for i, h in enumerate(held):
            self._emit(h[0], q[i], bias[i], w[i], h[4])

    def _emit(self, t_ns: int, q: list, bias: list, weight: float, w_in) -> None:
        msg = M.attitude_msg(t_ns, q, bias, weight, w_in)
        t0 = time.perf_counter()
        self.publish(msg)
        self.publish_s += time.perf_counter() - t0
        self.counts["published"] += 1

    def cost_us(self) -> float:
        """Filter + message building per IMU sample [us] (publishing excluded)."""
        return 1e6 * (self.cost_s - self.publish_s) / max(self.counts["imu"], 1)

    def counters(self) -> dict:
        n = max(self.counts["imu"], 1)
        return {**self.counts, **self.follower.counts, "cost_us_per_sample": round(self.cost_us(), 2),
                "publish_us_per_sample": round(1e6 * self.publish_s / n, 2), "done": int(self.follower.done)}
