"""Foxglove views of zennav messages in an MCAP recording: channels Foxglove shows without configuration.

For a navigation solution (nav_solution): ``<key>/location`` foxglove.LocationFix (latitude/longitude in degrees,
ellipsoidal height, position covariance ENU [m^2], diagonal known), ``<key>/pose`` foxglove.PoseInFrame (frame
"enu": ENU metres from the recording's first solution, orientation of the FLU body in ENU) and ``<key>/tf``
foxglove.FrameTransform (enu -> base_link, the same). For a GNSS fix (gnss): ``<key>/location``. Timestamps are
the sample time as Unix time (zennav.gpstime), the log time Foxglove's timeline uses. Frames are converted once
(zennav.rosframes). The JSON schemas follow Foxglove's published message schemas.
"""
from __future__ import annotations

import math

import numpy as np

from .gpstime import gps_ns_to_unix_ns
from .nav import earth
from .rosframes import cov_ned_to_enu, q_nb_to_q_enu_flu

_TIME = {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                          "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_NUM = {"type": "number"}

SCHEMAS = {
    "foxglove.LocationFix": {
        "title": "foxglove.LocationFix", "description": "A navigation satellite fix for any Global Navigation "
        "Satellite System", "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"}, "latitude": _NUM, "longitude": _NUM,
                       "altitude": _NUM, "position_covariance": {"type": "array", "items": _NUM, "minItems": 9,
                                                                 "maxItems": 9},
                       "position_covariance_type": {"type": "integer", "enum": [0, 1, 2, 3]}}},
    "foxglove.PoseInFrame": {
        "title": "foxglove.PoseInFrame", "description": "A timestamped pose for an object or reference frame in 3D "
        "space", "type": "object",
        "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                       "pose": {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}}},
    "foxglove.FrameTransform": {
        "title": "foxglove.FrameTransform", "description": "A transform between two reference frames in 3D space",
        "type": "object",
        "properties": {"timestamp": _TIME, "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
                       "translation": _VEC3, "rotation": _QUAT}},
}
COV_DIAGONAL_KNOWN = 2
ENU_FRAME, BODY_FRAME = "enu", "base_link"


def stamp(unix_ns: int) -> dict:
    return {"sec": unix_ns // 1_000_000_000, "nsec": unix_ns % 1_000_000_000}


def location_fix(t_ns: int, llh, std_ned, frame_id: str) -> dict:
    """foxglove.LocationFix of a position (llh [rad, rad, m], std NED [m]) at GPS time t_ns."""
    cov = cov_ned_to_enu(np.diag(np.square(np.asarray(std_ned, dtype=float))))
    return {"timestamp": stamp(gps_ns_to_unix_ns(t_ns)), "frame_id": frame_id, "latitude": math.degrees(llh[0]),
            "longitude": math.degrees(llh[1]), "altitude": float(llh[2]),
            "position_covariance": [float(x) for x in cov.ravel()], "position_covariance_type": COV_DIAGONAL_KNOWN}


class FoxgloveViews:
    """derived(key, msg) -> [(topic, schema name, message)] for one recording (its ENU origin: the first solution)."""

    def __init__(self) -> None:
        self.origin: np.ndarray | None = None

    def derived(self, key: str, msg: dict) -> list[tuple[str, str, dict]]:
        schema = msg["schema"]
        if schema == "gnss":
            return [(f"{key}/location", "foxglove.LocationFix", location_fix(msg["t_ns"], msg["llh"], msg["std_ned"],
                                                                              "gnss_antenna"))]
        if schema != "nav_solution":
            return []
        llh = np.asarray(msg["llh"], dtype=float)
        if self.origin is None:
            self.origin = llh
        o = self.origin
        dn, de, dd = earth.dllh_to_ned(llh - o, o[0], o[2])
        q = q_nb_to_q_enu_flu(msg["q_nb"])
        ts = stamp(gps_ns_to_unix_ns(msg["t_ns"]))
        pos = {"x": float(de), "y": float(dn), "z": float(-dd)}
        rot = {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])}
        return [(f"{key}/location", "foxglove.LocationFix", location_fix(msg["t_ns"], llh, msg["std_pos_ned"],
                                                                          BODY_FRAME)),
                (f"{key}/pose", "foxglove.PoseInFrame", {"timestamp": ts, "frame_id": ENU_FRAME,
                                                          "pose": {"position": pos, "orientation": rot}}),
                (f"{key}/tf", "foxglove.FrameTransform", {"timestamp": ts, "parent_frame_id": ENU_FRAME,
                                                          "child_frame_id": BODY_FRAME, "translation": pos,
                                                          "rotation": rot})]
