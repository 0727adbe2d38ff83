"""Record the bus to MCAP and publish an MCAP back (`zennav record`, `zennav bus-replay`).

MCAP layout (opens in Foxglove Studio): one channel per zenoh key (topic = the key), one schema per message
schema. ``--encoding json`` (default) stores each message as JSON with a JSON-schema description of its
schema (``<name>@v<version>``), so Foxglove shows and plots the fields; ``--encoding msgpack`` stores the
payload bytes exactly as they travelled, with message encoding "msgpack" (Foxglove lists the channels but
cannot decode them). Both replay bit for bit: float64 values are written with Python's round-trip ``repr``
and re-encoded to the same msgpack floats. log_time is the message's sample time ``t_ns`` as Unix time
(zennav.gpstime; a service heartbeat's t_ns is already wall-clock Unix time), so Foxglove's timeline is the
sample time; publish_time the message's pub_ns (wall clock). Messages are stored in receive order. In json mode
payloads that fail validation are counted and not recorded (they could not be represented); msgpack mode
records everything received (an undecodable payload at its receive time).

Beside the raw messages, solutions and GNSS fixes get Foxglove views (zennav.foxglove: foxglove.LocationFix,
PoseInFrame, FrameTransform on ``<key>/location``, ``/pose``, ``/tf``; channel metadata ``derived_from``), so a
map and a 3-D view need no configuration. Readers of zennav messages (``read_mcap``) skip them.

Replay republishes every recorded message of the selected keys in receive order with the original gaps of
their log (sample) times (``--speed 1``), N times faster, or as fast as the consumers drain (``--speed 0``),
through the stream's QoS; the header (src, seq, pub_ns) is restamped by the replaying publisher, everything
else is unchanged, so an ins fed from a replay reproduces the recorded solution exactly.
"""
from __future__ import annotations

import json
import logging
import re
import threading
import time
from pathlib import Path

from . import messages as M
from .foxglove import SCHEMAS as FOXGLOVE_SCHEMAS
from .foxglove import FoxgloveViews
from .gpstime import gps_ns_to_unix_ns

log = logging.getLogger("zennav.record")

_JSON_TYPES = {"int": {"type": "integer"}, "float": {"type": "number"}, "str": {"type": "string"},
               "bool": {"type": "boolean"}, "map": {"type": "object"}, "any": {}}


def _spec_schema(spec) -> dict:
    if isinstance(spec, tuple):
        if spec[0] == "opt":
            inner = _spec_schema(spec[1])
            return {"anyOf": [inner, {"type": "null"}]}
        arr = {"type": "array", "items": {"type": "integer" if spec[0] == "ints" else "number"}}
        if spec[0] == "vec":
            arr.update(minItems=spec[1], maxItems=spec[1])
        return arr
    return dict(_JSON_TYPES[spec])


def json_schema(schema: M.Schema) -> dict:
    """JSON schema of one zennav message schema (for MCAP / Foxglove)."""
    props = {name: _spec_schema(spec) for name, spec in schema.fields.items()}
    required = [n for n, s in schema.fields.items() if not (isinstance(s, tuple) and s[0] == "opt")]
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": f"zennav.{schema.name}",
            "description": schema.doc, "type": "object", "properties": props, "required": required}


def log_time_ns(msg: dict | None, recv_ns: int) -> int:
    """An MCAP log time for a message: its sample time as Unix ns (a heartbeat's wall-clock t_ns as it is); the
    receive time for a payload that could not be decoded."""
    if msg is None:
        return int(recv_ns)
    return int(msg["t_ns"]) if msg["schema"] == "service_status" else gps_ns_to_unix_ns(msg["t_ns"])


def _compression():
    from mcap.writer import CompressionType

    try:
        import zstandard  # noqa: F401

        return CompressionType.ZSTD
    except ImportError:
        return CompressionType.NONE


