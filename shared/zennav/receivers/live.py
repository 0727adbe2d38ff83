"""The ingest's sensor stream with the GNSS fixes of a live receiver (``zennav-ingest --gnss-receiver``).

IMU samples come from the dataset (its description and initial state too), paced at ``speed`` times real time
(0: as fast as the fixes allow); GNSS fixes come from the receiver instead of the dataset. The stream stays one
time-ordered sequence (zennav.messages.sensor): before the IMU sample at t goes out, every fix with a time <= t
must be in, so the sample is held until the receiver has handed over a fix newer than t, or the file ended, or
``latency_s`` of wall time passed after the sample was due (the receiver's output latency the stream absorbs).
At speed 0 a sample is due at once, and once a wait timed out the receiver counts as quiet: samples go on
without waiting until its next fix arrives.
A fix that arrives after IMU samples past its time went out is dropped and counted ``late_fix``; fixes inside
the outage windows are withheld (``withheld``). stream_start's expected GNSS count is -1 (unknown); stream_end
carries the number sent.
"""
from __future__ import annotations

import collections
import queue
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import TYPE_CHECKING

from .. import messages as M
from ..stream import stream_messages
from .receiver import GnssReceiver

if TYPE_CHECKING:
    from ..replay import EventPlan


def live_messages(ds, windows: list, events: EventPlan, receiver: GnssReceiver, speed: float, latency_s: float,
                  stopping: Callable[[], bool] = lambda: False) -> Iterator[tuple[str, dict]]:
    """(kind, message) of the stream (as zennav.stream.stream_messages) with the dataset's GNSS replaced by the
    receiver's fixes; events: zennav.replay.sensor_events' selection (its GNSS entries are ignored)."""
    imu_events = replace(events, inserts=[e for e in events.inserts if e[1] != "gnss"])
    pending: collections.deque = collections.deque()
    counts = receiver.events
    cseq = 0
    n_gnss = 0
    last_imu_t = -1
    quiet = False
    wall0 = time.perf_counter()
    t0 = int(ds.initial.t_ns)

    def newest() -> int:
        return pending[-1].t_ns if pending else -1

    def take(timeout: float) -> bool:
        try:
            fix = receiver.fixes.get(timeout=max(timeout, 0.0)) if timeout > 0 else receiver.fixes.get_nowait()
        except queue.Empty:
            return False
        if fix.t_ns <= last_imu_t:
            counts["late_fix"] += 1
            if counts["late_fix"] <= 3 or counts["late_fix"] % 1000 == 0:
                receiver.log.warning("fix at %d ns came after the IMU passed it (%d late so far; raise "
                                     "--gnss-latency)", fix.t_ns, counts["late_fix"])
        elif any(a <= fix.t_ns < b for a, b in windows):
            counts["withheld"] += 1
        else:
            pending.append(fix)
        return True

    for kind, msg in stream_messages(ds, [], imu_events):
        if stopping():
            return
        if kind == "stream":
            if msg["schema"] == "stream_start":
                msg["counts"]["gnss"] = -1
                msg["outages"] = [[int(a), int(b)] for a, b in windows]
            else:
                msg["counts"]["gnss"] = n_gnss
                msg["cseq"] = msg["last_cseq"] = cseq + 1
            yield kind, msg
            continue
        t = msg["t_ns"]
        due = wall0 + (t - t0) / 1e9 / speed if speed > 0 else time.perf_counter()
        while (delay := due - time.perf_counter()) > 0:
            take(delay)
        deadline = due + latency_s
        while take(0.0):
            quiet = False
        while not (quiet or newest() > t or stopping() or (receiver.exhausted.is_set() and receiver.fixes.empty())):
            if take(min(deadline - time.perf_counter(), 0.05)):
                quiet = False
            elif time.perf_counter() >= deadline:
                quiet = speed == 0
                break
        while pending and pending[0].t_ns <= t:
            cseq += 1
            n_gnss += 1
            yield "gnss", M.gnss_msg(pending.popleft(), cseq)
        cseq += 1
        msg["cseq"] = cseq
        last_imu_t = t
        yield kind, msg
