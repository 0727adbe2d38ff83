"""The sensor stream of one run: how the ingest produces it (``stream_messages``) and how its consumers, the
ins and the attitude service, follow it (``StreamFollower``).

``stream_messages(ds, windows, events)`` turns a run's selection (zennav.replay.sensor_events, the one the
in-process replay feeds the engine) into the messages of the sensor keys, each stamped with ``cseq``:
stream_start (the sensor description, zennav.params.SENSOR_FIELDS; the initial state; counts; outages), the
imu (or imu_batch), gnss, dvl and depth messages in order, stream_end.

``StreamFollower`` takes validated sensor messages (any sensor key, any order) and hands its consumer the
samples of ONE stream (one ingest instance, ``src``) strictly in ``cseq`` order (zennav.messages.SequenceMerger,
``imu_batch`` expanded), with ``on_start`` before the first and ``on_end`` after the last.

Source ownership: the stream whose start the follower took is live until its ``stream_end``, or until it has
been silent for ``takeover_after_s``; messages of another source meanwhile are dropped (``foreign_source``)
and its ``stream_start`` is refused (``takeover_refused``); a repeated start of the live source is counted
``duplicate_start``. Once the live stream ended or timed out, another source's start begins a new stream.

No single message stalls the stream: samples are released through zennav.messages.SequenceMerger (bounded
reorder window, holes skipped as counted gaps), and at its turn each is judged by the stream's time chain
(``_accept``): an IMU interval must start where the last one ended (after skipped cseqs: later, by at most
``max_step_s`` per cseq), a fix (a DVL or depth sample) must lie within that much of it, the end must repeat
the start's counts (those it knew: -1 is unknown); a refused sample (counted ``time_jump``, ``time_backwards``,
``bad_end`` in the merge counts) leaves its cseq open for the genuine one. ``tick()`` (``start_ticker``) skips
a hole the stream stopped behind.

Resume (crash recovery): ``resume(start, next_cseq, t_ref_ns)`` takes a checkpoint's position in a stream; it
applies once a message of that source arrives (``on_resume``), and is dropped when another stream starts.

Backfill: samples that wait behind a hole that has not moved for 2 s (a restarted consumer behind its checkpoint,
a message lost in transit) are fetched from the ingest's history (zennav.nodes.ingest.History) outside the
consumer's live queue (``Backfill``, run by ``start_ticker``); a resume not yet applied fetches from its
checkpoint at once.

Late join (one policy for every consumer): a consumer that starts after a stream began (launched late,
restarted by ``zennav launch``) joins it at the first IMU sample it receives. It needs the stream's
description (the ins builds its engine from it), so it asks for the stream's ``stream_start`` with
``fetch_start(src)``: the services query the ingest's latest value on ``sensor/stream`` (the stream key is
served to late joiners, see zennav.messages.keys). Joined that way it is counted ``late_join`` and its
``on_start`` gets the first sample (``join``) besides the start: the attitude filter levels from there; the ins
starts in coarse alignment at that sample's time (heading unknown; position, velocity and attitude from the
next GNSS fixes, as an ins switched on in motion). When nothing is live and the start cannot be had (no
ingest answers, or it ended), messages are dropped and counted ``no_stream``; the start is asked for again
after ``retry_every`` more of them. If the first message received is the one right after the start
(nothing missed), the stream is followed from its start as usual.
"""
from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from . import messages as M
from .params import sensor_map

if TYPE_CHECKING:
    from .replay import EventPlan

DROPS = ("foreign_source", "no_stream", "duplicate_start", "late_join", "takeover_refused")
RESYNC_AFTER = 8  # consecutive IMU samples refused as running backwards that re-anchor the time chain
RESUME_END = 1 << 62  # StreamFollower.hole's last cseq for a resume not yet applied (where the stream is: unknown)


