"""ROS 2 over Zenoh without a ROS installation: sensor_msgs/Imu and NavSatFix of the simulated drive, serialized
by rosbags and published on rmw_zenoh's key expressions with its attachment, navigated by zennav (ros-bridge +
ins services); the NavSatFix, Odometry and Imu it publishes back are decoded with rosbags and checked against
the simulator's truth."""
from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from zennav_harness import Collector, wait_until

DURATION = 120.0


def _ros_inputs(ds):
    """(t_ns, topic, ros type, CDR) of the drive as a ROS robot publishes it (FLU, ENU, Unix stamps)."""
    from zennav import rmw
    from zennav.gpstime import gps_ns_to_unix_ns
    from zennav.nav.rotation import euler_to_quat
    from zennav.rosframes import cov_ned_to_enu, frd_to_flu, q_nb_to_q_enu_flu

    T = rmw.typestore().types
    vec, quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    out = []
    t, imu, truth = ds.imu.t_ns, ds.imu, ds.truth
    for k in range(1, len(t)):
        dt = (t[k] - t[k - 1]) / 1e9
        w, f = frd_to_flu(imu.dtheta[k] / dt), frd_to_flu(imu.dvel[k] / dt)
        j = min(np.searchsorted(truth.t_ns, t[k]), len(truth.t_ns) - 1)
        q = q_nb_to_q_enu_flu(euler_to_quat(truth.euler[j]))
        msg = T["sensor_msgs/msg/Imu"](
            header=rmw.header(gps_ns_to_unix_ns(t[k]), "imu_link"), orientation=quat(x=q[1], y=q[2], z=q[3], w=q[0]),
            orientation_covariance=np.diag([1e-4] * 3).ravel(), angular_velocity=vec(x=w[0], y=w[1], z=w[2]),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=vec(x=f[0], y=f[1], z=f[2]),
            linear_acceleration_covariance=np.zeros(9))
        out.append((int(t[k]), 1, "/imu/data", "sensor_msgs/msg/Imu", rmw.serialize(msg, "sensor_msgs/msg/Imu")))
    for i in range(len(ds.gnss.t_ns)):
        fx = ds.gnss.fix_at(i)
        cov = cov_ned_to_enu(np.diag(np.square(fx.std_ned)))
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=rmw.header(gps_ns_to_unix_ns(fx.t_ns), "gnss"),
            status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=math.degrees(fx.llh[0]),
            longitude=math.degrees(fx.llh[1]), altitude=float(fx.llh[2]), position_covariance=cov.ravel(),
            position_covariance_type=2)
        out.append((int(fx.t_ns), 0, "/gnss/fix", "sensor_msgs/msg/NavSatFix",
                    rmw.serialize(msg, "sensor_msgs/msg/NavSatFix")))
    return sorted(out, key=lambda x: (x[0], x[1]))


