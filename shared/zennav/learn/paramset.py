"""Versioned parameter sets of the learned models (ARCHITECTURE.md section 3): build, encode, checksum, validate.
numpy + msgpack only.

Message (msgpack-friendly dict):
  schema "zennav.paramset/2", kind "anfis" | "elman", name str, version int >= 0, created_t_ns int,
  norm {x_mean, x_std, x_min, x_max, y_mean, y_std} (x_min/x_max: the training range, new in /2),
  arrays: anfis {a, b, c, rules, consequents} (see anfis_numpy), elman {w1, w2, b1, w3, b3, context} (see elman;
  its context gain is metrics["context_gain"]),
  metrics {str: int | float | str | list of numbers}, checksum "sha256:<hex>".
Each array is {"dtype": "<f8" | "<i8", "shape": [...], "data": bytes (C order)}.
The checksum is the SHA-256 of the msgpack encoding of every other field with map keys sorted at every level.
A signature (zennav.learn.signing: Ed25519 over the checksum) travels beside the set, not in it (the wire
message's signature field); validate() checks it when given a verifier.
validate() returns a read-only ParamSet or raises ParamSetRejected whose .reason is one of REASONS.
"""
from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np

from . import anfis_numpy, elman
from .anfis_numpy import NORM_NAMES

if TYPE_CHECKING:
    from .signing import Verifier

SCHEMA = "zennav.paramset/2"
KINDS = {"anfis": anfis_numpy.ARRAY_NAMES, "elman": elman.ARRAY_NAMES}  # kind -> its array names
INT_ARRAYS = ("rules",)
REASONS = ("decode", "schema", "checksum", "unsigned", "bad_signature", "shape", "non_finite", "invalid_value",
           "stale_version", "version_ahead")
_FIELDS = {"schema": str, "kind": str, "name": str, "version": int, "created_t_ns": int, "norm": dict,
           "arrays": dict, "metrics": dict, "checksum": str}
_DTYPES = {"<f8": np.float64, "<i8": np.int64}