def stream_messages(ds, windows: list, events: EventPlan, batch: int = 1) -> Iterator[tuple[str, dict]]:
    """(kind, message) of the sensor stream of a run (see the module docstring), kind "stream", "imu", "gnss",
    "dvl" or "depth" (the key it goes on); events: zennav.replay.sensor_events'; the publisher stamps src, seq and
    pub_ns. counts: imu and gnss, and
    each aid stream the dataset has (zennav.messages.AID_STREAMS). batch > 1: up to batch consecutive IMU samples
    per imu_batch message, cut before every other sample (the same samples, cseqs and order)."""
    imu, gnss = ds.imu, ds.gnss
    counts = dict.fromkeys(("imu", "gnss", *(a for a in M.AID_STREAMS if getattr(ds, a) is not None)), 0)
    counts.update(events.counts())
    yield "stream", M.make("stream_start", int(ds.initial.t_ns), cseq=0, dataset=ds.name,
                           config=sensor_map(ds.config), initial=M.dataclass_to_map(ds.initial), counts=counts,
                           outages=[[int(a), int(b)] for a, b in windows])
    rows = _ImuRows(imu)
    make = M.make
    prev_t = int(ds.initial.t_ns)
    held: list[tuple] = []  # batch: the IMU samples not yet sent, (t_ns, dtheta, dvel)
    cseq = 0
    for kind, idx in events:
        cseq += 1
        if kind != "imu":
            if held:
                yield "imu", _batch(held, prev_t, cseq - len(held))
                prev_t = held[-1][0]
                held = []
            yield kind, (M.gnss_msg(gnss.fix_at(idx), cseq) if kind == "gnss" else
                         M.aid_msg(kind, getattr(ds, kind).sample(idx), cseq))
        elif batch > 1:
            held.append(rows[idx])
            if len(held) == batch:
                yield "imu", _batch(held, prev_t, cseq - len(held) + 1)
                prev_t = held[-1][0]
                held = []
        else:
            t, dtheta, dvel = rows[idx]
            yield "imu", make("imu", t, cseq=cseq, dt_ns=t - prev_t, dtheta=dtheta, dvel=dvel)
            prev_t = t
    if held:
        yield "imu", _batch(held, prev_t, cseq - len(held) + 1)
        prev_t = held[-1][0]
    cseq += 1
    yield "stream", M.make("stream_end", prev_t, cseq=cseq, counts=counts, last_cseq=cseq)


class _ImuRows:
    """rows[i] -> (t_ns, dtheta [3], dvel [3]) of IMU sample i as Python values, converted CHUNK samples at a time
    (all at once they take about 330 bytes a sample: 240 MB for an hour at 200 Hz, held for the whole stream)."""

    CHUNK = 8192

    def __init__(self, imu) -> None:
        self.imu, self.first = imu, 0  # the rows of samples first .. first + len(self.t) - 1
        self.t: list = []
        self.dtheta: list = []
        self.dvel: list = []

    def __getitem__(self, i: int) -> tuple:
        k = i - self.first
        if not 0 <= k < len(self.t):
            part = slice(i, i + self.CHUNK)
            self.first, k = i, 0
            self.t, self.dtheta, self.dvel = (a[part].tolist() for a in (self.imu.t_ns, self.imu.dtheta, self.imu.dvel))
        return self.t[k], self.dtheta[k], self.dvel[k]


def _batch(held: list, prev_t: int, first_cseq: int) -> dict:
    ts = [r[0] for r in held]
    return M.imu_batch_msg(ts, [b - a for a, b in zip([prev_t] + ts[:-1], ts)], [r[1] for r in held],
                           [r[2] for r in held], first_cseq)


