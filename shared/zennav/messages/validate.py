"""The one validator: every decoded message is checked here before it reaches a core.

``Validator.check(key, payload)`` decodes and checks: msgpack map, header, schema known and allowed on this
key, supported version, field types, array shapes, finite numbers, the schema's own consistency check
(``Schema.check``), and monotonic ``t_ns`` per (key, src) (strictly or non-decreasing per the stream's time
policy; the sensor streams' time order is their consumers' cseq merge's, zennav.stream). It returns
``(msg, "")`` or ``(None, reason)``; rejections are counted per reason code (the part of the reason before
``:``) in ``Validator.rejected`` and never raise. Unknown extra fields are tolerated (forward compatible
within one version) but never used.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from typing import Any

from .codec import decode
from .keys import stream_of
from .schema import ANY, BOOL, FLOAT, INT, INTS, MAP, SCHEMAS, STR, STRS, Schema

_FLOAT_ONLY = {float}


def check_value(spec, v, name: str) -> str:
    """'' when v fits spec, else 'code: detail'. Float lists are normalised in place by the caller."""
    if isinstance(spec, tuple):
        kind = spec[0]
        if kind == "opt":
            return "" if v is None else check_value(spec[1], v, name)
        if kind in ("ints", "strs"):
            want = int if spec == INTS else str
            if not isinstance(v, list):
                return f"bad_type: {name} is {type(v).__name__}, want list"
            bad = next((i for i, x in enumerate(v) if type(x) is not want), None)
            return "" if bad is None else f"bad_type: {name}[{bad}] is {type(v[bad]).__name__}, want {want.__name__}"
        if kind in ("vec", "floats"):
            if not isinstance(v, list):
                return f"bad_type: {name} is {type(v).__name__}, want list"
            if kind == "vec" and len(v) != spec[1]:
                return f"bad_shape: {name} has {len(v)} elements, want {spec[1]}"
            # the common case at C speed: floats only, and a finite sum means every one is finite (an inf or a NaN
            # makes it inf or NaN; finite values that overflow it take the loop below)
            if set(map(type, v)) <= _FLOAT_ONLY and math.isfinite(sum(v)):
                return ""
            for i, x in enumerate(v):
                tx = type(x)
                if tx is float:
                    if not math.isfinite(x):
                        return f"not_finite: {name}[{i}]"
                elif tx is not int:
                    return f"bad_type: {name}[{i}] is {tx.__name__}"
            return ""
        raise AssertionError(spec)
    t = type(v)
    if spec == INT:
        return "" if t is int else f"bad_type: {name} is {t.__name__}, want int"
    if spec == FLOAT:
        if t is float:
            return "" if math.isfinite(v) else f"not_finite: {name}"
        return "" if t is int else f"bad_type: {name} is {t.__name__}, want float"
    if spec == STR:
        return "" if t is str else f"bad_type: {name} is {t.__name__}, want str"
    if spec == BOOL:
        return "" if t is bool else f"bad_type: {name} is {t.__name__}, want bool"
    if spec == MAP:
        if t is not dict:
            return f"bad_type: {name} is {t.__name__}, want map"
        return check_finite_deep(v, name)
    if spec == ANY:
        return check_finite_deep(v, name)
    raise AssertionError(spec)


def check_finite_deep(v, name: str, depth: int = 0) -> str:
    """'' when every float inside a nested map/list is finite (depth <= 16), else 'code: detail'."""
    if depth > 16:
        return f"bad_shape: {name} nested too deep"
    t = type(v)
    if t is float:
        return "" if math.isfinite(v) else f"not_finite: {name}"
    if t is dict:
        for k, x in v.items():
            r = check_finite_deep(x, f"{name}.{k}", depth + 1)
            if r:
                return r
    elif t is list:
        for i, x in enumerate(v):
            if type(x) is float:
                if not math.isfinite(x):
                    return f"not_finite: {name}[{i}]"
            elif type(x) in (dict, list):
                r = check_finite_deep(x, f"{name}[{i}]", depth + 1)
                if r:
                    return r
    return ""


def _normalise(schema: Schema, msg: dict) -> None:
    """ints inside float fields -> float (so consumers see float64 throughout)."""
    for name, spec in schema.fields.items():
        if isinstance(spec, tuple):
            inner = spec[1] if spec[0] == "opt" else spec
            v = msg.get(name)
            if v is None:
                continue
            if isinstance(inner, tuple) and inner[0] in ("vec", "floats"):
                if int in set(map(type, v)):
                    msg[name] = [float(x) for x in v]
            elif inner == FLOAT and type(v) is int:
                msg[name] = float(v)
        elif spec == FLOAT and type(msg.get(name)) is int:
            msg[name] = float(msg[name])


def validate_map(msg: Any, key: str | None = None) -> str:
    """Static checks of a decoded message (no time state): '' or 'code: detail'."""
    if not isinstance(msg, dict):
        return f"not_a_map: {type(msg).__name__}"
    name = msg.get("schema")
    if not isinstance(name, str):
        return "missing_field: schema"
    schema = SCHEMAS.get(name)
    if schema is None:
        return f"unknown_schema: {name[:40]!r}"
    if key is not None:
        stream = stream_of(key)
        if stream is None:
            return f"unknown_key: {key}"
        if name not in stream.schemas:
            return f"wrong_schema: {name} on {stream.name}"
    v = msg.get("v")
    if v != schema.version or type(v) is not int:
        return f"unsupported_version: {name} v{v!r}, want v{schema.version}"
    fast = _FAST.get(name)
    if fast is None:
        fast = _FAST[name] = _compile_fast(schema)
    if fast(msg):  # straight-line check of every field; the loop below explains failures
        return schema.check(msg) if schema.check is not None else ""
    needs_norm = False
    isfinite = math.isfinite
    for fname, spec, code, n, optional in _plan(schema):
        val = msg.get(fname, _MISSING)
        if val is _MISSING or (val is None and optional):
            if optional:
                continue
            return f"missing_field: {name}.{fname}"
        if code == 1:  # int (bool is not an int here)
            if type(val) is not int:
                return f"bad_type: {fname} is {type(val).__name__}, want int"
            continue
        if code == 2 and type(val) is list and (n == 0 or len(val) == n) \
                and all(type(x) is float for x in val) and all(map(isfinite, val)):
            continue  # fast path: a float list of the right length, all finite
        if code == 3 and type(val) is str:
            continue
        r = check_value(spec, val, fname)
        if r:
            return r
        needs_norm = needs_norm or code in (2, 4)
    if schema.check is not None:
        r = schema.check(msg)
        if r:
            return r
    if needs_norm:
        _normalise(schema, msg)
    return ""


_MISSING = object()
_PLANS: dict[str, list] = {}
_FAST: dict[str, Callable[[dict], bool]] = {}


def _compile_fast(schema: Schema) -> Callable[[dict], bool]:
    """A generated function that returns True when every field of ``schema`` is present with the exact type
    (floats as Python floats, finite) -- the common case, checked without loops or dispatch. False means
    "use the generic checker", which finds the reason (or accepts and normalises ints in float fields)."""
    lines = ["def fast(msg):", "    g = msg.get"]
    for i, (fname, spec) in enumerate(schema.fields.items()):
        optional = isinstance(spec, tuple) and spec[0] == "opt"
        inner = spec[1] if optional else spec
        v = f"v{i}"
        lines.append(f"    {v} = g({fname!r}, MISSING)")
        if inner == INT:
            cond = f"type({v}) is int"
        elif inner == FLOAT:
            cond = f"type({v}) is float and isfinite({v})"
        elif inner == STR:
            cond = f"type({v}) is str"
        elif inner == BOOL:
            cond = f"type({v}) is bool"
        elif isinstance(inner, tuple) and inner[0] == "vec" and inner[1] <= 8:
            n = inner[1]
            elems = " and ".join(f"type({v}[{j}]) is float and isfinite({v}[{j}])" for j in range(n))
            cond = f"type({v}) is list and len({v}) == {n}" + (f" and {elems}" if n else "")
        elif inner == INTS:
            cond = f"type({v}) is list and all(type(x) is int for x in {v})"
        elif inner == STRS:
            cond = f"type({v}) is list and all(type(x) is str for x in {v})"
        elif isinstance(inner, tuple) and inner[0] in ("vec", "floats"):
            ln = f" and len({v}) == {inner[1]}" if inner[0] == "vec" else ""
            cond = f"type({v}) is list{ln} and all(type(x) is float for x in {v}) and all(map(isfinite, {v}))"
        elif inner == MAP:
            cond = f"type({v}) is dict and not deep({v}, '')"
        else:
            cond = f"{v} is not MISSING and not deep({v}, '')"
        if optional:
            cond = f"{v} is MISSING or {v} is None or ({cond})"
        lines.append(f"    if not ({cond}): return False")
    lines.append("    return True")
    ns: dict[str, Any] = {"MISSING": _MISSING, "isfinite": math.isfinite, "deep": check_finite_deep}
    exec("\n".join(lines), ns)  # noqa: S102 (source built from the registry's own schema table)
    return ns["fast"]


def _plan(schema: Schema) -> list:
    """Per-field check plan: (name, spec, code, n, optional); code 1 int, 2 float list, 3 str, 4 float, 0 other."""
    plan = _PLANS.get(schema.name)
    if plan is None:
        plan = []
        for fname, spec in schema.fields.items():
            optional = isinstance(spec, tuple) and spec[0] == "opt"
            inner = spec[1] if optional else spec
            if inner == INT:
                code, n = 1, 0
            elif isinstance(inner, tuple) and inner[0] in ("vec", "floats"):
                code, n = 2, (inner[1] if inner[0] == "vec" else 0)
            elif inner == STR:
                code, n = 3, 0
            elif inner == FLOAT:
                code, n = 4, 0
            else:
                code, n = 0, 0
            plan.append((fname, spec, code, n, optional))
        _PLANS[schema.name] = plan
    return plan


class Validator:
    """Decodes and validates messages of one subscriber; keeps the last t_ns per (key, src) for the
    monotonic-time check and counts rejections per reason code. Not thread-safe (one per consumer thread)."""

    def __init__(self) -> None:
        self.last_t: dict[tuple[str, str], int] = {}
        self.rejected: Counter[str] = Counter()
        self.rejected_by_key: Counter[tuple[str, str]] = Counter()
        self.accepted = 0

    def check(self, key: str, payload: bytes | bytearray | memoryview) -> tuple[dict | None, str]:
        try:
            msg = decode(bytes(payload))
        except Exception as e:  # random bytes: msgpack raises many types
            return self._reject(key, f"decode_error: {type(e).__name__}")
        r = validate_map(msg, key)
        if r:
            return self._reject(key, r)
        stream = stream_of(key)
        assert stream is not None  # validate_map rejected keys outside the grammar
        if stream.time in ("strict", "nondecreasing"):
            sk = (key, msg["src"])
            last = self.last_t.get(sk)
            t = msg["t_ns"]
            first = msg["t_ns_list"][0] if msg["schema"] == "imu_batch" else t
            if last is not None and (first < last or (stream.time == "strict" and first == last)):
                return self._reject(key, f"time_backwards: t_ns {first} after {last} on {key}")
            self.last_t[sk] = t
        self.accepted += 1
        return msg, ""

    def _reject(self, key: str, reason: str) -> tuple[None, str]:
        code = reason.split(":", 1)[0]
        self.rejected[code] += 1
        self.rejected_by_key[(key, code)] += 1
        return None, reason

    def forget(self, src: str) -> None:
        """Drop the time state of one source (e.g. when a stream restarts)."""
        for k in [k for k in self.last_t if k[1] == src]:
            del self.last_t[k]