def test_ros2_imu_and_navsatfix_navigated_and_published_back(cluster):
    from zennav import rmw
    from zennav.datasets.registry import load_dataset
    from zennav.gpstime import unix_ns_to_gps_ns
    from zennav.metrics import ned_errors
    from zennav.rosframes import q_enu_flu_to_q_nb

    ds = load_dataset("sim:car", duration_s=DURATION)
    inputs = _ros_inputs(ds)
    keys = {"fix": rmw.topic_key(0, "/zennav/fix", "sensor_msgs/msg/NavSatFix"),
            "odom": rmw.topic_key(0, "/zennav/odom", "nav_msgs/msg/Odometry"),
            "imu": rmw.topic_key(0, "/zennav/imu", "sensor_msgs/msg/Imu")}
    assert keys["fix"] == "0/zennav/fix/sensor_msgs::msg::dds_::NavSatFix_/" \
        "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404"
    got: dict[str, list] = {name: [] for name in keys}
    lock = threading.Lock()
    for name, key in keys.items():
        def on(k, payload, recv_ns, name=name):
            with lock:
                got[name].append(payload)
        cluster.bus.subscribe(key, on, validate=False, channel="fifo", capacity=100_000, name=f"ros-{name}")
    status = Collector(cluster.bus, cluster.keys.nav_status(), channel="ring")
    cluster.service("ins")
    cluster.start("ros-bridge", "zennav.services.ros_bridge", "--latency", "2.0")  # data s: 0.2 s at 10x
    cluster.wait_alive(["ros-bridge"])
    pubs = {topic: cluster.bus.publisher(rmw.topic_key(0, topic, t)) for _t, _o, topic, t, _c in inputs[:300]}
    wait_until(lambda: all(p.matching for p in pubs.values()), 30, "the bridge to subscribe to the ROS topics")
    gid = rmw.gid_of("test-robot")
    wall0 = time.perf_counter()
    for seq, (t, _o, topic, _type, cdr) in enumerate(inputs):
        delay = wall0 + (t - inputs[0][0]) / 1e9 / 10.0 - time.perf_counter()  # 10x real time
        if delay > 0:
            time.sleep(delay)
        pubs[topic].put_raw(cdr, attachment=rmw.attachment(seq, time.time_ns(), gid))
    n_imu = sum(1 for x in inputs if x[2] == "/imu/data")
    st = status.wait(lambda c: next((m for m in c.msgs() if m["imu_count"] >= n_imu - 800), None), 120,
                     "the ins to navigate the ROS stream")
    assert st["stream"]["dataset"].startswith("ros:0/imu/data")
    assert not {"gap", "time_jump", "time_backwards"} & set(st["stream"]), st["stream"]  # in time order, none lost
    wait_until(lambda: len(got["odom"]) >= st["imu_count"] - 50, 60, "the ROS outputs")
    with lock:  # the three topics arrive on three subscriptions: the solutions all three have so far
        n = min(len(v) for v in got.values())
        fixes = [rmw.deserialize(p, "sensor_msgs/msg/NavSatFix") for p in got["fix"][:n]]
        odoms = [rmw.deserialize(p, "nav_msgs/msg/Odometry") for p in got["odom"][:n]]
        imus = [rmw.deserialize(p, "sensor_msgs/msg/Imu") for p in got["imu"][:n]]
    assert n > 20_000
    assert [rmw.stamp_ns(o.header) for o in odoms] == [rmw.stamp_ns(f.header) for f in fixes]
    truth = ds.truth
    t_fix = np.array([unix_ns_to_gps_ns(rmw.stamp_ns(f.header)) for f in fixes])
    j = np.clip(np.searchsorted(truth.t_ns, t_fix), 0, len(truth.t_ns) - 1)
    assert np.all(truth.t_ns[j] == t_fix)  # stamps round-trip to the samples' GPS times
    llh = np.column_stack([np.radians([f.latitude for f in fixes]), np.radians([f.longitude for f in fixes]),
                           [f.altitude for f in fixes]])
    err = ned_errors(llh, truth.llh[j])
    h_rms = float(np.sqrt(np.mean(err[:, 0] ** 2 + err[:, 1] ** 2)))
    assert fixes[-1].position_covariance_type == 2 and fixes[-1].position_covariance[0] > 0
    from zennav.nav.rotation import quat_to_euler

    yaw = np.array([quat_to_euler(q_enu_flu_to_q_nb([o.pose.pose.orientation.w, o.pose.pose.orientation.x,
                                                     o.pose.pose.orientation.y, o.pose.pose.orientation.z]))[2]
                    for o in odoms])
    d_yaw = np.degrees(np.angle(np.exp(1j * (yaw - truth.euler[j, 2]))))
    speed_fwd = np.array([o.twist.twist.linear.x for o in odoms[-2000:]])
    v_truth = np.linalg.norm(truth.v_n[j[-2000:]], axis=1)
    assert imus[-1].angular_velocity_covariance[0] == -1.0 and imus[-1].orientation == odoms[-1].pose.pose.orientation
    print(f"\nROS bridge: {len(inputs)} ROS messages in ({n_imu} Imu, {len(inputs) - n_imu} NavSatFix) -> "
          f"{len(fixes)} NavSatFix/Odometry/Imu out; horizontal RMS {h_rms:.3f} m, yaw RMS "
          f"{np.sqrt(np.mean(d_yaw ** 2)):.3f} deg, forward speed error (last 2000) "
          f"{np.abs(speed_fwd - v_truth).max():.3f} m/s max")
    assert h_rms < 3.0 and np.sqrt(np.mean(d_yaw ** 2)) < 2.0 and np.abs(speed_fwd - v_truth).max() < 0.5


@pytest.mark.parametrize("imu_lag_s", [-1.0, 3.0, 10.0])
def test_the_bridge_hands_out_time_order_when_one_subscription_lags(imu_lag_s):
    """The Imu and NavSatFix subscriptions drain on threads of their own: a busy bridge may take the fixes
    seconds before the Imu samples of their time (imu_lag_s > 0) or after them. The stream it hands out is in
    time order either way (a fix ahead of the IMU chain by more than max_step would be refused by the ins as a
    time jump and cost it a stalled slot), and a fix is dropped only when it comes later than the latency."""
    from zennav import rmw
    from zennav.datasets.registry import load_dataset
    from zennav.nodes.ros_bridge import IMU_TYPE, RosInput
    from zennav.sim.scenarios import IMU_GRADES

    inputs = _ros_inputs(load_dataset("sim:car", duration_s=40.0))
    core = RosInput("ros:test", IMU_GRADES["mems"].noise(), [0.0, 0.0, 0.0], latency_s=2.0)
    arrival = sorted(inputs, key=lambda x: x[0] + (imu_lag_s * 1e9 if x[3] == IMU_TYPE else 0.0))
    out = []
    for _t, _o, _topic, ros_type, cdr in arrival:
        msg = rmw.deserialize(cdr, ros_type)
        out += core.on_imu(msg) if ros_type == IMU_TYPE else core.on_fix(msg)
    out += core.end()
    t = [m["t_ns"] for kind, m in out if kind in ("imu", "gnss")]
    assert np.all(np.diff(t) >= 0)
    assert [m["cseq"] for _k, m in out] == list(range(len(out)))
    t0 = out[0][1]["t_ns"]  # the stream starts at the first Imu after two fixes: all after it are handed out
    n_after = {kind: sum(1 for x in inputs if x[0] > t0 and (x[3] == IMU_TYPE) == (kind == "imu"))
               for kind in ("imu", "gnss")}
    assert out[0][0] == "stream" and core.n == n_after, (core.n, n_after, dict(core.counts))
    assert dict(core.counts) == {}
