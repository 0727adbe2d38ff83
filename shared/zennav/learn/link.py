"""The ins's side of the learning loop over the bus, transport-free: publishes the engine's training samples and
prediction queries, keeps the pending queries and hands the predictor's matching answers to the engine, which
fuses them or rejects them with its reason (see zennav.services.ins for the wiring).

Every query carries n_samples, the number of samples of its target variant published before it (since this link
started), so that the trainer fits through exactly those and the predictor (in lockstep) answers with that set
(zennav.learn.learner). The counts agree only if the trainer received every sample this link published: a
trainer started later (or restarted) never gets a fit point through n; outside lockstep the predictor then
answers with its live set, as it would without n_samples. Every sample carries the stream's src and its index
(the count of its variant published before it, restored with a checkpoint): a trainer drops the samples a resumed
ins sends again (zennav.nodes.trainer).
Lockstep (lockstep_timeout_s > 0; a replay of a recording): after publishing queries, ``after_imu`` waits for
their answers (or refusals) before it returns, i.e. before the ins consumes its next sensor sample, up to the
timeout (counted: lockstep_timeouts). The wait is on a condition of ``lock``, the lock the answers' callback runs
under (the bus's callback lock of a serial bus), so the answers are fused by ``on_correction`` while the sensor
thread is parked at that one point: the engine then sees the same sequence as the in-process replay.
"""
from __future__ import annotations

import threading
from collections import Counter
from typing import TYPE_CHECKING

from zennav import messages as M

if TYPE_CHECKING:
    from zennav.nav.learning import LearnQuery


class LearningLink:
    """The ins side of the learning loop over the bus (see the module docstring): publishes the core's samples
    and queries (``publish("sample" | "query", msg)``; the publisher stamps src/seq), keeps the pending
    queries and hands the matching answers to the engine (Navigator.on_correction, which judges them: stale,
    late, malformed, gated; counted in its counters). Counts: samples, queries (sent), fused, not_fused (the
    engine's rejections), refused_<reason> (the predictor's), unmatched, mismatched, unanswered (expired after
    max_age_s of data time without an answer), lockstep_timeouts."""

    def __init__(self, publish, log, targets=("drift",), max_age_s: float = 1.0, lockstep_timeout_s: float = 0.0,
                 lock=None):
        self.publish = publish
        self.log = log
        self.targets = frozenset(targets)
        self.max_age_ns = int(max_age_s * 1e9)
        self.lockstep_timeout_s = float(lockstep_timeout_s)
        self.cv = threading.Condition(lock if lock is not None else threading.RLock())
        self.pending: dict[tuple, LearnQuery] = {}  # (src, seq) -> query, oldest first
        self.sent = {t: 0 for t in self.targets}  # samples published per target
        self.counts: Counter[str] = Counter()
        self.last_model = ""
        self.last_version = -1
        self.stream: str | None = None  # src of the sensor stream followed (stamped on the samples)
        self._n = 0

    def reset(self, stream: str | None = None) -> None:
        """A new stream (its src): pending queries are unanswered. The sample counts go on: the trainer counts
        every sample it received from the start, whatever the stream."""
        self.stream = stream
        with self.cv:
            if self.pending:
                self.counts["unanswered"] += len(self.pending)
            self.pending.clear()

    def after_imu(self, nav) -> None:
        for s in nav.pop_samples():
            if s.target in self.targets:
                self.publish("sample", M.learn_sample_msg(s, self.stream, self.sent[s.target]))
                self.sent[s.target] += 1
                self.counts["samples"] += 1
        queries = nav.pop_queries()
        with self.cv:
            p = self.pending
            while p:  # queries never answered (no model for the target, predictor down, message lost)
                first = next(iter(p))
                if nav.t_ns - p[first].t_ns <= self.max_age_ns:
                    break
                del p[first]
                self.counts["unanswered"] += 1
            mine = []
            for q in queries:
                if q.target not in self.targets:
                    continue
                msg = M.learn_query_msg(q, self.sent[q.target])
                self.publish("query", msg)
                self._n += 1
                key = (msg.get("src", ""), msg.get("seq", self._n))
                p[key] = q
                mine.append(key)
                self.counts["queries"] += 1
            if mine and self.lockstep_timeout_s > 0.0:
                if not self.cv.wait_for(lambda: not any(k in self.pending for k in mine), self.lockstep_timeout_s):
                    self.counts["lockstep_timeouts"] += 1
                    self.log.warning("lockstep: no answer to %d queries within %.0f s; going on",
                                     sum(k in self.pending for k in mine), self.lockstep_timeout_s)

    def on_correction(self, nav, msg: dict) -> bool:
        """Fuse the answer to a pending query; False (counted) when it is not fused."""
        with self.cv:
            self.cv.notify_all()
            q = self.pending.pop((msg.get("query_src"), msg.get("query_seq")), None)
            if q is None:
                self.counts["unmatched"] += 1
                return False
            if msg["kind"] != q.target:
                self.counts["mismatched"] += 1
                return False
            if msg.get("refused"):
                self.counts[f"refused_{msg['refused']}"] += 1
                nav.on_refusal(q, str(msg["refused"]))  # a source holding data for the answer stops waiting
                return False
            self.last_model, self.last_version = msg["model"], msg["version"]
            # the engine judges the answer: stale (a fix fused since the query), late, malformed, gated (its counters)
            fused = bool(nav.on_correction(q, msg["value"], msg["std"]))
            self.counts["fused" if fused else "not_fused"] += 1
            return fused

    def status(self) -> dict:
        with self.cv:
            return {"learning": True, "targets": sorted(self.targets), "pending": len(self.pending),
                    "model": self.last_model, "version": int(self.last_version),
                    "lockstep": self.lockstep_timeout_s > 0.0, **{k: int(v) for k, v in self.counts.items()}}