class SolutionTally:
    """`zennav record --until-stream-end`: per ins (its nav status key, also with a --nav-prefix), the solutions of
    its finished stream (the status's stream.solutions, one per IMU sample) against the distinct solution times
    recorded on its solution key. ``complete()``: every ins seen acknowledged its end and all its solutions are in.

    A resumed ins (zennav.checkpoint) publishes the solutions since its checkpoint again: recorded, counted as
    repeats. Solutions a killed ins had put but not yet sent (queued in its own zenoh transmit queue, behind a slow
    consumer) and that precede its checkpoint cannot be recovered: its publisher's cache died with it and the
    resumed ins starts after them. They are counted as missing, exactly (expected minus distinct times)."""

    def __init__(self) -> None:
        self.expected: dict[str, int | None] = {}  # nav status key -> solutions of its finished stream
        self.times: dict[str, set[int]] = {}  # nav solution key -> distinct solution times [ns]
        self.repeats: dict[str, int] = {}  # nav solution key -> solutions received again (same time)

    def add(self, key: str, msg: dict | None) -> None:
        """A validated message recorded on key (None: invalid, ignored)."""
        stream = M.stream_of(key)
        if msg is None or stream is None:
            return
        if stream.name == "nav/status":
            st = msg.get("stream", {})
            self.expected[key] = st.get("solutions") if st.get("done") else None
        elif stream.name == "nav/solution":
            times = self.times.setdefault(key, set())
            for t in msg.get("t_ns_list") or (msg["t_ns"],):  # a nav_solution_batch: each of its solutions
                if t in times:
                    self.repeats[key] = self.repeats.get(key, 0) + 1
                times.add(t)

    def ended(self) -> bool:
        """Every ins seen acknowledged its stream's end."""
        return bool(self.expected) and all(n is not None for n in self.expected.values())

    def missing(self) -> dict[str, int]:
        """Per solution key of an ins that acknowledged its end: solutions not recorded."""
        return {k[:-len("status")] + "solution": n - len(self.times.get(k[:-len("status")] + "solution", ()))
                for k, n in self.expected.items() if n is not None}

    def complete(self) -> bool:
        return self.ended() and not any(self.missing().values())

    def summary(self) -> str:
        return "; ".join(f"{k}: {len(self.times.get(k, ()))} solutions, {self.repeats.get(k, 0)} repeated (a resumed "
                         f"ins's), {n} missing" for k, n in self.missing().items())


class McapRecorder:
    """Writes (key, payload, recv_ns) or (key, message) to an MCAP file with the Foxglove views; thread-safe."""

    def __init__(self, path, encoding: str = "json"):
        from mcap.writer import Writer

        if encoding not in ("json", "msgpack"):
            raise ValueError("encoding must be json or msgpack")
        self.path = Path(path)
        self.encoding = encoding
        self._f = open(self.path, "wb")
        self._w = Writer(self._f, compression=_compression())
        self._w.start(profile="", library="zennav")
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._validator = M.Validator()
        self._lock = threading.Lock()
        self.count = 0
        self.skipped = 0
        self.per_key: dict[str, int] = {}
        self._closed = False
        self._views = FoxgloveViews()
        self._seq: dict[str, int] = {}

    def _schema_id(self, name: str | None) -> int:
        if name is None:
            return 0
        sid = self._schemas.get(name)
        if sid is None:
            sch = M.SCHEMAS[name]
            if self.encoding == "json":
                sid = self._w.register_schema(f"zennav.{name}@v{sch.version}", "jsonschema",
                                              json.dumps(json_schema(sch)).encode())
            else:
                sid = self._w.register_schema(f"zennav.{name}@v{sch.version}", "",
                                              json.dumps(json_schema(sch)).encode())
            self._schemas[name] = sid
        return sid

    def add(self, key: str, payload: bytes, recv_ns: int) -> dict | None:
        """A payload as received on key at wall time recv_ns [ns]; returns its validated message (None: invalid)."""
        msg = None
        try:
            m = M.decode(payload)
            if not M.validate_map(m, key):
                msg = m
        except Exception:
            pass
        self.add_message(key, msg, payload, recv_ns)
        return msg

    def add_message(self, key: str, msg: dict | None, payload: bytes | None = None, recv_ns: int = 0) -> None:
        """A validated message (or None: an undecodable payload) of key; its Foxglove views after it."""
        with self._lock:
            if self._closed:
                return
            if self.encoding == "json":
                if msg is None:
                    self.skipped += 1
                    return
                data = json.dumps(msg, allow_nan=False, separators=(",", ":")).encode()
            else:
                data = payload if payload is not None else M.encode(msg)
            name = msg["schema"] if msg is not None else None
            ck = (key, name or "")
            cid = self._channels.get(ck)
            if cid is None:
                cid = self._w.register_channel(key, "json" if self.encoding == "json" else "msgpack",
                                               self._schema_id(name), {"zenoh_key": key})
                self._channels[ck] = cid
            seq = msg.get("seq", 0) if msg is not None else 0
            pub = msg.get("pub_ns", recv_ns) if msg is not None else recv_ns
            log_ns = log_time_ns(msg, recv_ns)
            self._w.add_message(cid, log_time=log_ns, data=data, publish_time=int(pub),
                                sequence=int(seq) & 0xFFFFFFFF)
            self.count += 1
            self.per_key[key] = self.per_key.get(key, 0) + 1
            for m in M.solutions(msg) if msg is not None else ():  # a nav_solution_batch: each solution's views
                m_log = log_ns if m is msg else log_time_ns(m, recv_ns)
                for topic, schema, view in self._views.derived(key, m):
                    self._add_view(topic, schema, view, key, m_log, int(pub))

    def _add_view(self, topic: str, schema: str, view: dict, key: str, log_ns: int, pub_ns: int) -> None:
        cid = self._channels.get((topic, schema))
        if cid is None:
            sid = self._schemas.get(schema)
            if sid is None:
                sid = self._schemas[schema] = self._w.register_schema(
                    schema, "jsonschema", json.dumps(FOXGLOVE_SCHEMAS[schema]).encode())
            cid = self._channels[(topic, schema)] = self._w.register_channel(topic, "json", sid,
                                                                             {"derived_from": key})
        n = self._seq[topic] = self._seq.get(topic, -1) + 1
        self._w.add_message(cid, log_time=log_ns, data=json.dumps(view, separators=(",", ":")).encode(),
                            publish_time=pub_ns, sequence=n & 0xFFFFFFFF)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._w.finish()
            self._f.close()


