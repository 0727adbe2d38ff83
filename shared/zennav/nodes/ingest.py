"""The ingest service's streaming core, transport-agnostic over the bus object it is given: publish a run's
sensor messages paced in data time or as fast as the consumers drain (``stream``), pause while an awaited
service is down (``hold_while_down``), and stay within a lead of the slowest ins following the stream
(``Progress``), wait for the subscribers (``wait_matching``), keep its last messages for consumers that lack some
(``History``, fetched with ``fetch_history``); see zennav.services.ingest for the wiring."""
from __future__ import annotations

import argparse
import bisect
import threading
import time
from collections import deque
from itertools import islice

import msgpack

from .. import messages as M


class History:
    """The ingest's sensor messages of its last ``size`` cseqs (samples: an imu_batch holds one per IMU sample),
    served by cseq range on <base>/sensor/history (Bus.serve): a
    consumer that lacks some (a restarted ins behind its checkpoint, a message lost in transit) fetches them
    outside its live queue (zennav.stream.Backfill, ``fetch_history``). A query's payload is msgpack
    [first, last] (cseqs, at most ``max_range`` apart); its one reply is msgpack [[key, payload], ...]: the
    messages with a cseq in that range (an imu_batch when any of its cseqs is), in order, as published; what the
    ingest no longer has is left out. Not thread-bound: the stream's thread adds, zenoh's answers."""

    def __init__(self, bus, key: str, size: int, max_range: int = 10_000):
        self.size, self.max_range = int(size), max_range
        self._msgs: deque[tuple[int, int, str, bytes]] = deque()  # (cseq, last cseq, key, payload)
        self._lock = threading.Lock()
        bus.serve(key, self.answer)

    def add(self, key: str, msg: dict, payload: bytes) -> None:
        """A message just published on key (its payload as sent); the messages wholly older than the last size
        cseqs go."""
        cseq = msg["cseq"]
        last = cseq + len(msg["t_ns_list"]) - 1 if msg["schema"] == "imu_batch" else cseq
        with self._lock:
            self._msgs.append((cseq, last, key, payload))
            while self._msgs[0][1] <= last - self.size:
                self._msgs.popleft()

    def answer(self, query: bytes) -> bytes | None:
        """The reply to a query's payload (None: a malformed query, not answered)."""
        try:
            first, last = msgpack.unpackb(query)
        except Exception:  # msgpack raises many types; a wrong shape raises ValueError/TypeError
            return None
        if type(first) is not int or type(last) is not int or not 0 <= last - first <= self.max_range:
            return None
        with self._lock:
            msgs = list(self._msgs)  # a copy: the deque moves on while it is searched (at most size entries)
        i = bisect.bisect_left(msgs, first, key=lambda m: m[1])  # the first message that reaches first
        out = []
        for cseq, _, key, payload in islice(msgs, i, None):
            if cseq > last:
                break
            out.append([key, payload])
        return msgpack.packb(out)


def fetch_history(bus, key: str, first: int, last: int, timeout_s: float = 5.0) -> list[tuple[str, dict]] | None:
    """The messages of cseqs first..last from the ingest's History on key, as validated (key, message) pairs;
    None when no ingest answered, or its reply is malformed (counted rejected on the bus). Queried with
    zennav.messages.HISTORY_QOS (blocking: the replies take it). A reply entry that is not a valid message of a
    sensor key of this vehicle is counted rejected on the bus and left out."""
    replies = bus.get(key, timeout_s, payload=msgpack.packb([first, last]), qos=M.HISTORY_QOS)
    if not replies:
        return None
    validator, base, out = M.Validator(), bus.keys.base + "/sensor/", []
    for _, reply in replies:
        try:
            pairs = msgpack.unpackb(reply)
        except Exception as e:  # msgpack raises many types
            bus.count_rejected(key, f"bad_history: {type(e).__name__}")
            return None
        for entry in pairs if isinstance(pairs, list) else [None]:
            if not (isinstance(entry, list) and len(entry) == 2 and isinstance(entry[0], str)
                    and isinstance(entry[1], bytes) and entry[0].startswith(base)):
                bus.count_rejected(key, "bad_history: not a [sensor key, payload] pair")
                continue
            msg, reason = validator.check(*entry)
            if msg is None:
                bus.count_rejected(entry[0], reason)
            else:
                out.append((entry[0], msg))
    return out


class Progress:
    """How far each ins following this ingest's stream got (the next cseq its nav status reports), per service
    name (a restarted ins replaces its old self); one not heard from for stale_s [s] is not waited for."""

    def __init__(self, bus, stale_s: float):
        self.src, self.stale_s = bus.src, stale_s
        self._next: dict[str, tuple[int, float]] = {}  # ins service name -> (next cseq, monotonic time heard)
        self._cv = threading.Condition()
        for key in (bus.keys.nav_status(), f"{bus.keys.base}/nav/*/status"):
            bus.subscribe(key, self._on_status, channel="ring", name="progress")

    def _on_status(self, key, msg, recv_ns) -> None:
        st = msg["stream"]
        if st.get("src") == self.src:
            with self._cv:
                self._next[msg["src"].rsplit(".", 2)[0]] = (int(st.get("next_cseq", -1)), time.monotonic())
                self._cv.notify_all()

    def wait_within(self, cseq: int, lead: int, run) -> None:
        """Block while cseq is more than lead ahead of the slowest ins heard from within stale_s."""
        with self._cv:
            while not run.stopping:
                now = time.monotonic()
                live = [n for n, t in self._next.values() if now - t < self.stale_s]
                if not live or cseq - min(live) <= lead:
                    return
                self._cv.wait(0.2)


