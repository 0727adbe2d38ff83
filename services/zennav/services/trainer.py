"""trainer service (ARCHITECTURE.md sections 3 and 5): the learner of the learning loop on the bus. It collects
the ins's training samples per target variant, fits on the schedule of zennav.learn.learner (the same Learner, with
the same LearnSettings defaults, that the in-process loop of `zennav replay --compensation` runs) and publishes
versioned parameter sets. --model anfis (default): ANFIS on the newest --window samples, premises by hybrid LSE +
Fletcher-Reeves CG (--optimizer cg, seed 000) or particle swarm (--optimizer pso, seed 003). --model elman (seed
002): an Elman network learns online from every sample, in order; its state is published once its training error
is under its threshold. ANFIS fits run in the trainer's fit worker (zennav.learn.fit_worker: a child process, the
only zennav process that imports torch), on the GPU when torch sees one (--device cpu and --torch-threads 1 for
sets equal, bit for bit, to the in-process loop's).

Wiring table
    subscribes <base>/learn/samples        learn_sample from the ins (variants outside --targets, and samples of the
                                           wrong size, are counted and ignored)
               <base>/learn/query          learn_query from the ins: its n_samples asks for a set trained through
                                           exactly that many samples of its variant (queries without it are counted)
    publishes  <base>/learn/model/<name>   model_params, the wire form of a zennav.learn.paramset set (name
                                           <prefix>-<target>, e.g. anfis-drift; the latest is served to late
                                           joiners by the publisher's queryable)
               <base>/svc/trainer/status   per target: samples, sets published and their last version, the last fit
                                           point, fit points without a set (elman not ready, fit errors), requests;
                                           link losses, device

Schedule, in data terms only (zennav.learn.learner): at --min-samples, every --retrain-samples and at each query's
n_samples, each fit on exactly its first n samples, on its own thread (metrics carry samples_seen, RMSE, sigma).

Versions: +1 per set and model name, persisted in --state-dir (default ZENNAV_STATE_DIR) and continued above the
latest set found on the bus at start (else from --first-version): see zennav.nodes.trainer.

Signatures: every set carries an Ed25519 signature of its checksum by --signing-key (default ZENNAV_SIGNING_KEY;
`zennav keys DIR` makes a pair); the predictor holds the public key. Without a key the trainer does not start,
unless --unsigned (development only).

Stopping: SIGTERM or SIGINT stops the trainer within seconds even mid-fit: the fit worker is terminated (the fit
is lost; nothing is published), the training thread ends, the session closes, exit code 0.

Remote deployment: run it as a zenoh client of the edge router (``--mode client --connect tcp/<edge>:7447``,
deploy/zenoh-client.json5: waits for the router, reconnects for ever). When the link drops the trainer keeps
running and keeps its samples (none arrive meanwhile); the edge keeps predicting with the last set. On
reconnection (seen as the router reappearing in the session's info) it re-publishes its latest set of each
model, so a set trained during the cut is not lost; the next fit then follows the schedule.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading

from zennav.learn.fit_worker import FitWorker
from zennav.learn.settings import MODELS, OPTIMIZERS, LearnSettings
from zennav.learn.signing import Signer
from zennav.nav.learning import TARGETS
from zennav.nodes.trainer import ModelPublishers, TrainerNode, VersionFile, train_loop
from zennav.service import ArgumentParser, ServiceRunner, add_bus_args

DEFAULTS = LearnSettings()


def build_parser() -> argparse.ArgumentParser:
    d = DEFAULTS
    p = ArgumentParser(prog="zennav-trainer", description="zennav trainer service: ANFIS (premises by "
                       "hybrid LSE + Fletcher-Reeves CG or PSO) or online Elman on the ins's samples, "
                       "versioned parameter sets; defaults: zennav.learn.settings.LearnSettings")
    p.add_argument("--model", default=d.model, choices=MODELS, help="anfis: fitted on the newest samples; "
                   "elman: learns online from every sample (seed 002)")
    p.add_argument("--optimizer", default=d.optimizer, choices=OPTIMIZERS,
                   help="anfis premises: cg (hybrid LSE + Fletcher-Reeves CG, seed 000), pso (seed 003) or ipso "
                   "(seed 003's improved swarm: inertia 0.9 -> 0.4, c1 2.5 -> 0.5, c2 0.5 -> 2.5)")
    p.add_argument("--targets", default="body_velocity",
                   help=f"comma-separated target variants to learn ({', '.join(TARGETS)})")
    p.add_argument("--prefix", default=None, help="model name prefix (default: --model): sets are published as "
                   "<prefix>-<target>")
    p.add_argument("--window", type=int, default=None, help="anfis: newest samples a fit uses; elman: its sliding "
                   "window (default: the model's, zennav.learn.settings.WINDOW)")
    p.add_argument("--min-samples", type=int, default=None, help="no set below this many samples (default: the "
                   "model's, zennav.learn.settings.MIN_SAMPLES)")
    p.add_argument("--retrain-samples", type=int, default=d.retrain_samples,
                   help="a scheduled fit every this many samples")
    p.add_argument("--n-rules", type=int, default=d.n_rules, help="ANFIS rules (k-means rule base)")
    p.add_argument("--max-epochs", type=int, default=d.max_epochs, help="ANFIS epochs per fit (LSE + FR-CG, or swarm "
                   "iterations)")
    p.add_argument("--val-patience", type=int, default=d.val_patience,
                   help="ANFIS epochs (--optimizer cg) chosen by early stopping on a validation split, this many "
                        "epochs past the best (0: --max-epochs always)")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--device", default=None, help="torch device (default: cuda when torch sees one, else cpu)")
    p.add_argument("--torch-threads", type=int, default=d.torch_threads,
                   help="torch CPU threads during a fit (1: the in-process loop's sets, bit for bit; 0: torch's "
                        "default)")
    p.add_argument("--first-version", type=int, default=1, help="version of the first set if none is found on the bus")
    p.add_argument("--signing-key", default=os.environ.get("ZENNAV_SIGNING_KEY"),
                   help="Ed25519 private key (PEM, `zennav keys DIR`; default ZENNAV_SIGNING_KEY) that signs every set")
    p.add_argument("--unsigned", action="store_true", help="development only: publish sets without a signature")
    p.add_argument("--state-dir", default=os.environ.get("ZENNAV_STATE_DIR"),
                   help="directory of the last published versions (default ZENNAV_STATE_DIR): they survive a restart")
    p.add_argument("--link-poll", type=float, default=0.5, help="period [s] of the link (router/peer) check")
    p.add_argument("--close-timeout", type=float, default=3.0, help="longest wait [s] for the session to close")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    if not targets or not set(targets) <= set(TARGETS):
        raise SystemExit(f"zennav-trainer: --targets: choose from {TARGETS}")
    try:
        settings = LearnSettings(model=args.model, optimizer=args.optimizer, window=args.window,
                                 min_samples=args.min_samples, retrain_samples=args.retrain_samples,
                                 n_rules=args.n_rules, max_epochs=args.max_epochs, val_patience=args.val_patience,
                                 seed=args.seed, torch_threads=args.torch_threads)
        signer = None if args.unsigned else Signer.from_file(args.signing_key) if args.signing_key else None
        versions = VersionFile(args.state_dir) if args.state_dir else None
    except (ValueError, OSError) as e:
        raise SystemExit(f"zennav-trainer: {e}") from None
    if signer is None and not args.unsigned:
        raise SystemExit("zennav-trainer: no --signing-key (`zennav keys DIR` makes one); --unsigned publishes "
                         "unsigned sets (development only)")
    run = ServiceRunner("trainer", args, serial=False)
    if signer is None:
        run.log.warning("--unsigned: parameter sets are published without a signature (development only)")
    if versions is None:
        run.log.warning("no --state-dir: versions continue only above a set still served on the bus")
    worker = FitWorker(settings.torch_threads) if settings.model == "anfis" else None
    try:  # the worker starts now, from the main thread (its parent-death signal follows that thread)
        device = worker.device() if worker else "cpu"
    except RuntimeError as e:
        return run.fail(f"fit worker: {e}")
    device = args.device or device
    k = run.keys
    bus = run.bus
    models = ModelPublishers(bus, run.log)
    node = TrainerNode(models.publish, run.log, targets, settings, prefix=args.prefix, device=device,
                       first_version=args.first_version, signer=signer, versions=versions, fitter=worker)
    for t, name in node.names.items():  # continue the version numbering of a set already on the bus
        for _key, msg in bus.get_latest(k.learn_model(name), timeout=2.0):
            if msg["name"] == name:
                node.seen_version(t, msg["version"])
    run.describe = node.detail  # its sets, and "fitting ..." while a fit runs
    run.counters = lambda: {**node.counters(), **models.counters()}
    bus.subscribe(k.learn_samples(), lambda key, msg, recv_ns: node.on_sample(msg), channel="fifo", capacity=8192,
                  name="samples")
    bus.subscribe(k.learn_query(), lambda key, msg, recv_ns: node.on_query(msg), channel="fifo", capacity=8192,
                  name="query")
    threads = [threading.Thread(target=models.watch, args=(run, args.link_poll, node.received),
                                name="zennav-watch_link", daemon=True),
               threading.Thread(target=train_loop, args=(run, node), name="zennav-train_loop", daemon=True)]
    for th in threads:
        th.start()
    run.ready("running", node.detail())
    try:
        run.wait()
    finally:
        run.stop()
        if worker is not None:
            if node.busy:
                run.log.info("stopping: %s interrupted", node.busy)
            worker.close()  # a fit in progress ends now: the training thread gets its error and stops
        with node.cv:
            node.cv.notify_all()
        threads[1].join(args.close_timeout)
        # a client whose router is unreachable can block in the zenoh session's close (it is reconnecting): bound it
        closer = threading.Thread(target=run.close, name="zennav-close", daemon=True)
        closer.start()
        closer.join(args.close_timeout)
        if closer.is_alive():
            run.log.warning("zenoh session close still blocked after %.0f s (link down?); exiting anyway",
                            args.close_timeout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
