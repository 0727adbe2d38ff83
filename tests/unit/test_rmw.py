"""rmw_zenoh conventions (zennav.rmw) and the bridge's frame conversions, against rosbags and zenoh-ext."""
from __future__ import annotations

import math

import numpy as np

from zennav import rmw
from zennav.nav.rotation import euler_to_quat, quat_to_dcm


def test_key_attachment_and_cdr():
    import zenoh.ext as ze

    assert rmw.topic_key(0, "/imu/data/", "sensor_msgs/msg/Imu") == \
        "0/imu/data/sensor_msgs::msg::dds_::Imu_/" + rmw.typestore().hash_rihs01("sensor_msgs/msg/Imu")
    assert rmw.topic_key(3, "/a", "nav_msgs/msg/Odometry", any_hash=True) == "3/a/nav_msgs::msg::dds_::Odometry_/*"
    gid = rmw.gid_of("x")
    att = rmw.attachment(7, 123456789, gid)
    ref = ze.z_serialize((ze.Int64(7), ze.Int64(123456789), tuple(ze.UInt8(b) for b in gid))).to_bytes()
    assert att == ref and rmw.parse_attachment(att) == (7, 123456789, gid)
    T = rmw.typestore().types
    h = rmw.header(1_700_000_000_123_456_789, "base_link")
    data = rmw.serialize(T["sensor_msgs/msg/NavSatFix"](
        header=h, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=48.1, longitude=11.5,
        altitude=500.0, position_covariance=np.arange(9.0), position_covariance_type=2), "sensor_msgs/msg/NavSatFix")
    assert data[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation
    back = rmw.deserialize(data, "sensor_msgs/msg/NavSatFix")
    assert rmw.stamp_ns(back.header) == 1_700_000_000_123_456_789 and back.latitude == 48.1


def test_rep103_frames():
    from zennav.rosframes import frd_to_flu, ned_to_enu, q_enu_flu_to_q_nb, q_nb_to_q_enu_flu

    q_nb = euler_to_quat([0.1, -0.2, math.radians(30.0)])  # heading 30 deg east of north
    q = q_nb_to_q_enu_flu(q_nb)
    x_flu_in_enu = quat_to_dcm(q) @ [1.0, 0.0, 0.0]
    assert np.allclose(x_flu_in_enu, ned_to_enu(quat_to_dcm(q_nb) @ [1.0, 0.0, 0.0]))  # the same forward axis
    yaw_enu = math.atan2(x_flu_in_enu[1], x_flu_in_enu[0])
    assert abs(math.degrees(yaw_enu) - 60.0) < 1.0  # ENU yaw = 90 deg - NED heading (pitch tilts it a little)
    assert np.allclose(q_enu_flu_to_q_nb(q) * np.sign(q_enu_flu_to_q_nb(q)[0]), q_nb * np.sign(q_nb[0]))
    assert np.allclose(frd_to_flu([1.0, 2.0, 3.0]), [1.0, -2.0, -3.0])
