"""ROS 2 over Zenoh as rmw_zenoh carries it: key expressions, CDR payloads (rosbags) and the sample attachment.

A topic's key expression is ``<domain id>/<topic name without leading/trailing '/'>/<DDS type name>/<type hash>``,
e.g. ``0/imu/data/sensor_msgs::msg::dds_::Imu_/RIHS01_7d9a...``; the type hash is the ROS 2 type description hash
(RIHS01, computed by rosbags' type store). A subscription here uses ``*`` for the hash, so any distribution's
publisher of the same type and topic matches. Payloads are CDR with the 4-byte encapsulation header (rosbags'
serialize_cdr / deserialize_cdr, little endian). Every sample carries an attachment: the publisher's sequence
number (int64), its source timestamp [ns] (int64) and its 16-byte GID, serialized as zenoh-ext serializes a
(int64, int64, uint8[16]) tuple: 32 bytes, little endian, no length prefixes.
"""
from __future__ import annotations

import functools
import hashlib
import struct

ATTACHMENT = struct.Struct("<qq16s")


@functools.lru_cache(maxsize=1)
def typestore():
    """The ROS 2 message definitions (Jazzy, the first distribution with rmw_zenoh)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def dds_type(ros_type: str) -> str:
    """'sensor_msgs/msg/Imu' -> 'sensor_msgs::msg::dds_::Imu_' (the type chunk of the key expression)."""
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


@functools.cache
def type_hash(ros_type: str) -> str:
    """The RIHS01 type description hash of a ROS type."""
    return typestore().hash_rihs01(ros_type)


def topic_key(domain: int, topic: str, ros_type: str, any_hash: bool = False) -> str:
    """The key expression of a ROS topic (any_hash: '*' for the hash chunk, for subscribing)."""
    return f"{int(domain)}/{topic.strip('/')}/{dds_type(ros_type)}/{'*' if any_hash else type_hash(ros_type)}"


def gid_of(name: str) -> bytes:
    """A stable 16-byte publisher GID derived from a name."""
    return hashlib.sha256(name.encode()).digest()[:16]


def attachment(seq: int, source_ns: int, gid: bytes) -> bytes:
    """The attachment of one sample (see the module docstring)."""
    return ATTACHMENT.pack(int(seq), int(source_ns), gid)


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp [ns], gid); ValueError when it is not one."""
    if len(data) != ATTACHMENT.size:
        raise ValueError(f"rmw_zenoh attachment of {len(data)} bytes, expected {ATTACHMENT.size}")
    return ATTACHMENT.unpack(data)


def serialize(msg, ros_type: str) -> bytes:
    return bytes(typestore().serialize_cdr(msg, ros_type))


def deserialize(data: bytes, ros_type: str):
    return typestore().deserialize_cdr(data, ros_type)


def stamp_ns(header) -> int:
    """A std_msgs/Header stamp -> Unix nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def header(unix_ns: int, frame_id: str):
    ts = typestore().types
    return ts["std_msgs/msg/Header"](stamp=ts["builtin_interfaces/msg/Time"](
        sec=int(unix_ns // 1_000_000_000), nanosec=int(unix_ns % 1_000_000_000)), frame_id=frame_id)
