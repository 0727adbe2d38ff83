"""ros-bridge service: ROS 2 robots on the same Zenoh network (rmw_zenoh) <-> zennav (core:
zennav.nodes.ros_bridge; key expressions, CDR and attachments: zennav.rmw).

Wiring table
    subscribes <domain>/<--imu-topic>/sensor_msgs::msg::dds_::Imu_/*        sensor_msgs/Imu (FLU)
               <domain>/<--fix-topic>/sensor_msgs::msg::dds_::NavSatFix_/*  sensor_msgs/NavSatFix
               <base>/nav/solution                                         the ins's solution
    publishes  <base>/sensor/stream, <base>/sensor/imu/<id>, <base>/sensor/gnss/<id>   the stream the ins follows
                                                                           (this service is its ingest)
               <domain>/<--out-ns>/fix   sensor_msgs/NavSatFix   the solution (degrees, ENU covariance)
               <domain>/<--out-ns>/odom  nav_msgs/Odometry       map (ENU from the first solution) -> base_link
               <domain>/<--out-ns>/imu   sensor_msgs/Imu         the attitude (orientation only)
    ROS keys carry the type hash of rosbags' Jazzy definitions and the rmw_zenoh attachment (sequence number,
    source timestamp, GID). On stop the stream is flushed and ended (stream_end).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from zennav import rmw
from zennav.nodes.ros_bridge import FIX_TYPE, IMU_TYPE, ODOM_TYPE, RosInput, ros_outputs
from zennav.service import ServiceRunner, add_bus_args


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-ros-bridge", description=__doc__.split("\n\n")[0])
    p.add_argument("--domain", type=int, default=0, help="ROS_DOMAIN_ID")
    p.add_argument("--imu-topic", default="/imu/data")
    p.add_argument("--fix-topic", default="/gnss/fix")
    p.add_argument("--out-ns", default="/zennav", help="namespace of the published fix, odom and imu topics")
    p.add_argument("--frame-id", default="base_link", help="the body frame's name in the published messages")
    p.add_argument("--imu-grade", default="mems", help="IMU noise model: ideal, tactical, mems, consumer")
    p.add_argument("--lever-arm", default="0,0,0", help="GNSS antenna from the IMU, body FRD [m], 'x,y,z'")
    p.add_argument("--latency", type=float, default=0.2, help="[s] how long a sample waits for older ones")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--gnss-id", default="0")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("ros-bridge", args)
    from zennav.sim.scenarios import IMU_GRADES

    if args.imu_grade not in IMU_GRADES:
        return run.fail(f"unknown --imu-grade {args.imu_grade!r}; choose from {sorted(IMU_GRADES)}")
    try:
        lever = [float(x) for x in args.lever_arm.split(",")]
        assert len(lever) == 3
    except (ValueError, AssertionError):
        return run.fail(f"--lever-arm needs 'x,y,z' in metres, got {args.lever_arm!r}")
    k = run.keys
    core = RosInput(f"ros:{args.domain}{args.imu_topic}+{args.fix_topic}", IMU_GRADES[args.imu_grade].noise(),
                    lever, args.latency)
    pubs = {"stream": run.bus.publisher(k.stream()), "imu": run.bus.publisher(k.imu(args.imu_id)),
            "gnss": run.bus.publisher(k.gnss(args.gnss_id))}
    out_types = {"fix": FIX_TYPE, "odom": ODOM_TYPE, "imu": IMU_TYPE}
    ros_pubs = {name: run.bus.publisher(rmw.topic_key(args.domain, f"{args.out_ns}/{name}", t))
                for name, t in out_types.items()}
    gid = {name: rmw.gid_of(f"{run.bus.src}/{name}") for name in out_types}
    seq = {name: 0 for name in out_types}
    origin: list[np.ndarray] = []
    stats = {"ros_imu": 0, "ros_fix": 0, "ros_bad": 0, "solutions_out": 0}
    run.counters = lambda: {**stats, **{f"stream_{kk}": v for kk, v in core.n.items()}, **dict(core.counts)}

    def publish(items) -> None:
        for kind, msg in items:
            pubs[kind].put(msg)

    def on_ros(kind: str, ros_type: str):
        def cb(key: str, payload: bytes, recv_ns: int) -> None:
            try:
                msg = rmw.deserialize(payload, ros_type)
            except Exception as e:  # a payload that is not this type's CDR
                stats["ros_bad"] += 1
                if stats["ros_bad"] <= 3:
                    run.log.warning("undecodable %s on %s: %s", ros_type, key, e)
                return
            stats[f"ros_{kind}"] += 1
            publish(core.on_imu(msg) if kind == "imu" else core.on_fix(msg))
        return cb

    def on_solution(key: str, msg: dict, recv_ns: int) -> None:
        if not origin:
            origin.append(np.asarray(msg["llh"], dtype=float))
        for name, ros_msg in ros_outputs(msg, origin[0], args.frame_id).items():
            att = rmw.attachment(seq[name], time.time_ns(), gid[name])
            seq[name] += 1
            ros_pubs[name].put_raw(rmw.serialize(ros_msg, out_types[name]), attachment=att)
        stats["solutions_out"] += 1

    run.bus.subscribe(rmw.topic_key(args.domain, args.imu_topic, IMU_TYPE, any_hash=True),
                      on_ros("imu", IMU_TYPE), validate=False, channel="fifo", capacity=65536, name="ros-imu")
    run.bus.subscribe(rmw.topic_key(args.domain, args.fix_topic, FIX_TYPE, any_hash=True),
                      on_ros("fix", FIX_TYPE), validate=False, channel="fifo", capacity=4096, name="ros-fix")
    run.bus.subscribe(k.nav_solution(), on_solution, channel="fifo", capacity=65536, name="solution")
    run.ready("running", f"bridging ROS domain {args.domain} {args.imu_topic}, {args.fix_topic} <-> {k.all()}")
    try:
        run.wait()
        lock = run.bus.callback_lock
        if lock is not None:
            with lock:
                publish(core.end())
        else:
            publish(core.end())
        run.log.info("stream ended: %s sent, %s received, rejected %s", core.n, stats, dict(core.counts))
        time.sleep(0.5)  # let the end go out before the session closes
    finally:
        run.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
