"""The predictor core: transport-free, numpy only (never imports torch). Used by the predictor service and by the
in-process loop (zennav.learn.loop), so both validate, swap and answer the same way.

``offer(name, msg, signature)`` validates a parameter set (zennav.learn.paramset message) and swaps it in: the
target variant in metrics.target, paramset.validate (schema, name, checksum, the trainer's Ed25519 signature when
the core has a verifier (zennav.learn.signing; reasons unsigned, bad_signature), shapes against the target's
feature and output counts, finite values, ranges, a version newer than the live one and at most max_version_step
above it (version_ahead: a set far ahead would block every legitimate set after it)), a finite positive
metrics.sigma per output.
A set equal to the live one (same version and checksum) is a duplicate, not a rejection. Rejections are counted
per reason (model_<paramset reason>, model_schema, model_invalid_value) and the live set stays.

``answer(target, features, n_samples, wait_s)`` answers a query with (value, 1-sigma, the live model) or refuses
it with a reason (REFUSALS): no_model, bad_features, off_domain (features further than max_domain_excess training
standard deviations outside the training range: a first-order Takagi-Sugeno model extrapolates linearly and without
bound there), nonfinite. With wait_s > 0 (lockstep) it first waits up to wait_s seconds for a set trained through
at least the query's n_samples (metrics.samples_seen), unless the trainer's progress (``trainer_progress``) says
that none will come (too few samples, the Elman not ready, a failed fit: then it answers with the live set, as the
in-process loop does); past wait_s it counts late_model and answers with the live set.

Atomic swap: the live sets are immutable objects (read-only arrays) in a dict keyed by target; a swap is one
reference store, and an answer reads the reference once, so every answer is the forward pass of exactly the one
version it names. An Elman set carries its context; the core advances that context with every query it answers
(as the network does at the edge in seed 002) and starts again from the set's own context when a new set is
swapped in.
"""
from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..nav.learning import FEATURES, OUTPUTS
from . import anfis_numpy, elman, paramset
from .signing import Verifier

REFUSALS = ("no_model", "bad_features", "off_domain", "nonfinite")


@dataclass(frozen=True)
class LiveModel:
    """One validated parameter set in service; never mutated (a swap replaces the object), except an Elman's
    context, which only the answering thread advances."""

    kind: str
    name: str
    target: str
    version: int
    checksum: str
    arrays: Mapping[str, np.ndarray]
    norm: Mapping[str, np.ndarray]
    std: tuple  # 1-sigma per output (physical units), metrics.sigma
    n_in: int
    samples_seen: int  # the set was trained through this many samples of its target (-1: not stated)
    context_gain: float = 0.0  # elman
    context: list = field(default_factory=list)  # elman: [context (n_hidden,)], advanced per answered query

    def forward(self, x: np.ndarray) -> np.ndarray:
        """The prediction (physical units) for features x (n_in,)."""
        if self.kind == "anfis":
            return anfis_numpy.predict(self.arrays, self.norm, x)
        y, self.context[0] = elman.step(self.arrays, self.norm, x, self.context[0], self.context_gain)
        return y


