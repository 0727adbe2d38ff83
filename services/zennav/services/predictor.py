"""predictor service (issue 6, DESIGN.md section 5): holds the live parameter set of each target variant, an ANFIS
or an Elman network (numpy only: this process never imports torch), swaps in a validated newer one atomically
between two queries, and answers every learn/query with the prediction, its 1-sigma and the model version used.
An Elman set carries its context; the predictor advances that context with every query it answers (as the network
does at the edge in seed 002) and starts again from the set's own context when a new set is swapped in.

Wiring table
    subscribes <base>/learn/model/*     model_params (the wire form of zennav.learn.paramset; validated, below)
               <base>/learn/query       learn_query from the ins while GNSS is lost
               <base>/nav/status        GNSS state (shown in the status; queries come only during outages)
    publishes  <base>/learn/correction  one correction per answered query: t_ns and kind of the query, value
                                        (the target's outputs, zennav.nav.learning.OUTPUTS) and std = the set's
                                        metrics.sigma per output, model name and version, query_src/query_seq
                                        (the query's header)
               <base>/svc/predictor/status   live versions, sets accepted/rejected per reason, last rejection,
                                        swap latency percentiles, queries answered / without a model

Validation of a parameter set (in this order; the first failure rejects it, with its reason counted, logged,
put in the status and in the bus's rejected map, and the live set stays): the bus schema (decode, header,
fields, finite numbers, array shape vs data length: codes decode_error, bad_shape, not_finite, ...); the
target variant in metrics.target; zennav.learn.paramset.validate: schema (format, fields, name equal to the
key's <name>), checksum (sha256 over the set, computed by the trainer), shapes (n_in = the target's feature
count, n_out = the target's output count), finite values, value ranges, version newer than the live one of that
target (codes model_<reason> in the rejected map); a finite positive metrics.sigma per output (the 1-sigma of a
prediction; see zennav.compensation for how each model's is measured). A set equal to the
live one (same version and checksum, e.g. the late-joiner reply and the publication both arriving) is counted
as a duplicate, not a rejection.

Domain: a query whose features lie outside the live set's training range by more than --max-domain-excess
training standard deviations (anfis_numpy.domain_excess) is not answered (counted as off_domain): a first-order
Takagi-Sugeno model extrapolates linearly there, without bound, and the ins then runs on its own INS.

Atomic swap: the live sets are immutable objects (read-only arrays) in a dict keyed by target; validation runs
on the model subscription's thread, outside any lock the queries take, and the swap is one reference store. A
query (on its own thread) reads the reference once and computes the whole answer from that object, so every
answer is the forward pass of exactly one version, the one it names, and no query waits for a validation.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from collections.abc import Mapping

import numpy as np

from zennav import messages as M
from zennav.learn import anfis_numpy, elman, paramset
from zennav.nav.learning import FEATURES, OUTPUTS
from zennav.service import ServiceRunner, add_bus_args


@dataclass(frozen=True)
class LiveModel:
    """One validated parameter set in service; never mutated (a swap replaces the object), except an Elman's
    context, which only the query thread advances."""

    kind: str
    name: str
    target: str
    version: int
    checksum: str
    arrays: Mapping[str, np.ndarray]
    norm: Mapping[str, np.ndarray]
    std: tuple  # 1-sigma per output: the set's training RMSE (physical units)
    n_in: int
    swapped_ns: int
    context_gain: float = 0.0  # elman
    context: list = field(default_factory=list)  # elman: [context (n_hidden,)], advanced per answered query

    def forward(self, x: np.ndarray) -> np.ndarray:
        """The prediction (physical units) for features x (n_in,)."""
        if self.kind == "anfis":
            return anfis_numpy.predict(self.arrays, self.norm, x)
        y, self.context[0] = elman.step(self.arrays, self.norm, x, self.context[0], self.context_gain)
        return y


def _pct(values, q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else 0.0


class PredictorNode:
    """The transport-free part of the predictor: ``on_model(key, msg, recv_ns)`` with bus-valid model_params
    messages (``reject(key, reason)`` for bus-invalid ones), ``on_query(msg)`` with learn_query messages; answers
    go to ``publish(msg)``. on_model may run concurrently with on_query (see the module docstring)."""

    def __init__(self, publish, log, bus_reject=None, on_change=None, max_domain_excess: float = 0.5):
        self.publish = publish
        self.max_domain_excess = float(max_domain_excess)
        self.log = log
        self.bus_reject = bus_reject or (lambda key, reason: None)
        self.on_change = on_change or (lambda detail: None)
        self.live: dict[str, LiveModel] = {}
        self._model_lock = threading.RLock()  # serialises writers (subscription and late-joiner fetch); queries never take it
        self.sets: Counter[str] = Counter()  # received, accepted, duplicate, rejected
        self.rejected: Counter[str] = Counter()  # per reason
        self.last_rejection = ""
        self.swap_latency_ns: deque = deque(maxlen=10_000)  # publisher put -> live (same-host clocks)
        self.validate_ns: deque = deque(maxlen=10_000)  # received -> live
        self.queries: Counter[str] = Counter()  # answered, no_model, bad_features, off_domain, nonfinite (query thread)
        self.gnss_state = "unknown"

    # ------------------------------------------------------------------ parameter sets
    def reject(self, key: str, reason: str, bus_counted: bool = True) -> None:
        """Count and log a rejected set; reason 'code: detail'. bus_counted: already in the bus's rejected map."""
        code = reason.split(":", 1)[0]
        with self._model_lock:
            self.sets["received"] += 1
            self.sets["rejected"] += 1
            self.rejected[code] += 1
            self.last_rejection = f"{key.rsplit('/', 1)[-1]}: {reason}"[:300]
        self.log.warning("parameter set on %s rejected (%s); the live set stays: %s", key, code, self.describe())
        if not bus_counted:
            self.bus_reject(key, reason)
        self.on_change(self.detail())

    def on_model(self, key: str, msg: dict, recv_ns: int, latency: bool = True) -> bool:
        """Validate a model_params message and swap it in; False when rejected (or a duplicate)."""
        name = key.rsplit("/", 1)[-1]
        with self._model_lock:
            metrics = msg.get("metrics") or {}
            target = metrics.get("target")
            if target not in FEATURES:
                self.reject(key, f"model_schema: metrics.target {str(target)[:40]!r} is not one of {tuple(FEATURES)}",
                            False)
                return False
            cur = self.live.get(target)
            if cur is not None and msg["version"] == cur.version and msg["checksum"] == cur.checksum:
                self.sets["received"] += 1
                self.sets["duplicate"] += 1
                return False
            try:
                n_out = len(OUTPUTS[target])
                ps = paramset.validate(M.paramset_of(msg), live_version=None if cur is None else cur.version,
                                       n_in=len(FEATURES[target]), n_out=n_out, name=name)
            except paramset.ParamSetRejected as e:
                self.reject(key, f"model_{e.reason}: {e.detail}", False)
                return False
            except Exception as e:  # a map paramset_of cannot read
                self.reject(key, f"model_schema: {type(e).__name__}: {e}", False)
                return False
            sigma = ps.metrics.get("sigma")
            std = np.asarray(sigma, dtype=float).ravel() if isinstance(sigma, list) else np.zeros(0)
            if std.shape != (n_out,) or not np.all(np.isfinite(std)) or not np.all(std > 0):
                self.reject(key, f"model_invalid_value: metrics.sigma must be {n_out} finite numbers > 0", False)
                return False
            now = time.time_ns()
            extra = {} if ps.kind == "anfis" else dict(context_gain=float(ps.metrics["context_gain"]),
                                                       context=[ps.arrays["context"].copy()])
            new = LiveModel(ps.kind, name, target, ps.version, ps.checksum, ps.arrays, ps.norm,
                            tuple(float(s) for s in std), ps.n_in, now, **extra)
            self.live[target] = new  # the swap: one reference store (see the module docstring)
            self.sets["received"] += 1
            self.sets["accepted"] += 1
            if latency:
                self.swap_latency_ns.append(now - msg["pub_ns"])
                self.validate_ns.append(now - recv_ns)
        self.log.info("live %s: %s v%d (was %s), 1-sigma %s", target, name, ps.version,
                      "none" if cur is None else f"v{cur.version}", [round(s, 4) for s in new.std])
        self.on_change(self.detail())
        return True

    # ------------------------------------------------------------------ queries
    def on_query(self, msg: dict) -> dict | None:
        """Answer one learn_query (published and returned); None (counted) without a live model for its target."""
        model = self.live.get(msg["target"])  # read once: the whole answer comes from this one version
        if model is None:
            self.queries["no_model"] += 1
            return None
        x = np.asarray(msg["features"], dtype=float)
        if x.shape != (model.n_in,):
            self.queries["bad_features"] += 1
            return None
        if anfis_numpy.domain_excess(model.norm, x) > self.max_domain_excess:
            self.queries["off_domain"] += 1
            return None
        y = model.forward(x)
        if not np.all(np.isfinite(y)):
            self.queries["nonfinite"] += 1
            return None
        out = M.correction_msg(msg, y, model.std, model.name, model.version)
        self.publish(out)
        self.queries["answered"] += 1
        return out

    def on_nav_status(self, msg: dict) -> None:
        self.gnss_state = msg["gnss_state"]

    # ------------------------------------------------------------------ status
    def describe(self) -> str:
        live = dict(self.live)
        return ", ".join(f"{t}: {m.name} v{m.version}" for t, m in sorted(live.items())) or "no model"

    def detail(self) -> str:
        d = f"live {self.describe()}; GNSS {self.gnss_state}"
        return d + (f"; last rejected {self.last_rejection}" if self.last_rejection else "")

    def counters(self) -> dict:
        lat = list(self.swap_latency_ns)
        val = list(self.validate_ns)
        c = {f"sets_{k}": v for k, v in dict(self.sets).items()}
        c.update({f"rejected_{k}": v for k, v in dict(self.rejected).items()})
        c.update({f"queries_{k}": v for k, v in dict(self.queries).items()})
        c.update({f"live_version_{t}": m.version for t, m in dict(self.live).items()})
        c.update(swaps=len(lat), swap_p50_us=round(_pct(lat, 50) / 1e3, 1), swap_p99_us=round(_pct(lat, 99) / 1e3, 1),
                 swap_max_us=round(max(lat, default=0) / 1e3, 1), validate_p99_us=round(_pct(val, 99) / 1e3, 1),
                 torch_imported=int("torch" in sys.modules))
        return c


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-predictor", description="zennav predictor service: live ANFIS "
                                "parameter sets (numpy), validated hot swap, answers learn/query")
    p.add_argument("--queue", type=int, default=4096, help="query queue capacity (back-pressure beyond)")
    p.add_argument("--no-fetch", action="store_true", help="do not ask for the latest parameter sets at start")
    p.add_argument("--max-domain-excess", type=float, default=0.5,
                   help="answer only queries within this many training standard deviations of the training range")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("predictor", args, serial=False)  # queries must not wait for a set's validation
    k = run.keys
    bus = run.bus
    out = bus.publisher(k.learn_correction())
    node = PredictorNode(out.put, run.log, bus_reject=bus.count_rejected, on_change=lambda d: setattr(run, "detail", d),
                         max_domain_excess=args.max_domain_excess)
    validator = M.Validator()

    def on_model(key, payload, recv_ns):  # raw bytes: bus-invalid sets are parameter-set rejections too
        msg, reason = validator.check(key, payload)
        if msg is None:
            bus.count_rejected(key, reason)
            node.reject(key, reason, bus_counted=True)
            return
        node.on_model(key, msg, recv_ns)

    run.counters = node.counters
    bus.subscribe(k.learn_model(), on_model, validate=False, channel="fifo", capacity=256, name="model")
    bus.subscribe(k.learn_query(), lambda key, msg, recv_ns: node.on_query(msg), channel="fifo",
                  capacity=args.queue, name="query")
    bus.subscribe(k.nav_status(), lambda key, msg, recv_ns: node.on_nav_status(msg), channel="ring", capacity=4,
                  name="nav_status")
    if not args.no_fetch:  # late joiner: the latest set of each model (duplicates of a publication are ignored)
        for key, msg in bus.get_latest(k.learn_model(), timeout=2.0):
            node.on_model(key, msg, time.time_ns(), latency=False)
    return run.serve("running", node.detail())


if __name__ == "__main__":
    sys.exit(main())
