"""Outage benchmark of learned INS-error compensation on real data (issue 6).

Per window length and compensation (none = pure INS, anfis = ANFIS with FR-CG premises, anfis-pso, elman: the
in-process learning loop of zennav.learn.loop with the default LearnSettings, the trainer's and predictor's), prints
the RMS and the maximum over windows of the per-window maximum horizontal drift, scored against the withheld
reference positions, and the change of that RMS against pure INS.

rtklibexplorer (one 500 s drive, --dataset rtklibexplorer): GNSS is withheld in windows of 10, 30 and 60 s, the
first after an initial training period (--train-s) and then one every window length plus --gap-s of GNSS in
between; the model learns online from the drive itself (samples while GNSS is good, prediction in the windows).
`zennav replay rtklibexplorer --outage-every 90:30:120 --compensation elman --target body_velocity` is one row.

ansfl (61 quadrotor flights of 11-55 s, --dataset ansfl): one flight is too short to train on, so the model learns
across flights: the flights are split in two folds (odd and even path numbers of each group); a model trained on
the samples of every flight of one fold (full GNSS, learning from --learn-after-s) predicts, frozen, in the
outage windows of the other fold's flights; each flight long enough gets one window starting at
max(--first-s, min(half the flight, its end minus the window)). 30 s windows fit only 9 flights (>= 40 s); 60 s
none.

    .venv/bin/python benchmarks/outage_learning.py [--dataset rtklibexplorer|ansfl] [--target body_velocity]
        [--windows 10,30,60] [--seeds 0,1,2]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from zennav.datasets.registry import ansfl_specs, load_dataset
from zennav.learn.loop import CHOICES, make_compensator, training_set
from zennav.metrics import evaluate
from zennav.nav.learning import TARGETS, LearnSample
from zennav.nav.navigator import Navigator
from zennav.progress import Progress
from zennav.replay import run_replay

HEADER = (f"{'window':>7}{'compensation':>14}{'windows':>9}{'RMS of max m':>14}{'max m':>9}{'vs INS':>9}"
          f"{'answered':>10}{'wall s':>8}")


def _row(length: float, label: str, drifts: list[float], base: float | None, answered: int, wall: float) -> float:
    """Print one row; returns its RMS of the per-window maxima (base: pure INS's, None for pure INS itself)."""
    d = np.asarray(drifts, dtype=float)
    rms, mx = float(np.sqrt(np.mean(d**2))), float(d.max())
    base = rms if base is None else base
    print(f"{length:>6.0f}s{label:>14}{len(d):>9}{rms:>14.2f}{mx:>9.2f}{100.0 * (rms - base) / base:>8.0f}%"
          f"{answered:>10}{wall:>8.1f}", flush=True)
    return rms


def _runs(seeds: list[int]):
    """(model, seed, label) of each row: pure INS once, each learned model once per seed."""
    for model in CHOICES:
        for seed in seeds if model != "none" else [0]:
            yield model, seed, model if len(seeds) == 1 or model == "none" else f"{model} s{seed}"


def _median_row(length: float, model: str, rms: list[float], base: float, seeds: list[int]) -> None:
    if len(seeds) > 1 and model != "none":
        m = float(np.median(rms))
        print(f"{length:>6.0f}s{model + ' median':>14}{'':>9}{m:>14.2f}{'':>9}{100.0 * (m - base) / base:>8.0f}%",
              flush=True)


def _answered(res) -> int:
    return sum(1 for r in res.reports if r.source.startswith("learned_"))


def drive(args) -> None:
    ds = load_dataset(args.dataset)
    if ds.truth is None:
        raise SystemExit(f"{ds.name} has no truth to score the drift against")
    print(f"{ds.name}: first window after {args.train_s:g} s, {args.gap_s:g} s of GNSS between windows; "
          f"learned target: {args.target}; reference: {ds.truth.source}")
    print(HEADER)
    for length in (float(x) for x in args.windows.split(",")):
        every = (length + args.gap_s, length, args.train_s)
        base: float | None = None
        rms: dict[str, list[float]] = {}
        for model, seed, label in _runs(args.seeds):
            t0 = time.perf_counter()
            progress = Progress.of_replay(ds, f"{length:g} s windows, {label}")
            res = run_replay(ds, outage_every=every, compensator=make_compensator(model, args.target, seed),
                             on_epoch=progress.on_epoch)
            progress.close()
            m = evaluate(ds, res)
            rms.setdefault(model, []).append(_row(length, label, [w["max_horizontal_m"] for w in m["outages"]], base,
                                                  _answered(res), time.perf_counter() - t0))
            base = rms["none"][0]
            if seed == args.seeds[-1]:
                _median_row(length, model, rms[model], base, args.seeds)


class Frozen:
    """A trained compensator that predicts but learns nothing more (the held-out flights' own samples are not
    used: the model is the other fold's)."""

    def __init__(self, comp):
        self.comp = comp

    def add(self, samples) -> None:
        pass

    def predict(self, query):
        return self.comp.predict(query)


def quadrotor(args) -> None:
    flights = {spec: load_dataset(spec) for spec in ansfl_specs()}
    length_s = {spec: (ds.imu.t_ns[-1] - ds.initial.t_ns) / 1e9 for spec, ds in flights.items()}
    folds = [[s for s in flights if int(s.rsplit("_", 1)[1]) % 2 == k] for k in (1, 0)]
    print(f"ANSFL quadrotor: {len(flights)} flights, 2 folds (odd / even path numbers); learned target "
          f"{args.target}; learning from {args.learn_after_s:g} s of each training flight; reference: the DJI RTK "
          f"positions withheld in the window")
    samples = {}
    t0 = time.perf_counter()
    for spec, ds in flights.items():
        nav = Navigator(ds.config.with_(learning=True, learn_after_s=args.learn_after_s), ds.initial)
        x, y, t = training_set(ds, args.target, navigator=nav)
        samples[spec] = [LearnSample(int(ti), args.target, xi, yi) for xi, yi, ti in zip(x, y, t)]
    print(f"training samples per fold: {[sum(len(samples[s]) for s in f) for f in folds]} "
          f"({time.perf_counter() - t0:.0f} s)")
    print(HEADER)
    for length in (float(x) for x in args.windows.split(",")):
        starts = {s: max(args.first_s, min(0.5 * length_s[s], length_s[s] - length)) for s in flights}
        tests = {s: ds for s, ds in flights.items() if length_s[s] >= starts[s] + length}
        if not tests:
            print(f"{length:>6.0f}s  no flight is long enough")
            continue
        base: float | None = None
        rms: dict[str, list[float]] = {}
        for model, seed, label in _runs(args.seeds):
            t0 = time.perf_counter()
            drifts, answered = [], 0
            for k, fold in enumerate(folds):
                comp = make_compensator(model, args.target, seed)  # None for 'none'
                if comp is not None:
                    comp.add([smp for s in folds[1 - k] for smp in samples[s]])
                for spec in (s for s in fold if s in tests):
                    ds, start = tests[spec], starts[spec]
                    nav = Navigator(ds.config.with_(learning=True, learn_after_s=args.learn_after_s), ds.initial)
                    res = run_replay(ds, outages=[(start, length)], navigator=nav,
                                     compensator=Frozen(comp) if comp is not None else None)
                    drifts += [w["max_horizontal_m"] for w in evaluate(ds, res)["outages"]]
                    answered += _answered(res)
            rms.setdefault(model, []).append(_row(length, label, drifts, base, answered, time.perf_counter() - t0))
            base = rms["none"][0]
            if seed == args.seeds[-1]:
                _median_row(length, model, rms[model], base, args.seeds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="rtklibexplorer", choices=("rtklibexplorer", "ansfl"))
    ap.add_argument("--target", default="body_velocity", choices=TARGETS)
    ap.add_argument("--windows", default=None, help="window lengths [s] (default 10,30,60; ansfl 10,30)")
    ap.add_argument("--train-s", type=float, default=120.0, help="rtklibexplorer: GNSS before the first window [s]")
    ap.add_argument("--gap-s", type=float, default=60.0, help="rtklibexplorer: GNSS between windows [s]")
    ap.add_argument("--first-s", type=float, default=10.0, help="ansfl: earliest window start in a flight [s]")
    ap.add_argument("--learn-after-s", type=float, default=3.0,
                    help="ansfl: samples from this long after the start of a training flight [s]")
    ap.add_argument("--seeds", default="0", type=lambda v: [int(x) for x in v.split(",")],
                    help="seeds of the learned models, one row each and their median (default 0)")
    args = ap.parse_args()
    if args.dataset == "ansfl":
        args.windows = args.windows or "10,30"
        quadrotor(args)
    else:
        args.windows = args.windows or "10,30,60"
        drive(args)


if __name__ == "__main__":
    main()