def hold_while_down(run, waits: list, timeout: float, stats: dict, given_up: set) -> None:
    """As fast as the consumers drain: pause while an awaited service is down (restarting: it recovers the
    messages it missed from the cache), at most timeout [s] per outage. A service still down after that is in
    given_up: not waited for again until it is back (then its next outage pauses the stream again), so a service
    that stays down costs one timeout, not one per message."""
    alive = run.bus.alive()
    given_up &= set(waits) - alive  # those back alive are awaited again
    need = [w for w in waits if w not in given_up]
    if set(need) <= alive:
        return
    log = run.log
    log.warning("pausing the stream: %s down", sorted(set(need) - alive))
    t0 = time.monotonic()
    ok = False
    while not (ok or run.stopping) and time.monotonic() - t0 < timeout:
        ok = run.bus.wait_alive(need, 0.5)
    stats["paused_s"] += round(time.monotonic() - t0)
    if not ok:
        given_up |= set(need) - run.bus.alive()
    (log.info if ok else log.error)("%s after %.1f s", "streaming on: all back" if ok else
                                    f"streaming on without {sorted(given_up)}", time.monotonic() - t0)


def stream(run, msgs, t0_ns: int, speed: float, pubs: dict, stats: dict, hold=None,
           history: History | None = None) -> int | None:
    """Publish the stream's messages (zennav.stream.stream_messages), paced at ``speed`` times real time (0: as
    fast as the consumers drain; hold(cseq): called before each message, may pause), each kept in history; returns
    the last cseq, or None when stopped."""
    wall0 = time.perf_counter()
    msg: dict = {}
    for kind, msg in msgs:
        if run.stopping:
            return None
        if hold is not None:
            hold(msg["cseq"])
        if speed > 0 and kind == "imu":
            delay = wall0 + (msg["t_ns"] - t0_ns) / 1e9 / speed - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        payload = pubs[kind].put(msg)
        if history is not None:
            history.add(pubs[kind].key, msg, payload)
        if kind != "stream":
            stats[kind] += len(msg["t_ns_list"]) if msg["schema"] == "imu_batch" else 1
        stats["cseq"] = msg["cseq"]
    return msg.get("last_cseq")


def outage_arg(parse):
    """argparse type from a zennav.replay outage parser (ValueError -> a usage error with the reason)."""
    def conv(text: str):
        try:
            return parse(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
    conv.__name__ = parse.__name__
    return conv


def wait_matching(publishers, timeout_s: float, stopping) -> bool:
    """Wait up to timeout_s [s] (or until stopping()) for a subscriber on every publisher (zenoh's matching
    status); whether they all have one."""
    deadline = time.monotonic() + timeout_s
    while not all(p.matching for p in publishers) and time.monotonic() < deadline and not stopping():
        time.sleep(0.01)
    return all(p.matching for p in publishers)


def wait_for_consumers(run, waits: list, publishers, timeout_s: float) -> bool:
    """Wait for the services ``waits`` to be alive (False, logged and the state set to error, when they are not
    after timeout_s [s]), then for a subscriber on ``publishers`` (a warning when none after timeout_s)."""
    if not waits:
        return True
    run.set_state("starting", f"waiting for {','.join(waits)}")
    if not run.bus.wait_alive(waits, timeout_s):
        run.log.error("gave up waiting for %s (alive: %s)", waits, sorted(run.bus.alive()))
        run.set_state("error", f"{waits} not alive")
        return False
    if not wait_matching(publishers, timeout_s, lambda: run.stopping):
        run.log.warning("no subscriber on the sensor keys after %.0f s: streaming anyway", timeout_s)
    return True


def make_hold(run, waits: list, rejoin_timeout_s: float, max_lead: int, stats: dict):
    """The hold of an as-fast-as-drained stream before each message (cseq): pause while a waited-for service is
    down (hold_while_down; given up after rejoin_timeout_s [s]) and, with max_lead > 0, keep within max_lead
    messages of the slowest consumer's progress."""
    progress, given_up = Progress(run.bus, rejoin_timeout_s), set[str]()  # still down after the timeout

    def hold(cseq: int) -> None:
        hold_while_down(run, waits, rejoin_timeout_s, stats, given_up)
        if max_lead > 0:
            progress.wait_within(cseq, max_lead, run)

    return hold


def wait_for_end(run, acks, ins_waited: bool, last_cseq: int, ack_timeout_s: float, linger_s: float,
                 exit_on_end: bool) -> None:
    """After the last message (last_cseq): wait for every ins's acknowledgement when an ins was waited for
    (closing the session drops what is still queued; at most ack_timeout_s [s]), else with exit_on_end linger
    linger_s [s] for the queues to drain; without exit_on_end stay up until stopped."""
    if ins_waited:
        ok = acks.wait(last_cseq, ack_timeout_s, lambda: run.stopping)
        run.log.info("end of stream %s by %s", "acknowledged" if ok else "NOT acknowledged",
                     sorted(acks.following) if ok else sorted(acks.pending(last_cseq)) or "any ins")
    elif exit_on_end:
        run.wait(linger_s)
    if not exit_on_end:
        run.wait()
