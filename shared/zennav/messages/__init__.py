"""Every message zennav exchanges, by concern: ``keys`` (key grammar, QoS per stream), ``schema`` (the schema
registry), ``codec`` (msgpack, numpy and dataclass conversions), ``validate`` (the one validator of decoded
maps: types, shapes, finiteness, time order), ``sensor`` (sensor messages and the cseq ``SequenceMerger``),
``nav`` (attitude, solution, aid status, ins status), ``learn`` (the learning loop) and ``status`` (service
heartbeats). ``from zennav import messages as M`` gives every public name as ``M.x``.

No zenoh here (``zennav.bus`` is the only module that imports it): pure Python + msgpack, so the schemas can
be unit-tested, recorded and replayed without a network.

Wire format: every message is a msgpack map with a header and the schema's fields::

    {"schema": "imu", "v": 1,          # schema name and version (zennav.messages.schema is the registry)
     "t_ns": int,                       # sample time, integer ns of GPS time (ARCHITECTURE.md, opening lines)
     "src": str, "seq": int,            # publisher instance id and its per-key sequence number (drop detection)
     "pub_ns": int,                     # wall-clock publish time [ns since 1970] (latency measurement only)
     ...fields}
"""
from __future__ import annotations

from .codec import ValidationError, dataclass_to_map, decode, encode, floats, make, map_to_dataclass, pyval
from .keys import (
    ALIVE,
    CHUNK,
    ENCODING,
    HISTORY_QOS,
    ROOT,
    STREAM_BY_NAME,
    STREAMS,
    Keys,
    QoS,
    Stream,
    check_chunk,
    qos_of,
    qos_table,
    stream_of,
)
from .learn import (
    PARAMSET_FORMAT,
    array_map,
    correction_msg,
    learn_query_msg,
    learn_sample_msg,
    map_array,
    model_params_msg,
    params_checksum,
    paramset_of,
)
from .nav import (
    ALIGN_STATES,
    SolutionPacker,
    aid_report_msg,
    alignment_map,
    attitude_msg,
    check_nav_status,
    euler_list,
    nav_solution_batch_msg,
    nav_solution_msg,
    nav_solution_msg_of,
    nav_solution_msg_of_row,
    nav_status_msg,
    noise_map,
    solutions,
)
from .schema import (
    ANY,
    BOOL,
    FLOAT,
    FLOATS,
    HEADER,
    INT,
    INTS,
    MAP,
    OPT,
    SCHEMAS,
    SENSOR,
    STR,
    STRS,
    VEC,
    Schema,
    define,
)
from .sensor import (
    AID_STREAMS,
    SequenceMerger,
    aid_msg,
    aid_sample,
    check_dvl,
    check_imu_batch,
    depth_msg,
    depth_sample,
    dvl_msg,
    dvl_sample,
    gnss_fix,
    gnss_msg,
    imu_batch_msg,
    imu_msg,
    samples,
)
from .status import SERVICE_STATES, service_status_msg
from .validate import Validator, check_finite_deep, check_value, validate_map

__all__ = [
    "AID_STREAMS", "aid_msg", "aid_report_msg", "aid_sample",
    "ALIGN_STATES", "alignment_map", "ALIVE", "ANY", "array_map", "attitude_msg", "BOOL",
    "check_chunk", "check_dvl",
    "check_finite_deep", "check_imu_batch", "check_nav_status", "check_value", "CHUNK",
    "correction_msg", "dataclass_to_map", "decode", "define",
    "depth_msg", "depth_sample", "dvl_msg", "dvl_sample", "encode", "ENCODING", "euler_list", "FLOAT",
    "FLOATS", "floats", "gnss_fix", "gnss_msg", "HEADER", "HISTORY_QOS", "imu_batch_msg", "imu_msg", "INT", "INTS",
    "Keys",
    "learn_query_msg", "learn_sample_msg", "make", "MAP", "map_array", "map_to_dataclass", "model_params_msg",
    "nav_solution_batch_msg",
    "nav_solution_msg", "nav_solution_msg_of", "nav_solution_msg_of_row", "nav_status_msg", "noise_map", "OPT",
    "params_checksum",
    "PARAMSET_FORMAT", "paramset_of", "pyval", "QoS", "qos_of", "qos_table", "ROOT", "samples", "Schema",
    "SCHEMAS", "SENSOR", "SequenceMerger", "SERVICE_STATES", "SolutionPacker", "service_status_msg", "solutions",
    "STR", "Stream",
    "STREAM_BY_NAME", "stream_of", "STREAMS", "STRS", "validate_map", "ValidationError", "Validator", "VEC",
]
