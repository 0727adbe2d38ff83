"""attitude service: seed 000's adaptive PI complementary filter at IMU rate (core: zennav.nodes.attitude).

Wiring table
    subscribes <base>/sensor/**       the sensor stream (zennav.stream.StreamFollower: one stream, cseq order,
                                      late join at the first IMU sample): stream_start -> new filter; imu -> one
                                      filter step; stream_end -> stream summary
               <base>/nav/solution    latest position/velocity -> omega_in_n = omega_ie_n + omega_en_n, used while
                                      at most --rate-max-age old (sample time)
    publishes  <base>/attitude        one per IMU sample: q_nb, roll/pitch/yaw, gyro-bias estimate, rejection
                                      weight, and the omega_in_n applied (zeros without a recent ins solution)

Gains: deploy/attitude.yaml (human units, converted once by zennav.params; --config picks another file).
"""
from __future__ import annotations

import argparse
import sys

from zennav.nodes.attitude import AttitudeNode
from zennav.params import ParamError, load_attitude_params
from zennav.service import ServiceRunner, add_bus_args
from zennav.stream import start_ticker


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-attitude", description="zennav attitude service (seed 000 filter)")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--config", default=None,
                   help="attitude parameter file (default: ZENNAV_ATTITUDE_CONFIG, else deploy/attitude.yaml)")
    p.add_argument("--rate-max-age", type=float, default=60.0,
                   help="use the ins solution for omega_in_n while it is at most this old (sample time) [s]")
    p.add_argument("--queue", type=int, default=8192, help="sensor queue capacity (back-pressure beyond)")
    p.add_argument("--takeover-after", type=float, default=10.0,
                   help="[s] another source's stream_start replaces the live stream only after this long without a "
                        "message of it (inf: only after its end)")
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
    node.follower.takeover_after_s = args.takeover_after
    run.log.info("gains from %s: k_p %.4g 1/s, k_i %.4g 1/s^2", origin, *config.gains())
    run.counters = node.counters
    run.bus.subscribe(k.nav_solution(), lambda key, msg, recv_ns: node.on_solution(msg), channel="ring",
                      capacity=64, name="solution")
    # every sensor message of the live stream goes through the cseq merge (GNSS included, or it would leave gaps)
    # recovering: a restarted attitude service fetches the ingest's cache and levels again from there
    run.bus.recovering_subscribe(k.sensors(), lambda key, msg, recv_ns: node.on_sensor(key, msg), channel="fifo",
                                 capacity=args.queue, name="sensors")
    start_ticker(node.follower, run.bus.callback_lock, lambda: run.stopping)
    return run.serve("running", f"waiting for a sensor stream; gains from {origin}")


if __name__ == "__main__":
    sys.exit(main())