class StreamFollower:
    """One consumer's view of the sensor stream (see the module docstring).

    on_start(start, join): a stream begins; start is its stream_start message, join None when followed from
    its start, else the first imu message of a late join. on_sample(key, msg): an imu, gnss, dvl or depth message of the
    live stream (each sample of an imu_batch as an imu message), in cseq order. on_end(end): its stream_end,
    after every sample. fetch_start(src) -> the stream_start of src or None (late join; None: never joins).
    on_resume(start): a stream resumed from a checkpoint (``resume``) gets its first message.
    takeover_after_s: another source's stream_start replaces a live stream only after this long [s, wall clock]
    without a message of it (inf: only after its end); max_step_s: the most a sample may run ahead of the
    stream's time per cseq [s]; max_hold, timeout_s: the merge's reorder window (zennav.messages.SequenceMerger).
    on_flush(): called at the end of every call that may have handed samples on (on_message, tick, backfill): a
    consumer that collects samples (the ins's block loop over an imu_batch) processes them there.
    on_batch(key, msg) (None: not used): an imu_batch whose samples all come next in cseq order (nothing held) and
    each continue the time chain, handed on whole (the merge and the chain advanced as by its samples one by one:
    the same order, checks and counts); any other imu_batch goes to on_sample sample by sample."""

    def __init__(self, on_start: Callable, on_sample: Callable, on_end: Callable,
                 fetch_start: Callable[[str], dict | None] | None = None, log: logging.Logger | None = None,
                 retry_every: int = 1000, max_hold: int = 1 << 16, timeout_s: float = 5.0,
                 takeover_after_s: float = 10.0, max_step_s: float = 1.0, on_resume: Callable | None = None,
                 on_flush: Callable[[], None] | None = None, on_batch: Callable[[str, dict], None] | None = None):
        self.on_start, self.on_sample, self.on_end, self.on_batch = on_start, on_sample, on_end, on_batch
        self.on_resume = on_resume
        self.on_flush = on_flush or (lambda: None)
        self.fetch_start = fetch_start
        self.log = log or logging.getLogger("zennav.stream")
        self.retry_every = retry_every
        self.max_hold, self.timeout_s = max_hold, timeout_s
        self.takeover_after_s = takeover_after_s
        self.max_step_ns = int(max_step_s * 1e9)
        self.src: str | None = None
        self.start: dict | None = None
        self.dataset = ""
        self.done = False
        self.last_cseq = -1
        self.merger: M.SequenceMerger | None = None
        self.counts: Counter[str] = Counter({d: 0 for d in DROPS})
        self.t_ref = 0  # [ns] end of the last IMU interval handed on (the time chain's reference)
        self._last_cseq = -1  # cseq of the last sample handed on
        self._refused = 0  # consecutive IMU slots refused as running backwards (a forged reference?)
        self._seen = 0.0  # monotonic time of the live stream's last message
        self._heard = 0.0  # monotonic time of the last message received live (not fetched by a backfill)
        self._filling = False  # messages fetched by a backfill are being pushed
        self._resume: tuple[dict, int, int] | None = None
        self._busy = False  # a message is being handled (its consumer may wait, releasing the lock: lockstep)
        self._retry_in = 0
        self.backfills: Counter[str] = Counter()  # Backfill: backfilled (samples), backfill_empty, backfill_failed

    def on_message(self, key: str, msg: dict) -> None:
        """A validated message of a sensor key (stream_start, imu, imu_batch, gnss, stream_end)."""
        src = msg["src"]
        if not self._filling:
            self._heard = time.monotonic()
        if self._resume is not None:
            if src == self._resume[0]["src"]:
                self._activate()
            elif msg["schema"] == "stream_start":
                self.log.info("checkpoint of stream %s dropped: a new stream starts", self._resume[0]["src"])
                self._resume = None
        if msg["schema"] == "stream_start":
            if src == self.src:
                self.counts["duplicate_start"] += 1
                self._seen = time.monotonic()
            elif self._live():
                self._drop("takeover_refused", msg)
            else:
                self._begin(msg, msg["cseq"] + 1, None)
            return
        if src != self.src:
            if self._live():
                self._drop("foreign_source", msg)
                return
            if not self._join(msg):
                return
        self._seen = time.monotonic()
        merger = self.merger
        assert merger is not None  # _begin sets it with src: a message of the live (or just joined) stream
        self._busy = True
        try:
            if self.on_batch is not None and msg["schema"] == "imu_batch" and self._in_order(msg, merger):
                self.on_batch(key, msg)
            else:
                for m in M.samples(msg):
                    merger.push(m["cseq"], (key, m), self._release)
            self.on_flush()
        finally:
            self._busy = False

    def _in_order(self, msg: dict, merger: M.SequenceMerger) -> bool:
        """The imu_batch msg's samples come next (nothing held) and each continues the time chain, as _accept
        judges an IMU sample at its turn: the merge and the chain advanced past them (True), or nothing done."""
        if msg["cseq"] != merger.next:
            return False
        t_ref = self.t_ref
        for t, dt in zip(msg["t_ns_list"], msg["dt_ns_list"]):
            if t - dt != t_ref:
                return False
            t_ref = t
        n = len(msg["t_ns_list"])
        if not merger.advance(n):
            return False
        self.t_ref, self._refused, self._last_cseq = t_ref, 0, msg["cseq"] + n - 1
        return True

    def _live(self) -> bool:
        """A stream is live: started, not ended, and heard from within takeover_after_s."""
        return self.src is not None and not self.done and \
            time.monotonic() - self._seen < self.takeover_after_s

    def tick(self) -> None:
        """Call periodically (under the consumer's lock): skips a gap the stream stopped behind (a lost message
        right before the end), see zennav.messages.SequenceMerger.expire."""
        if self.merger is not None and not self.done and not self._busy:  # busy: a sample waits (lockstep)
            self.merger.expire(self._release)
            self.on_flush()

    def hole(self, after_s: float) -> tuple[int, int] | None:
        """The cseqs (first, last) the live stream's samples have waited for at least after_s [s]; None when there
        are none, or a sample is being handled. A resume not yet applied waits from its checkpoint on (last:
        unknown, RESUME_END): the ingest's history may have what comes next before the stream does (a drained
        stream waits for this consumer's progress)."""
        if self._resume is not None:
            return self._resume[1], RESUME_END
        m = self.merger
        if m is None or self.done or self._busy:
            return None
        h = m.hole()
        return None if h is None or h[2] < after_s else (h[0], h[1])

    def hold(self) -> None:
        """The hole is being fetched (Backfill): the merge waits for it timeout_s more."""
        if self.merger is not None:
            self.merger.touch()

    def backfill(self, first: int, last: int, got: list[tuple[str, dict]] | None) -> None:
        """The messages fetched for the cseqs first..last (Backfill; None: not answered, counted backfill_failed):
        those of the live stream go into the merge; the cseqs it still waits for before the first one fetched
        are no longer to be had (counted backfill_empty) and skipped as a gap. A resume not yet applied is applied
        by the first fetched message of its stream (none fetched, or no answer: it waits on, nothing counted)."""
        if self._resume is not None:  # the checkpoint's stream, if the history has it: resume now
            got = [(k, msg) for k, msg in got or () if msg["src"] == self._resume[0]["src"]]
            if not got:
                return
            self._activate()
        m = self.merger
        if got is None:
            self.backfills["backfill_failed"] += 1
            self.log.warning("backfill of cseq %d..%d: no answer from the ingest's history", first, last)
            return
        if m is None or self.done or self._busy:  # the stream moved on meanwhile
            return
        got = [(k, msg) for k, msg in got if msg["src"] == self.src and msg["schema"] != "stream_start"]
        self.backfills["backfilled"] += sum(len(M.samples(msg)) for _, msg in got)
        gone = min((msg["cseq"] for _, msg in got), default=last + 1) - m.next
        if gone > 0:
            self.backfills["backfill_empty"] += gone
            self.log.warning("backfill: cseq %d..%d no longer in the ingest's history: skipped", m.next,
                             m.next + gone - 1)
            m.skip_to(m.next + gone, self._release)
            self.on_flush()
        self._filling = True
        try:
            for key, msg in got:
                self.on_message(key, msg)
        finally:
            self._filling = False

    def quiet(self, after_s: float) -> bool:
        """Whether a started stream, not done, has received nothing live for after_s [s] (it ended or paused while
        this consumer was away: Backfill goes on through the history)."""
        return (self.merger is not None and not self.done and not self._busy and self._resume is None
                and time.monotonic() - self._heard >= after_s)

    def resume(self, start: dict, next_cseq: int, t_ref_ns: int) -> None:
        """Resume the stream of ``start`` at next_cseq (a checkpoint: the samples before it were handled, the last
        IMU interval ended at t_ref_ns), once a message of its source arrives; a new stream's start first drops
        it. on_resume(start) is called then, instead of on_start."""
        self._resume = (start, int(next_cseq), int(t_ref_ns))

    def _activate(self) -> None:
        assert self._resume is not None
        start, next_cseq, t_ref = self._resume
        self._resume = None
        self._set(start, next_cseq)
        self.t_ref, self._last_cseq = t_ref, next_cseq - 1
        self.log.warning("resuming stream %s from %s at cseq %d (checkpoint)", start["dataset"], start["src"],
                         next_cseq)
        assert self.on_resume is not None  # resume() is called by consumers that handle it
        self.on_resume(start)

    def _join(self, msg: dict) -> bool:
        """Join the stream of msg (its start was missed) at msg, an IMU message; False when not (yet) possible."""
        start = None
        if msg["schema"] in ("imu", "imu_batch") and self.fetch_start is not None and self._retry_in <= 0:
            start = self.fetch_start(msg["src"])
            if start is None or start.get("schema") != "stream_start" or start.get("src") != msg["src"]:
                start, self._retry_in = None, self.retry_every
        if start is None:
            self._retry_in -= 1
            self._drop("no_stream", msg)
            return False
        if msg["cseq"] == start["cseq"] + 1:  # nothing missed: follow from the start
            self._begin(start, msg["cseq"], None)
            return True
        self.counts["late_join"] += 1
        self.log.warning("joining stream %s from %s late, at cseq %d (its start was cseq %d)", start["dataset"],
                         msg["src"], msg["cseq"], start["cseq"])
        self._begin(start, msg["cseq"], M.samples(msg)[0])
        return True

    def _begin(self, start: dict, next_cseq: int, join: dict | None) -> None:
        if self.src is not None and start["src"] != self.src:
            self.log.info("new stream %s from %s replaces %s%s", start["dataset"], start["src"], self.src,
                          "" if self.done else " (timed out)")
        self._set(start, next_cseq)
        self.t_ref = start["t_ns"] if join is None else join["t_ns"] - join["dt_ns"]
        self._last_cseq = next_cseq - 1
        self.on_start(start, join)

    def _set(self, start: dict, next_cseq: int) -> None:
        self.src, self.start, self.dataset, self.done, self.last_cseq = start["src"], start, start["dataset"], \
            False, -1
        self._refused, self._seen = 0, time.monotonic()
        self.merger = M.SequenceMerger(next_cseq, self.max_hold, self._accept, timeout_s=self.timeout_s)

    def _accept(self, cseq: int, item: tuple[str, dict]) -> str:
        """The stream's time rule for the sample at its turn: '' or the reason it is refused. An IMU interval
        starts where the last one ended (exactly: dt_ns chains the stream), or, after skipped cseqs, later but
        at most max_step_s per cseq; a fix lies within max_step_s per cseq of that time; the end repeats the
        start's counts. Consecutive IMU samples refused as running backwards re-anchor the chain (the sample it
        was anchored on was forged)."""
        msg = item[1]
        schema, t = msg["schema"], msg["t_ns"]
        steps = cseq - self._last_cseq
        ahead = t - self.t_ref
        if schema == "imu":
            t0 = t - msg["dt_ns"]
            if t0 != self.t_ref and not (steps > 1 and t0 > self.t_ref and ahead <= steps * self.max_step_ns):
                if t0 > self.t_ref:
                    return "time_jump"
                self._refused += 1
                if self._refused < RESYNC_AFTER:
                    return "time_backwards"
                self.counts["reanchored"] += 1
                self.log.warning("time chain re-anchored at cseq %d after %d samples refused", cseq, self._refused)
            self.t_ref, self._refused = t, 0
        elif schema in ("gnss", "dvl", "depth"):
            if ahead > steps * self.max_step_ns:
                return "time_jump"
            if -ahead > self.max_step_ns:
                return "time_backwards"
        elif schema == "stream_end":
            assert self.start is not None
            expected = self.start["counts"]  # -1: not known at the start (a live receiver's fixes)
            if (set(msg["counts"]) != set(expected) or msg["last_cseq"] != cseq
                    or any(n >= 0 and msg["counts"][k] != n for k, n in expected.items())):
                return "bad_end"
        self._last_cseq = cseq
        return ""

    def _release(self, item: tuple[str, dict]) -> None:
        key, msg = item
        if msg["schema"] == "stream_end":
            assert self.merger is not None  # _release is called by the merger only
            self.done, self.last_cseq = True, msg["last_cseq"]
            self.on_end(msg)
        else:
            self.on_sample(key, msg)

    def _drop(self, reason: str, msg: dict) -> None:
        self.counts[reason] += 1
        n = self.counts[reason]
        if n <= 3 or n % 1000 == 0:
            self.log.warning("dropped %s from %s (#%d %s; live stream: %s)", msg["schema"], msg["src"], n, reason,
                             self.src)

    def status(self) -> dict:
        """Stream progress for nav_status ``stream``: src, dataset, done, last_cseq, next_cseq, held, the
        merge counts (reordered, duplicate, gap) and the backfill's."""
        m = self.merger
        return {"src": self.src or "", "dataset": self.dataset, "done": self.done, "last_cseq": self.last_cseq,
                "next_cseq": m.next if m else -1, "held": m.held if m else 0,
                **({k: int(v) for k, v in m.counts.items()} if m else {}), **self.backfills}


