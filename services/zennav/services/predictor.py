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

Signatures (zennav.learn.signing): with --verify-key (default ZENNAV_VERIFY_KEY) every set must carry the
trainer's Ed25519 signature of its checksum (reasons model_unsigned, model_bad_signature), and a version more
than --max-version-step above the live one is refused (model_version_ahead): a set far ahead would block every
legitimate set after it. Without a key the predictor does not start, unless --allow-unsigned (development only:
no signature is checked, the status detail says UNSIGNED SETS ACCEPTED).

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
import os
import sys
import time

from zennav import messages as M
from zennav.learn.settings import LearnSettings
from zennav.learn.signing import Verifier
from zennav.nodes.predictor import PredictorNode
from zennav.service import ArgumentParser, ServiceRunner, add_bus_args


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="zennav-predictor", description="zennav predictor service: live ANFIS "
                       "parameter sets (numpy), validated hot swap, answers learn/query")
    p.add_argument("--queue", type=int, default=4096, help="query queue capacity (back-pressure beyond)")
    p.add_argument("--no-fetch", action="store_true", help="do not ask for the latest parameter sets at start")
    p.add_argument("--max-domain-excess", type=float, default=LearnSettings().max_domain_excess,
                   help="answer only queries within this many training standard deviations of the training range")
    p.add_argument("--lockstep", action="store_true", help="answer a query only with a set trained through its "
                   "n_samples, waiting for it (a replay of a recording; not for live vehicles)")
    p.add_argument("--lockstep-timeout", type=float, default=120.0,
                   help="longest wait [s] for that set; then the query counts as late_model and gets the live set")
    p.add_argument("--verify-key", default=os.environ.get("ZENNAV_VERIFY_KEY"),
                   help="the trainer's Ed25519 public key (PEM, `zennav keys DIR`; default ZENNAV_VERIFY_KEY): "
                        "only sets signed with its private key are taken")
    p.add_argument("--allow-unsigned", action="store_true",
                   help="development only: take sets without checking any signature (needed when no key is given)")
    p.add_argument("--max-version-step", type=int, default=1000,
                   help="refuse a set whose version is more than this above the live one")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    verifier = None
    if not args.allow_unsigned:
        if not args.verify_key:
            raise SystemExit("zennav-predictor: no --verify-key (the trainer's public key, `zennav keys DIR`); "
                             "--allow-unsigned takes unsigned sets (development only)")
        try:
            verifier = Verifier.from_file(args.verify_key)
        except ValueError as e:
            raise SystemExit(f"zennav-predictor: {e}") from None
    if args.max_version_step < 1:
        raise SystemExit("zennav-predictor: --max-version-step must be >= 1")
    run = ServiceRunner("predictor", args, serial=False)  # queries must not wait for a set's validation
    if verifier is None:
        run.log.warning("--allow-unsigned: parameter sets are taken without a signature check (development only)")
    k = run.keys
    bus = run.bus
    out = bus.publisher(k.learn_correction())
    node = PredictorNode(out.put, run.log, bus_reject=bus.count_rejected, on_change=lambda d: setattr(run, "detail", d),
                         max_domain_excess=args.max_domain_excess,
                         lockstep_timeout_s=args.lockstep_timeout if args.lockstep else 0.0, verifier=verifier,
                         max_version_step=args.max_version_step)
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
    # recovering: a restarted predictor fetches the queries it missed from the ins's cache (a lockstep ins waits)
    bus.recovering_subscribe(k.learn_query(), lambda key, msg, recv_ns: node.on_query(msg), channel="fifo",
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