def read_mcap(path, keys: list[str] | None = None):
    """Yield the zennav messages as (key, message map or None, payload bytes, log_time_ns) in recorded (receive)
    order; keys are regexes. The Foxglove views are skipped."""
    from mcap.reader import make_reader

    pats = [re.compile(k) for k in keys] if keys else None
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            if "derived_from" in channel.metadata:
                continue
            key = channel.topic
            if pats and not any(p.search(key) for p in pats):
                continue
            if channel.message_encoding == "json":
                msg = json.loads(message.data)
                yield key, msg, None, message.log_time
            else:
                payload = bytes(message.data)
                try:
                    msg = M.decode(payload)
                except Exception:
                    msg = None
                yield key, msg, payload, message.log_time


def glob_to_regex(pattern: str) -> str:
    """A zenoh-like key pattern ('*' one chunk, '**' any) as a regex on the full key."""
    out = re.escape(pattern).replace(r"\*\*", ".*").replace(r"\*", "[^/]*")
    return "^" + out + "$"


def replay(bus, path, keys: list[str] | None = None, speed: float = 1.0, vehicle: str | None = None,
           stop: threading.Event | None = None, raw: bool = False) -> dict:
    """Publish the recorded messages of ``keys`` (zenoh-like patterns) through ``bus``; returns counts.
    raw=True republishes msgpack payloads as recorded (header not restamped)."""
    regs = [glob_to_regex(k) for k in keys] if keys else None
    counts: dict[str, int] = {}
    wall0 = None
    t0 = None
    for key, msg, payload, log_ns in read_mcap(path, regs):
        if stop is not None and stop.is_set():
            break
        if vehicle:
            parts = key.split("/", 3)
            if len(parts) == 4:
                key = f"{parts[0]}/{parts[1]}/{vehicle}/{parts[3]}"
        if speed > 0:
            if wall0 is None:
                wall0, t0 = time.perf_counter(), log_ns
            delay = wall0 + (log_ns - t0) / 1e9 / speed - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        pub = bus.publisher(key)
        if raw and payload is not None:
            pub.put_raw(payload)
        elif msg is not None:
            pub.put(msg)
        elif payload is not None:
            pub.put_raw(payload)
        counts[key] = counts.get(key, 0) + 1
    return counts
