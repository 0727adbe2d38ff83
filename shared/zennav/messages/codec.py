"""msgpack codec and the conversions between Python/numpy values and wire maps.

Float arrays travel as msgpack lists of float64 (Python floats; numpy arrays go through ``tolist()``), so
every value round-trips bit for bit. Integers (times, counts) are msgpack integers.
"""
from __future__ import annotations

import threading
from dataclasses import MISSING, fields, is_dataclass
from typing import Any

import msgpack
import numpy as np

from .schema import SCHEMAS


class ValidationError(ValueError):
    pass


_packers = threading.local()  # one msgpack Packer per thread (a Packer is not thread-safe)


def encode(msg: Any) -> bytes:
    """msgpack map -> bytes (float64 kept as float64, strings as str, bytes as bin). The thread's Packer is reused
    (it keeps a buffer the size of the largest message it packed): msgpack.packb builds one, with a 256 KiB buffer,
    per call, a third of the cost of encoding a solution message."""
    try:
        packer = _packers.packer
    except AttributeError:
        packer = _packers.packer = msgpack.Packer(use_bin_type=True)
    return packer.pack(msg)


def decode(payload: bytes) -> Any:
    return msgpack.unpackb(payload, raw=False, strict_map_key=False)


def make(schema: str, t_ns: int, **fields) -> dict:
    """A message map with its schema/version and sample time; the bus adds src, seq and pub_ns."""
    s = SCHEMAS[schema]
    msg = {"schema": schema, "v": s.version, "t_ns": int(t_ns)}
    msg.update(fields)
    return msg


def floats(a) -> list:
    """Array-like -> list of Python floats (float64, exact)."""
    if type(a) is np.ndarray:
        return (a if a.dtype == np.float64 else a.astype(np.float64)).ravel().tolist()
    if type(a) in (list, tuple):
        return [float(x) for x in a]
    return np.asarray(a, dtype=np.float64).ravel().tolist()


def pyval(v):
    """A value with numpy scalars/arrays and dataclasses inside -> plain msgpack-able Python values."""
    if isinstance(v, np.ndarray):
        return [pyval(x) for x in v.tolist()] if v.dtype.kind in "iub" else v.astype(np.float64).tolist()
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, (np.bool_,)):
        return bool(v)
    if is_dataclass(v):
        return dataclass_to_map(v)
    if isinstance(v, (list, tuple)):
        return [pyval(x) for x in v]
    if isinstance(v, dict):
        return {str(k): pyval(x) for k, x in v.items()}
    return v


def dataclass_to_map(obj) -> dict:
    """A (nested) dataclass -> msgpack-able map (arrays -> lists of float64)."""
    return {f.name: pyval(getattr(obj, f.name)) for f in fields(obj)}


def map_to_dataclass(cls, m: dict):
    """Inverse of dataclass_to_map for NavConfig / InitialState / ImuNoise: lists -> float64 arrays,
    nested maps -> the field's dataclass; unknown keys are ignored."""
    kw = {}
    defaults = cls() if _has_all_defaults(cls) else None
    for f in fields(cls):
        if f.name not in m:
            continue
        v = m[f.name]
        cur = getattr(defaults, f.name) if defaults is not None else None
        if isinstance(v, dict) and is_dataclass(cur):
            v = map_to_dataclass(type(cur), v)
        elif isinstance(v, list):
            v = np.asarray(v, dtype=np.float64)
        kw[f.name] = v
    return cls(**kw)


def _has_all_defaults(cls) -> bool:
    return all(f.default is not MISSING or f.default_factory is not MISSING for f in fields(cls))
