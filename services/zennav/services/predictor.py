"""predictor service (ARCHITECTURE.md section 3): the predictor core of the learning loop on the bus
(zennav.learn.predictor_core.PredictorCore, the same one the in-process loop of `zennav replay --compensation`
runs): holds the live parameter set of each target variant, an ANFIS or an Elman network (numpy only: this process
never imports torch), swaps in a validated newer one atomically between two queries, and answers every learn/query
with the prediction, its 1-sigma and the model version used, or refuses it with a counted reason.

Wiring table
    subscribes <base>/learn/model/*     model_params (the wire form of zennav.learn.paramset; validated, below)
               <base>/learn/query       learn_query from the ins while GNSS is lost
               <base>/nav/status        GNSS state (shown in the status; queries come only during outages)
    publishes  <base>/learn/correction  one correction per query: t_ns and kind of the query, value (the
                                        target's outputs, zennav.nav.learning.OUTPUTS) and std = the set's
                                        metrics.sigma per output, model name and version, query_src/query_seq
                                        (the query's header); or, refused, the reason (value and std empty)
               <base>/svc/predictor/status   live versions, sets received / accepted / duplicate / rejected per
                                        reason, last rejection, swap latency percentiles, queries answered,
                                        refused per reason (no_model, bad_features, off_domain, nonfinite), late

Validation of a parameter set (the first failure rejects it, with its reason counted, logged, put in the status
and in the bus's rejected map, and the live set stays): the bus schema (decode, header, fields, finite numbers,
array shape vs data length: codes decode_error, bad_shape, not_finite, ...), then PredictorCore.offer (target,
zennav.learn.paramset.validate with the key's name, metrics.sigma: codes model_<reason>). A set equal to the live
one (e.g. the late-joiner reply and the publication both arriving) is counted as a duplicate, not a rejection.

Lockstep (--lockstep; a replay of a recording, e.g. the demo; not for live vehicles): a query is answered only
with a set trained through at least its n_samples (metrics.samples_seen); the query thread waits for it up to
--lockstep-timeout seconds, then counts late_model and answers with the live set (or refuses: no_model). It stops
waiting early when the trainer's status (<base>/svc/trainer/status, subscribed with --lockstep) says that no set
through n will come (n below its min_samples, or a fit point at n without a set). With the
ins's --lockstep (it waits for each answer before its next sensor sample) and the trainer's --torch-threads 1 on
the CPU, the answers are those of the in-process loop, bit for bit.

Atomic swap: validation runs on the model subscription's thread (the bus is not serial here), outside anything a
query takes; the swap is one reference store, so every answer is the forward pass of exactly one version, the one
it names, and no query waits for a validation (outside lockstep).
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import deque

import numpy as np

from zennav import messages as M
from zennav.learn.predictor_core import PredictorCore
from zennav.learn.settings import LearnSettings
from zennav.messages.learn import refusal_msg
from zennav.nav.learning import FEATURES
from zennav.service import ServiceRunner, add_bus_args


def _pct(values, q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else 0.0


class PredictorNode:
    """The transport-free part of the predictor: ``on_model(key, msg, recv_ns)`` with bus-valid model_params
    messages (``reject(key, reason)`` for bus-invalid ones), ``on_query(msg)`` with learn_query messages; answers
    go to ``publish(msg)``. on_model may run concurrently with on_query (see the module docstring)."""

    def __init__(self, publish, log, bus_reject=None, on_change=None, max_domain_excess: float = 0.5,
                 lockstep_timeout_s: float = 0.0):
        self.publish = publish
        self.log = log
        self.core = PredictorCore(max_domain_excess)
        self.wait_s = float(lockstep_timeout_s)  # > 0: lockstep
        self.bus_reject = bus_reject or (lambda key, reason: None)
        self.on_change = on_change or (lambda detail: None)
        self.swap_latency_ns: deque = deque(maxlen=10_000)  # publisher put -> live (same-host clocks)
        self.validate_ns: deque = deque(maxlen=10_000)  # received -> live
        self.gnss_state = "unknown"

    @property
    def live(self):
        return self.core.live

    # ------------------------------------------------------------------ parameter sets
    def reject(self, key: str, reason: str, bus_counted: bool = True) -> None:
        """Count and log a set rejected by the bus's check; reason 'code: detail'."""
        self.core.count_rejection(key.rsplit("/", 1)[-1], reason)
        self._rejected(key, reason, bus_counted)

    def _rejected(self, key: str, reason: str, bus_counted: bool) -> None:
        self.log.warning("parameter set on %s rejected (%s); the live set stays: %s", key, reason.split(":", 1)[0],
                         self.core.describe())
        if not bus_counted:
            self.bus_reject(key, reason)
        self.on_change(self.detail())

    def on_model(self, key: str, msg: dict, recv_ns: int, latency: bool = True) -> bool:
        """Validate a model_params message and swap it in; False when rejected (or a duplicate)."""
        name = key.rsplit("/", 1)[-1]
        target = (msg.get("metrics") or {}).get("target")
        cur = self.core.live.get(target) if isinstance(target, str) else None
        try:
            ps = M.paramset_of(msg)
        except Exception as e:  # a map paramset_of cannot read
            self.core.count_rejection(name, f"model_schema: {type(e).__name__}: {e}")
            self._rejected(key, f"model_schema: {type(e).__name__}: {e}", False)
            return False
        new, reason = self.core.offer(name, ps)
        if new is None:
            if reason != "duplicate":
                self._rejected(key, reason, False)
            return False
        now = time.time_ns()
        if latency:
            self.swap_latency_ns.append(now - msg["pub_ns"])
            self.validate_ns.append(now - recv_ns)
        self.log.info("live %s: %s v%d through %d samples (was %s), 1-sigma %s", new.target, name, new.version,
                      new.samples_seen, "none" if cur is None else f"v{cur.version}", [round(s, 4) for s in new.std])
        self.on_change(self.detail())
        return True

    # ------------------------------------------------------------------ queries
    def on_query(self, msg: dict) -> dict:
        """Answer one learn_query: the correction, or the refusal with its reason (counted); published and
        returned."""
        out = self.core.answer(msg["target"], msg["features"], msg.get("n_samples"), self.wait_s)
        if isinstance(out, str):
            ans = refusal_msg(msg, out)
        else:
            y, std, model = out
            ans = M.correction_msg(msg, y, std, model.name, model.version)
        self.publish(ans)
        return ans

    def on_trainer_status(self, msg: dict) -> None:
        """The trainer's status: its progress per target (lockstep, zennav.learn.predictor_core)."""
        c = msg["counters"]
        for t in FEATURES:
            if f"through_{t}" in c:
                self.core.trainer_progress(t, c.get(f"min_samples_{t}", 0), c.get(f"set_through_{t}", 0),
                                           c[f"through_{t}"])

    def on_nav_status(self, msg: dict) -> None:
        self.gnss_state = msg["gnss_state"]

    # ------------------------------------------------------------------ status
    def detail(self) -> str:
        d = f"live {self.core.describe()}; GNSS {self.gnss_state}" + ("; lockstep" if self.wait_s > 0 else "")
        last = self.core.last_rejection
        return d + (f"; last rejected {last}" if last else "")

    def counters(self) -> dict:
        lat = list(self.swap_latency_ns)
        val = list(self.validate_ns)
        return {**self.core.counters(), "swaps": len(lat), "swap_p50_us": round(_pct(lat, 50) / 1e3, 1),
                "swap_p99_us": round(_pct(lat, 99) / 1e3, 1), "swap_max_us": round(max(lat, default=0) / 1e3, 1),
                "validate_p99_us": round(_pct(val, 99) / 1e3, 1), "torch_imported": int("torch" in sys.modules)}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-predictor", description="zennav predictor service: live ANFIS "
                                "parameter sets (numpy), validated hot swap, answers learn/query")
    p.add_argument("--queue", type=int, default=4096, help="query queue capacity (back-pressure beyond)")
    p.add_argument("--no-fetch", action="store_true", help="do not ask for the latest parameter sets at start")
    p.add_argument("--max-domain-excess", type=float, default=LearnSettings().max_domain_excess,
                   help="answer only queries within this many training standard deviations of the training range")
    p.add_argument("--lockstep", action="store_true", help="answer a query only with a set trained through its "
                   "n_samples, waiting for it (a replay of a recording; not for live vehicles)")
    p.add_argument("--lockstep-timeout", type=float, default=120.0,
                   help="longest wait [s] for that set; then the query counts as late_model and gets the live set")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("predictor", args, serial=False)  # queries must not wait for a set's validation
    k = run.keys
    bus = run.bus
    out = bus.publisher(k.learn_correction())
    node = PredictorNode(out.put, run.log, bus_reject=bus.count_rejected, on_change=lambda d: setattr(run, "detail", d),
                         max_domain_excess=args.max_domain_excess,
                         lockstep_timeout_s=args.lockstep_timeout if args.lockstep else 0.0)
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
    if args.lockstep:
        bus.subscribe(k.svc_status("trainer"), lambda key, msg, recv_ns: node.on_trainer_status(msg), channel="ring",
                      capacity=16, name="trainer_status")
    if not args.no_fetch:  # late joiner: the latest set of each model (duplicates of a publication are ignored)
        for key, msg in bus.get_latest(k.learn_model(), timeout=2.0):
            node.on_model(key, msg, time.time_ns(), latency=False)
    return run.serve("running", node.detail())


if __name__ == "__main__":
    sys.exit(main())