class PredictorCore:
    """Live sets per target, their validation and swap, and the answers (module docstring). offer() may run
    concurrently with answer() (one writer thread at a time)."""

    def __init__(self, max_domain_excess: float = 0.5, verifier: Verifier | None = None,
                 max_version_step: int | None = None):
        self.max_domain_excess = float(max_domain_excess)
        self.verifier = verifier  # None: signatures are not checked (the in-process loop; --allow-unsigned)
        self.max_version_step = max_version_step
        self.live: dict[str, LiveModel] = {}
        self._cv = threading.Condition()  # writers; lockstep answers wait on it for a newer set
        self.sets: Counter[str] = Counter()  # received, accepted, duplicate, rejected
        self.rejected: Counter[str] = Counter()  # per reason
        self.queries: Counter[str] = Counter()  # answered, late_model, and the REFUSALS
        self.last_rejection = ""
        self._trainer: dict[str, tuple[int, int, int]] = {}  # target -> (min_samples, set_through, through)

    # ------------------------------------------------------------------ parameter sets
    def count_rejection(self, name: str, reason: str) -> None:
        """Count a set rejected before it reached offer() (e.g. by the bus's schema check); reason 'code: detail'."""
        with self._cv:
            self.sets["received"] += 1
            self.sets["rejected"] += 1
            self.rejected[reason.split(":", 1)[0]] += 1
            self.last_rejection = f"{name}: {reason}"[:300]

    def offer(self, name: str, msg: Mapping, signature: str | None = None) -> tuple[LiveModel | None, str]:
        """Validate a paramset message published under name (with its signature) and swap it in. Returns (the new
        live model, '') or (None, 'duplicate') or (None, 'code: detail') when rejected (counted)."""
        with self._cv:
            metrics = msg.get("metrics")
            if not isinstance(metrics, dict):
                metrics = {}
            target = metrics.get("target")
            if target not in FEATURES:
                return self._reject(name, f"model_schema: metrics.target {str(target)[:40]!r} is not one of "
                                          f"{tuple(FEATURES)}")
            cur = self.live.get(target)
            if cur is not None and msg.get("version") == cur.version and msg.get("checksum") == cur.checksum:
                self.sets["received"] += 1
                self.sets["duplicate"] += 1
                return None, "duplicate"
            n_out = len(OUTPUTS[target])
            try:
                ps = paramset.validate(msg, live_version=None if cur is None else cur.version,
                                       n_in=len(FEATURES[target]), n_out=n_out, name=name, verifier=self.verifier,
                                       signature=signature, max_version_step=self.max_version_step)
            except paramset.ParamSetRejected as e:
                return self._reject(name, f"model_{e.reason}: {e.detail}")
            except Exception as e:  # a map validate cannot read
                return self._reject(name, f"model_schema: {type(e).__name__}: {e}")
            sigma = ps.metrics.get("sigma")
            std = np.asarray(sigma, dtype=float).ravel() if isinstance(sigma, list) else np.zeros(0)
            if std.shape != (n_out,) or not np.all(np.isfinite(std)) or not np.all(std > 0):
                return self._reject(name, f"model_invalid_value: metrics.sigma must be {n_out} finite numbers > 0")
            seen = ps.metrics.get("samples_seen", -1)
            anfis = ps.kind == "anfis"
            new = LiveModel(ps.kind, name, target, ps.version, ps.checksum, ps.arrays, ps.norm,
                            tuple(float(s) for s in std), ps.n_in, seen if isinstance(seen, int) else -1,
                            context_gain=0.0 if anfis else float(ps.metrics["context_gain"]),
                            context=[] if anfis else [ps.arrays["context"].copy()])
            self.live[target] = new  # the swap: one reference store (module docstring)
            self.sets["received"] += 1
            self.sets["accepted"] += 1
            self._cv.notify_all()
        return new, ""

    def _reject(self, name: str, reason: str) -> tuple[None, str]:
        self.count_rejection(name, reason)
        return None, reason

    def trainer_progress(self, target: str, min_samples: int, set_through: int, through: int) -> None:
        """The trainer's progress on a target (its status counters, Learner.counters): a lockstep answer stops
        waiting for a set through n that will not come (n < min_samples, or set_through < n <= through)."""
        with self._cv:
            self._trainer[target] = (int(min_samples), int(set_through), int(through))
            self._cv.notify_all()

    def _no_set_coming(self, target: str, n: int) -> bool:
        m, s, t = self._trainer.get(target, (0, 0, 0))
        return n < m or s < n <= t

    # ------------------------------------------------------------------ queries
    def answer(self, target: str, features, n_samples: int | None = None,
               wait_s: float = 0.0) -> tuple[np.ndarray, tuple, LiveModel] | str:
        """(value, 1-sigma, model) for a query, or the reason it is refused (counted; module docstring)."""
        if wait_s > 0.0 and n_samples is not None:
            with self._cv:
                ok = self._cv.wait_for(lambda: ((m := self.live.get(target)) is not None
                                                and m.samples_seen >= n_samples)
                                       or self._no_set_coming(target, n_samples), wait_s)
            if not ok:
                self.queries["late_model"] += 1
        model = self.live.get(target)  # read once: the whole answer comes from this one version
        x = np.asarray(features, dtype=float)
        if model is None:
            return self._refuse("no_model")
        if x.shape != (model.n_in,):
            return self._refuse("bad_features")
        if anfis_numpy.domain_excess(model.norm, x) > self.max_domain_excess:
            return self._refuse("off_domain")
        y = model.forward(x)
        if not np.all(np.isfinite(y)):
            return self._refuse("nonfinite")
        self.queries["answered"] += 1
        return y, model.std, model

    def _refuse(self, reason: str) -> str:
        self.queries[reason] += 1
        return reason

    # ------------------------------------------------------------------ status
    def describe(self) -> str:
        live = dict(self.live)
        return ", ".join(f"{t}: {m.name} v{m.version}" for t, m in sorted(live.items())) or "no model"

    def counters(self) -> dict[str, int]:
        """sets_<received|accepted|duplicate|rejected>, rejected_<reason>, queries_<answered|late_model|refusal>,
        live_version_<target>."""
        c = {f"sets_{k}": v for k, v in dict(self.sets).items()}
        c.update({f"rejected_{k}": v for k, v in dict(self.rejected).items()})
        c.update({f"queries_{k}": v for k, v in dict(self.queries).items()})
        c.update({f"live_version_{t}": m.version for t, m in dict(self.live).items()})
        return c
