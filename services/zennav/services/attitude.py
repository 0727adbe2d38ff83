"""attitude service: seed 000's adaptive PI complementary filter at IMU rate (core: zennav.nodes.attitude).

Wiring table
    subscribes <base>/sensor/**       the sensor stream (zennav.stream.StreamFollower: one stream, cseq order,
                                      late join at the first IMU sample, also after a restart): stream_start ->
                                      new filter; imu -> one filter step; stream_end -> stream summary
               <base>/nav/solution    latest position/velocity -> omega_in_n = omega_ie_n + omega_en_n, used while
                                      at most --rate-max-age old (sample time); with --velocity-source ins (the
                                      default) also the velocity whose derivative, a_b, compensates the vehicle's
                                      own acceleration in the gravity reference (zennav.attitude.acceleration)
               <base>/sensor/gnss/<id> (in the sensor stream) with --velocity-source gnss: the fixes' speed instead,
                                      for when no ins runs
    publishes  <base>/attitude        one per IMU sample: q_nb, roll/pitch/yaw, gyro-bias estimate, rejection
                                      weight, the omega_in_n applied (zeros without a recent ins solution) and the
                                      a_b, v_b applied (zeros when the velocity is stale: older than
                                      --accel-max-age; None with --velocity-source none)

Gains: deploy/attitude.yaml (human units, converted once by zennav.params; --config picks another file).
"""
from __future__ import annotations

import argparse
import sys

from zennav.nodes.attitude import VELOCITY_SOURCES, AttitudeNode
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
    p.add_argument("--velocity-source", choices=VELOCITY_SOURCES, default="ins",
                   help="velocity for the acceleration compensation: ins (nav/solution), gnss (the fixes' speed, "
                        "a vehicle moving along its forward axis), none (the accelerometer alone)")
    p.add_argument("--gnss-id", default="0", help="GNSS sensor id for --velocity-source gnss")
    p.add_argument("--accel-max-age", type=float, default=1.5,
                   help="use a velocity-derived acceleration while at most this old (sample time) [s]")
    p.add_argument("--accel-min-span", type=float, default=0.1,
                   help="difference velocity samples at least this far apart [s]")
    p.add_argument("--queue", type=int, default=1024,
                   help="sensor queue capacity in messages (back-pressure beyond; every queued message holds zenoh's "
                        "receive buffer: 8192 cost about 100 MB of resident memory, benchmarks/memory.py)")
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
    try:
        node = AttitudeNode(pub.put, run.log, config, k.imu(args.imu_id), args.rate_max_age,
                            on_state=lambda d: setattr(run, "detail", d), fetch_start=run.stream_start_of,
                            velocity_source=args.velocity_source, gnss_key=k.gnss(args.gnss_id),
                            accel_min_span_s=args.accel_min_span, accel_max_age_s=args.accel_max_age)
    except ValueError as e:
        return run.fail(f"bad velocity reference settings: {e}")
    node.follower.takeover_after_s = args.takeover_after
    run.log.info("gains from %s: k_p %.4g 1/s, k_i %.4g 1/s^2; gravity reference: %s", origin, *config.gains(),
                 node.reference())
    run.counters = node.counters
    run.bus.subscribe(k.nav_solution(), lambda key, msg, recv_ns: node.on_solution(msg), channel="ring",
                      capacity=64, name="solution")
    # every sensor message of the live stream goes through the cseq merge (GNSS included, or it would leave gaps).
    # A restarted attitude service re-initialises from the stream in flight: it joins late at the next IMU sample
    # and levels from there (counted: late_join). It fetches no history: replaying the ingest's cache from the
    # stream's start would repeat attitudes already published, and the burst stalled a paced stream's restart.
    run.bus.subscribe(k.sensors(), lambda key, msg, recv_ns: node.on_sensor(key, msg), channel="fifo",
                      capacity=args.queue, name="sensors")
    start_ticker(node.follower, run.bus.callback_lock, lambda: run.stopping)
    return run.serve("running", f"waiting for a sensor stream; gains from {origin}; gravity reference: "
                                f"{node.reference()}")


if __name__ == "__main__":
    sys.exit(main())
