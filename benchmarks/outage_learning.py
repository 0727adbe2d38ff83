"""Outage benchmark of learned INS-error compensation on real data (issue 6).

GNSS is withheld in windows of 10, 30 and 60 s, the first after an initial training period (--train-s) and
then one every window length plus --gap-s of GNSS in between; each window is scored against the withheld
RTK fixes. Per window length and compensation, prints the RMS and the maximum over windows of the
per-window maximum horizontal drift, and the change of that RMS against pure INS.

    .venv/bin/python benchmarks/outage_learning.py [--dataset rtklibexplorer] [--target drift]
    (`zennav replay rtklibexplorer --outage-every 90:30:120 --compensation elman --target drift` is one row)
"""
from __future__ import annotations

import argparse
import time

from zennav.compensation import make_compensator
from zennav.datasets.registry import load_dataset
from zennav.metrics import evaluate
from zennav.replay import run_replay


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="rtklibexplorer")
    ap.add_argument("--target", default="drift", choices=["position", "velocity", "drift"])
    ap.add_argument("--train-s", type=float, default=120.0, help="GNSS before the first window [s]")
    ap.add_argument("--gap-s", type=float, default=60.0, help="GNSS between windows [s]")
    ap.add_argument("--windows", default="10,30,60", help="window lengths [s]")
    args = ap.parse_args()

    ds = load_dataset(args.dataset)
    print(f"{ds.name}: first window after {args.train_s:g} s, {args.gap_s:g} s of GNSS between windows; "
          f"learned target: {args.target}; reference: {ds.truth.source}")
    print(f"{'window':>7}{'compensation':>14}{'windows':>9}{'RMS of max m':>14}{'max m':>9}{'vs INS':>9}{'wall s':>8}")
    for length in (float(x) for x in args.windows.split(",")):
        every = (length + args.gap_s, length, args.train_s)
        base = None
        for model in ("none", "anfis", "elman"):
            t0 = time.perf_counter()
            res = run_replay(ds, outage_every=every, compensator=make_compensator(model, args.target))
            m = evaluate(ds, res)
            rms, mx = m["outage_max_horizontal_rms_m"], m["outage_max_horizontal_max_m"]
            base = base if base is not None else rms
            print(f"{length:>6.0f}s{model:>14}{len(m['outages']):>9}{rms:>14.2f}{mx:>9.2f}"
                  f"{100.0 * (rms - base) / base:>8.0f}%{time.perf_counter() - t0:>8.1f}")


if __name__ == "__main__":
    main()
