"""The ins's side of the learning loop over the bus, transport-free: publishes the engine's training samples and
prediction queries, keeps the pending queries and fuses the predictor's matching answers (see
zennav.services.ins for the wiring)."""
from __future__ import annotations

from zennav import messages as M


class LearningLink:
    """The ins side of the learning loop over the bus (see the module docstring): publishes the core's samples
    and queries (``publish("sample" | "query", msg)``; the publisher stamps src/seq), keeps the pending
    queries and fuses the matching corrections."""

    def __init__(self, publish, log, targets=("drift",), max_age_s: float = 1.0):
        self.publish = publish
        self.log = log
        self.targets = frozenset(targets)
        self.max_age_ns = int(max_age_s * 1e9)
        self.pending: dict[tuple, object] = {}  # (src, seq) -> LearnQuery, oldest first
        self.counts: dict[str, int] = {}
        self.last_model = ""
        self.last_version = -1
        self._n = 0

    def _count(self, what: str, n: int = 1) -> None:
        self.counts[what] = self.counts.get(what, 0) + n

    def reset(self) -> None:
        if self.pending:
            self._count("unanswered", len(self.pending))
        self.pending.clear()

    def after_imu(self, nav) -> None:
        for s in nav.pop_samples():
            if s.target in self.targets:
                self.publish("sample", M.learn_sample_msg(s))
                self._count("samples")
        queries = nav.pop_queries()
        p = self.pending
        while p:  # queries never answered (no model for the target, predictor down, message lost)
            first = next(iter(p))
            if nav.t_ns - p[first].t_ns <= self.max_age_ns:
                break
            del p[first]
            self._count("unanswered")
        for q in queries:
            if q.target not in self.targets:
                continue
            msg = M.learn_query_msg(q)
            self.publish("query", msg)
            self._n += 1
            p[(msg.get("src", ""), msg.get("seq", self._n))] = q
            self._count("queries")

    def on_correction(self, nav, msg: dict) -> bool:
        """Fuse the answer to a pending query; False (counted) when it is not fused."""
        q = self.pending.pop((msg.get("query_src"), msg.get("query_seq")), None)
        if q is None:
            self._count("unmatched")
            return False
        if msg["kind"] != q.target:
            self._count("mismatched")
            return False
        if nav.last_fused_t_ns >= q.t_ns:
            self._count("stale")
            return False
        if nav.t_ns - q.t_ns > self.max_age_ns:
            self._count("late")
            return False
        self.last_model, self.last_version = msg["model"], msg["version"]
        fused = bool(nav.on_correction(q, msg["value"], msg["std"]))  # the core counts gate/malformed rejections
        self._count("fused" if fused else "not_fused")
        return fused

    def status(self) -> dict:
        return {"learning": True, "targets": sorted(self.targets), "pending": len(self.pending),
                "model": self.last_model, "version": int(self.last_version),
                **{k: int(v) for k, v in self.counts.items()}}
