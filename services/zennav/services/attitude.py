"""attitude service: seed 000's adaptive PI complementary filter (zennav.attitude) at IMU rate.

Wiring table
    subscribes <base>/sensor/**       stream_start -> reset the filter; imu -> one filter step
    publishes  <base>/attitude        attitude (q_nb, roll/pitch/yaw, gyro-bias estimate, rejection weight)

IMU increments become rates over the sample interval (omega = dtheta/dt, f = dvel/dt). Until the attitude
core is importable (issue 4) the service starts, announces itself and reports 'not_implemented'.
"""
from __future__ import annotations

import argparse
import math
import sys

from zennav import messages as M
from zennav.service import ServiceRunner, add_bus_args, not_implemented_main


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-attitude", description="zennav attitude service")
    p.add_argument("--imu-id", default="0")
    return add_bus_args(p)


def _euler(q) -> list:
    q0, q1, q2, q3 = q
    c20 = 2 * (q1 * q3 - q0 * q2)
    c21 = 2 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    c10 = 2 * (q1 * q2 + q0 * q3)
    c00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    return [math.atan2(c21, c22), math.atan2(-c20, math.hypot(c21, c22)), math.atan2(c10, c00)]


def main(argv=None) -> int:
    try:
        from zennav.attitude.complementary import AdaptiveComplementaryFilter
    except Exception as e:  # the core of issue 4 has not landed
        return not_implemented_main("attitude", f"attitude core unavailable ({type(e).__name__}: {e})", argv,
                                    ["{base}/sensor/**"])
    args = build_parser().parse_args(argv)
    run = ServiceRunner("attitude", args)
    k = run.keys
    imu_key = k.imu(args.imu_id)
    pub = run.bus.publisher(k.attitude())
    st = {"filter": AdaptiveComplementaryFilter(), "src": None, "imu": 0, "published": 0}

    def on_sensor(key, msg, recv_ns):
        schema = msg["schema"]
        if schema == "stream_start":
            if msg["src"] != st["src"]:
                st["filter"], st["src"] = AdaptiveComplementaryFilter(), msg["src"]
                run.log.info("stream %s: filter reset", msg["dataset"])
            return
        if key != imu_key or schema != "imu":
            return
        dt = msg["dt_ns"] / 1e9
        if dt <= 0.0:
            return
        st["imu"] += 1
        dth, dv = msg["dtheta"], msg["dvel"]
        s = st["filter"].step(dt, [x / dt for x in dth], [x / dt for x in dv])
        q = [float(x) for x in s.q_nb]
        pub.put(M.make("attitude", msg["t_ns"], q_nb=q, euler=_euler(q), gyro_bias=M.floats(s.bias_b),
                       weight=float(s.weight)))
        st["published"] += 1

    run.counters = lambda: {"imu": st["imu"], "published": st["published"]}
    run.bus.subscribe(k.sensors(), on_sensor, channel="fifo", capacity=8192, name="sensors")
    run.ready("running", "adaptive PI complementary filter (seed 000)")
    try:
        run.wait()
    finally:
        run.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