class Backfill:
    """Fetches the samples a stream waits for from the ingest's history (zennav.nodes.ingest.History), outside the
    consumer's live queue: once samples have waited after_s [s] behind the same hole (a restarted consumer behind
    its checkpoint, a message lost in transit), its cseqs are fetched chunk by chunk (fetch(first, last) ->
    validated (key, message) pairs, None when nobody answered) and pushed into the merge
    (StreamFollower.backfill); each chunk holds the merge's timeout for the hole from its start
    (StreamFollower.hold). A hole nobody answered for (no ingest history) is not fetched again: the merge's
    timeout skips it as a gap. After a full chunk with nothing live behind it, a stream quiet for after_s (it went on,
    or ended, while this consumer was away) is followed on through the history to its end (StreamFollower.quiet).
    Counted in the stream status: backfilled, backfill_empty, backfill_failed.
    Not for a consumer whose sample handling waits releasing the lock (the ins's --lockstep): fetched samples
    pushed while one is being handled would enter the merge in the middle of its release."""

    def __init__(self, follower: StreamFollower, fetch: Callable[[int, int], list | None], after_s: float = 2.0,
                 chunk: int = 1000):
        self.follower, self.fetch, self.after_s, self.chunk = follower, fetch, after_s, chunk
        self._idle_until = 0.0  # [monotonic s] after a round that got nothing, the next waits after_s
        self._logged = -1  # the first cseq of the last hole logged (a resume nobody answers: logged once)
        self._unanswered = -1  # the first cseq of the last hole nobody answered for: the merge's timeout skips it

    def run(self, lock, stopping: Callable[[], bool]) -> None:
        """One round (the ticker's thread): fill the hole the stream has waited behind for after_s, if any."""
        if time.monotonic() < self._idle_until:
            return
        with lock:
            hole = self._next(self.after_s)
        if hole is not None and hole[0] != self._logged:
            self._logged = hole[0]
            self.follower.log.info("backfilling from cseq %d (to %s) from the ingest's history", hole[0],
                                   hole[1] if hole[1] < RESUME_END else "the stream")
        while hole is not None and not stopping():
            first, last = hole[0], min(hole[1], hole[0] + self.chunk - 1)
            got = self.fetch(first, last)
            with lock:
                self.follower.backfill(first, last, got)
                if got is None and hole[1] < RESUME_END:
                    self._unanswered = first
                hole = self._next(0.0) if got is not None else None
                if hole is None and got and _reach(got) >= last and self.follower.quiet(self.after_s):
                    # a full chunk and nothing live behind it: the stream went on (or ended) while this consumer
                    # was away and is quiet now: on through the history, up to its end (its stream_end included)
                    hole = (last + 1, RESUME_END)
            if got is None or (hole is not None and hole[0] <= first):  # no answer or no progress: wait after_s
                self._idle_until, hole = time.monotonic() + self.after_s, None

    def _next(self, after_s: float) -> tuple[int, int] | None:
        """The hole to fetch now (held timeout_s more for it), unless nobody answered for it already."""
        hole = self.follower.hole(after_s)
        if hole is None or hole[0] == self._unanswered:
            return None
        self.follower.hold()
        return hole


def _reach(got: list) -> int:
    """The last cseq the fetched messages cover (an imu_batch covers one per sample)."""
    return max(m["cseq"] + (len(m["t_ns_list"]) - 1 if m["schema"] == "imu_batch" else 0) for _, m in got)


def start_ticker(follower: StreamFollower, lock, stopping: Callable[[], bool], period_s: float = 0.25,
                 backfill: Backfill | None = None):
    """A daemon thread calling follower.tick() every period_s under lock (the bus's callback lock; None: none)
    until stopping(), then a round of backfill (when given)."""
    import threading
    from contextlib import nullcontext

    def run() -> None:
        guard = lock if lock is not None else nullcontext()
        while not stopping():
            time.sleep(period_s)
            with guard:
                follower.tick()
            if backfill is not None:
                backfill.run(guard, stopping)

    t = threading.Thread(target=run, name="zennav-stream-tick", daemon=True)
    t.start()
    return t