class ParamSetRejected(ValueError):
    """A parameter set failed validation; reason is one of REASONS, detail says what was wrong."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason, self.detail = reason, detail


@dataclass(frozen=True)
class ParamSet:
    """A validated parameter set; arrays and norm are read-only numpy arrays."""

    kind: str
    name: str
    version: int
    created_t_ns: int
    arrays: Mapping[str, np.ndarray]
    norm: Mapping[str, np.ndarray]
    metrics: Mapping[str, Any]
    checksum: str

    @property
    def n_in(self) -> int:
        return self.norm["x_mean"].shape[0]

    @property
    def n_out(self) -> int:
        return self.norm["y_mean"].shape[0]


def _encode_array(a: np.ndarray) -> dict:
    a = np.asarray(a)
    dt = "<i8" if np.issubdtype(a.dtype, np.integer) else "<f8"
    return {"dtype": dt, "shape": list(a.shape), "data": np.ascontiguousarray(a, dtype=dt).tobytes()}


def _plain(v):
    """numpy scalars/arrays and tuples in metrics -> Python numbers and lists."""
    if isinstance(v, (np.ndarray, list, tuple)):
        return [_plain(e) for e in v]
    return v.item() if isinstance(v, np.generic) else v


def _sorted(obj):
    if isinstance(obj, dict):
        return {k: _sorted(obj[k]) for k in sorted(obj)}
    if isinstance(obj, (list, tuple)):
        return [_sorted(v) for v in obj]
    return obj


def checksum(msg: Mapping) -> str:
    """"sha256:<hex>" over the canonical encoding of msg without its checksum field."""
    body = {k: v for k, v in msg.items() if k != "checksum"}
    return "sha256:" + hashlib.sha256(msgpack.packb(_sorted(body), use_bin_type=True)).hexdigest()


def build(name: str, version: int, arrays: Mapping[str, np.ndarray], norm: Mapping[str, np.ndarray],
          metrics: Mapping[str, Any] | None = None, *, kind: str = "anfis", created_t_ns: int | None = None) -> dict:
    """Parameter-set message from a model's arrays (KINDS[kind]) and normalisation, checksum included (not
    validated)."""
    msg = {
        "schema": SCHEMA,
        "kind": kind,
        "name": name,
        "version": int(version),
        "created_t_ns": time.time_ns() if created_t_ns is None else int(created_t_ns),
        "norm": {k: _encode_array(norm[k]) for k in NORM_NAMES},
        "arrays": {k: _encode_array(arrays[k]) for k in KINDS[kind]},
        "metrics": {str(k): _plain(v) for k, v in (metrics or {}).items()},
    }
    msg["checksum"] = checksum(msg)
    return msg


def encode(msg: Mapping) -> bytes:
    """msgpack bytes of a message (for the wire)."""
    return msgpack.packb(dict(msg), use_bin_type=True)


def decode(payload: bytes) -> dict:
    """Message from msgpack bytes; ParamSetRejected("decode") when they are not a msgpack map."""
    try:
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception as e:  # msgpack raises several unrelated types for malformed input
        raise ParamSetRejected("decode", f"not msgpack: {type(e).__name__}: {e}") from None
    if not isinstance(msg, dict):
        raise ParamSetRejected("decode", f"top level is {type(msg).__name__}, not a map")
    return msg


def _check_schema(msg: Mapping) -> None:
    def bad(detail):
        raise ParamSetRejected("schema", detail)

    if set(msg) != set(_FIELDS):
        bad(f"fields {sorted(map(str, msg))}, expected {sorted(_FIELDS)}")
    for key, typ in _FIELDS.items():
        if not isinstance(msg[key], typ) or (typ is int and isinstance(msg[key], bool)):
            bad(f"field {key!r} is {type(msg[key]).__name__}, not {typ.__name__}")
    if msg["schema"] != SCHEMA or msg["kind"] not in KINDS:
        bad(f"unsupported schema/kind {msg['schema']!r}/{msg['kind']!r}")
    if msg["version"] < 0:
        bad("negative version")
    for group, names in (("norm", NORM_NAMES), ("arrays", KINDS[msg["kind"]])):
        if set(msg[group]) != set(names):
            bad(f"{group} has {sorted(map(str, msg[group]))}, expected {sorted(names)}")
        for k in names:
            enc = msg[group][k]
            if not (isinstance(enc, dict) and set(enc) == {"dtype", "shape", "data"}):
                bad(f"{group}.{k} is not a {{dtype, shape, data}} map")
            dtype = "<i8" if k in INT_ARRAYS else "<f8"
            if enc["dtype"] != dtype or not isinstance(enc["data"], bytes):
                bad(f"{group}.{k}: dtype {enc['dtype']!r} (expected {dtype!r}) or data not bytes")
            shape = enc["shape"]
            if not (isinstance(shape, list) and all(isinstance(s, int) and s >= 0 for s in shape)):
                bad(f"{group}.{k}: bad shape {shape!r}")
            if len(enc["data"]) != 8 * math.prod(shape):
                bad(f"{group}.{k}: {len(enc['data'])} bytes for shape {shape}")
    for k, v in msg["metrics"].items():
        ok = isinstance(v, (int, float, str)) or (
            isinstance(v, list) and all(isinstance(e, (int, float)) for e in v))
        if not isinstance(k, str) or not ok:
            bad(f"metric {k!r} has an unsupported value type")


def _decode_array(enc: Mapping) -> np.ndarray:
    a = np.frombuffer(enc["data"], dtype=_DTYPES[enc["dtype"]]).reshape(enc["shape"]).copy()
    a.setflags(write=False)
    return a


def _anfis_dims(arrays) -> tuple[int, int]:
    a, b, c, rules, cons = (arrays[k] for k in anfis_numpy.ARRAY_NAMES)
    if a.ndim != 2 or b.shape != a.shape or c.shape != a.shape:
        raise ParamSetRejected("shape", f"a, b, c {a.shape}, {b.shape}, {c.shape} differ or are not 2-D")
    ni, nm = a.shape
    if rules.ndim != 2 or rules.shape[1] != ni or rules.shape[0] < 1:
        raise ParamSetRejected("shape", f"rules {rules.shape} is not (n_rules, {ni})")
    if cons.ndim != 3 or cons.shape[:2] != (rules.shape[0], ni + 1):
        raise ParamSetRejected("shape", f"consequents {cons.shape} is not ({rules.shape[0]}, {ni + 1}, n_out)")
    if np.any(rules < 0) or np.any(rules >= nm):
        raise ParamSetRejected("invalid_value", f"rule indices outside [0, {nm})")
    return ni, cons.shape[2]


def _elman_dims(arrays) -> tuple[int, int]:
    w1 = arrays["w1"]
    if w1.ndim != 2:
        raise ParamSetRejected("shape", f"w1 {w1.shape} is not (n_hidden, n_in)")
    nh, ni = w1.shape
    no = arrays["w3"].shape[0] if arrays["w3"].ndim == 2 else -1
    for k, want in (("w2", (nh, nh)), ("b1", (nh,)), ("w3", (no, nh)), ("b3", (no,)), ("context", (nh,))):
        if arrays[k].shape != want or no < 1:
            raise ParamSetRejected("shape", f"{k} {arrays[k].shape} is not {want} (n_hidden {nh}, n_in {ni})")
    return ni, no


def _check_shapes(kind, arrays, norm, n_in, n_out) -> None:
    ni, no = (_anfis_dims if kind == "anfis" else _elman_dims)(arrays)
    for k, want in (("x_mean", ni), ("x_std", ni), ("x_min", ni), ("x_max", ni), ("y_mean", no), ("y_std", no)):
        if norm[k].shape != (want,):
            raise ParamSetRejected("shape", f"norm.{k} {norm[k].shape} is not ({want},)")
    for dim, got, want in (("n_in", ni, n_in), ("n_out", no, n_out)):
        if want is not None and got != want:
            raise ParamSetRejected("shape", f"{dim} is {got}, the model expects {want}")


def validate(msg: Mapping, *, live_version: int | None = None, n_in: int | None = None,
             n_out: int | None = None, name: str | None = None, verifier: Verifier | None = None,
             signature: str | None = None, max_version_step: int | None = None) -> ParamSet:
    """Check schema, checksum, the signature (with a verifier: unsigned, bad_signature), shapes (against
    n_in/n_out when given), finiteness, value ranges and that the version is newer than live_version and at most
    max_version_step above it, in that order; the first failure raises ParamSetRejected."""
    _check_schema(msg)
    if name is not None and msg["name"] != name:
        raise ParamSetRejected("schema", f"name {msg['name']!r} is not {name!r}")
    expected = checksum(msg)
    if msg["checksum"] != expected:
        raise ParamSetRejected("checksum", f"{msg['checksum']!r} != computed {expected!r}")
    if verifier is not None:
        if not signature:
            raise ParamSetRejected("unsigned", f"no signature; sets must be signed by key {verifier.key_id}")
        why = verifier.check(expected, str(signature))
        if why:
            raise ParamSetRejected("bad_signature", why)
    kind = msg["kind"]
    arrays = {k: _decode_array(msg["arrays"][k]) for k in KINDS[kind]}
    norm = {k: _decode_array(msg["norm"][k]) for k in NORM_NAMES}
    _check_shapes(kind, arrays, norm, n_in, n_out)
    for group, d in (("arrays", arrays), ("norm", norm)):
        for k, v in d.items():
            if not np.all(np.isfinite(v)):
                raise ParamSetRejected("non_finite", f"{group}.{k} has {int(np.sum(~np.isfinite(v)))} NaN/inf")
    positive = (("arrays", arrays, "a"), ("arrays", arrays, "b")) if kind == "anfis" else ()
    for group, d, k in positive + (("norm", norm, "x_std"), ("norm", norm, "y_std")):
        if np.any(d[k] <= 0.0):
            raise ParamSetRejected("invalid_value", f"{group}.{k} must be > 0")
    if np.any(norm["x_min"] > norm["x_max"]):
        raise ParamSetRejected("invalid_value", "norm.x_min must be <= norm.x_max")
    if live_version is not None and msg["version"] <= live_version:
        raise ParamSetRejected("stale_version", f"version {msg['version']} is not above live {live_version}")
    if live_version is not None and max_version_step is not None and msg["version"] > live_version + max_version_step:
        raise ParamSetRejected("version_ahead", f"version {msg['version']} is more than {max_version_step} above "
                                                f"live {live_version}")
    if kind == "elman" and not (isinstance(msg["metrics"].get("context_gain"), float)
                                and 0.0 <= msg["metrics"]["context_gain"] < 1.0):
        raise ParamSetRejected("invalid_value", "metrics.context_gain must be a float in [0, 1)")
    return ParamSet(kind, msg["name"], msg["version"], msg["created_t_ns"], MappingProxyType(arrays),
                    MappingProxyType(norm), MappingProxyType(dict(msg["metrics"])), msg["checksum"])
