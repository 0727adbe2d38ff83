"""attitude service: seed 000's adaptive PI complementary filter (zennav.attitude.complementary) at IMU rate.

Wiring table
    subscribes <base>/sensor/**       stream_start -> new filter; imu -> one filter step (in cseq order);
                                      stream_end -> flush, stream summary
               <base>/nav/solution    latest position/velocity -> omega_in_n = omega_ie_n + omega_en_n
    publishes  <base>/attitude        one per IMU sample: q_nb, roll/pitch/yaw, gyro-bias estimate, rejection
                                      weight, and the omega_in_n applied (zeros without a recent ins solution)

The core is ``AdaptiveComplementaryFilter`` with the gains of deploy/attitude.yaml (human units, converted
once by ``ComplementaryConfig``; ``--config`` picks another file). IMU increments become rates over the
sample's interval: ``omega_ib_b = dtheta / dt``, ``f_b = dvel / dt`` with ``dt = dt_ns / 1e9``.

Order and exactness. Sensor messages are consumed strictly in the ingest's ``cseq`` order, through the same
zennav.stream.StreamFollower as the ins (one stream, one late-join policy). Until the filter is levelled the samples of
the first ``level_time_s`` are held and then run as one ``batch`` (levelling from their mean, as the batch
API does), then every sample is one ``step``; every sample is run with ``omega_in_n`` given (zeros when
none), so the published stream equals ``AdaptiveComplementaryFilter(cfg).batch(omega, f, dt=dt,
omega_in_n=<the published omega_in_n>)`` over the same samples bit for bit
(tests/integration/test_attitude_status.py checks it).

Rate of the navigation frame (seed 000's projected rate): ``omega_in_n`` is computed from the latest
nav/solution (latitude, height, NED velocity) when its sample time is within ``--rate-max-age`` seconds of
the IMU sample, else zeros (no ins, or a dead one). The rate changes slowly (the earth rate with latitude; the
transport rate is about 1 deg/h at 30 m/s), so a solution tens of seconds old is still a good value: the
default limit of 60 s leaves room for the ins to lag behind this service when a recording is streamed as fast
as possible (each consumer's queue holds about 40 s of 200 Hz data). The value applied is published with each
sample, so a consumer can reproduce the output whatever the arrival timing of the solutions was.

A service started in the middle of a stream (restart) joins it at the first IMU sample it receives (counted
``late_join``, see zennav.stream) and levels from there.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from zennav import messages as M
from zennav.params import ParamError, load_attitude_params
from zennav.service import ServiceRunner, add_bus_args
from zennav.stream import StreamFollower

ZERO3 = (0.0, 0.0, 0.0)


def omega_in_n_of(llh, v_n) -> tuple:
    """omega_in_n = omega_ie_n + omega_en_n [rad/s, NED] at llh [rad, rad, m] moving at v_n [m/s]."""
    from zennav.nav import earth

    lat, h = float(llh[0]), float(llh[2])
    w = earth.omega_ie_n(lat) + earth.omega_en_n(lat, h, np.asarray(v_n, dtype=float))
    return tuple(float(x) for x in w)


class AttitudeNode:
    """The transport-free part of the attitude service: feed validated sensor messages with ``on_sensor`` and
    nav solutions with ``on_solution``; it calls ``publish(msg)`` with one attitude message per IMU sample."""

    def __init__(self, publish, log, config, imu_key: str, rate_max_age_s: float = 60.0, on_state=None,
                 fetch_start=None):
        self.publish = publish
        self.log = log
        self.on_state = on_state or (lambda detail: None)
        self.config = config
        self.imu_key = imu_key
        self.rate_max_age_ns = int(rate_max_age_s * 1e9)
        self.filter = None
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
        from zennav.attitude.complementary import AdaptiveComplementaryFilter

        self.filter = AdaptiveComplementaryFilter(self.config)
        self._levelled, self._held, self._held_s = False, [], 0.0
        self._rate = None
        self.log.info("stream %s from %s: filter reset", start["dataset"], start["src"])
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
            s = self.filter.step(dt, omega, f, w_in)
            self._emit(t_ns, s.q_nb.tolist(), s.bias_b.tolist(), s.weight, w_in)
        self.cost_s += time.perf_counter() - t0

    def _run_held(self) -> None:
        held, self._held, self._levelled = self._held, [], True
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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-attitude", description="zennav attitude service (seed 000 filter)")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--config", default=None,
                   help="attitude parameter file (default: ZENNAV_ATTITUDE_CONFIG, else deploy/attitude.yaml)")
    p.add_argument("--rate-max-age", type=float, default=60.0,
                   help="use the ins solution for omega_in_n while it is at most this old (sample time) [s]")
    p.add_argument("--queue", type=int, default=8192, help="sensor queue capacity (back-pressure beyond)")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("attitude", args)
    try:
        config, origin = load_attitude_params(args.config)
    except (ParamError, ValueError, OSError) as e:
        return run.fail(f"bad attitude parameters: {e}")
    k = run.keys
    pub = run.bus.publisher(k.attitude())
    node = AttitudeNode(pub.put, run.log, config, k.imu(args.imu_id), args.rate_max_age,
                        on_state=lambda d: setattr(run, "detail", d), fetch_start=run.stream_start_of)
    run.log.info("gains from %s: k_p %.4g 1/s, k_i %.4g 1/s^2", origin, *config.gains())
    run.counters = node.counters
    run.bus.subscribe(k.nav_solution(), lambda key, msg, recv_ns: node.on_solution(msg), channel="ring",
                      capacity=64, name="solution")
    # every sensor message of the live stream goes through the cseq merge (GNSS included, or it would leave gaps)
    run.bus.subscribe(k.sensors(), lambda key, msg, recv_ns: node.on_sensor(key, msg), channel="fifo",
                      capacity=args.queue, name="sensors")
    return run.serve("running", f"waiting for a sensor stream; gains from {origin}")


if __name__ == "__main__":
    sys.exit(main())
