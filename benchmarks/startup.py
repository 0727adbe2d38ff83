#!/usr/bin/env python
"""Start-up benchmark (a script, not a test): how long the `zennav` command takes before it does work.

- ``zennav --help``: wall time of the whole command (the console script), median of --repeat runs.
- ``zennav replay SPEC``: from process start (this script's spawn) to the dataset loaded, the engine built and the
  first IMU sample the engine processed, wall and CPU seconds (CPU: what the process itself spent, not inflated by
  a busy machine), median of --repeat runs after one unmeasured warm-up run (file caches, .pyc: the children run
  without PYTHONDONTWRITEBYTECODE, as an installation does, unless --no-pyc; then, where no .pyc was written
  before, every run compiles zennav's sources, about 0.2 s more). The child runs
  the product's own command line (zennav.cli.main, standalone) with timestamps added from outside: when
  load_dataset returns, when a Navigator is constructed and when its first on_imu returns (then it exits: the
  rest is the core's speed; a replay that never calls on_imu fails here).
  It also lists the heavy modules the replay loaded (torch, matplotlib, mcap, scipy.stats, ... must not load
  for a plain replay).

By default it replays rtklibexplorer (the real 100 Hz drive; its loader low-passes it with scipy's filtfilt floats),
sim:car (the simulator's 600 s drive: its long series read from the simulator's cache, zennav.sim.cache, which the
warm-up run fills, as after a first run on a machine; --no-cache: generated in every run, ZENNAV_CACHE=0) and a
simulated car drive of --kf-gins-duration s at 200 Hz written as KF-GINS text files
(zennav.datasets.kfgins.write_dataset: the issue's case, 30 min).

    .venv/bin/python benchmarks/startup.py [--repeat 5] [--kf-gins-duration 1800] [--spec rtklibexplorer ...]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PY = sys.executable
BIN = Path(PY).parent
HEAVY = ("torch", "matplotlib", "mcap", "scipy.stats", "scipy.signal", "scipy.special", "scipy.optimize",
         "scipy.spatial", "sklearn", "pandas", "polars", "numba", "zenoh", "yaml", "zennav.learn.loop")

CHILD = r"""
import json, os, sys, time
from zennav.datasets import registry as _reg
from zennav.nav import navigator as _nv
marks = {}
def mark(name):
    if name not in marks:
        marks[name] = (time.monotonic(), time.process_time())
_load, _init, _on_imu, _run_imu = (_reg.load_dataset, _nv.Navigator.__init__, _nv.Navigator.on_imu,
                                   _nv.Navigator.run_imu)
def load(*a, **k):
    ds = _load(*a, **k)
    mark("dataset_loaded")
    return ds
def init(self, *a, **k):
    _init(self, *a, **k)
    mark("engine_built")
def on_imu(self, *a, **k):
    ok = _on_imu(self, *a, **k)
    mark("first_sample")
    report()
    os._exit(0)  # start-up measured: the rest of the replay is the core's speed, not this benchmark's
def run_imu(self, *a, **k):
    end = _run_imu(self, *a, **k)
    if end > a[3]:  # the compiled block loop processed its first samples
        mark("first_sample")
        report()
        os._exit(0)
    return end
_reg.load_dataset, _nv.Navigator.__init__, _nv.Navigator.on_imu, _nv.Navigator.run_imu = load, init, on_imu, run_imu
heavy = %r
def report():
    marks["loaded"] = sorted(m for m in heavy if m in sys.modules)
    os.write(2, ("STARTUP " + json.dumps(marks) + "\n").encode())
sys.argv = ["zennav", "replay", *sys.argv[1:]]
from zennav.cli import main
main()
"""


ENV = dict(os.environ)  # the children's (main: without PYTHONDONTWRITEBYTECODE unless --no-pyc)


def wall(argv: list[str]) -> float:
    t0 = time.monotonic()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True, env=ENV)
    return time.monotonic() - t0


def replay_marks(spec: str, out: Path) -> dict:
    """One replay of spec in a fresh process up to its first sample: wall and CPU seconds at each mark, modules."""
    t0 = time.monotonic()
    r = subprocess.run([PY, "-c", CHILD % (HEAVY,), spec, "-q", "--out", str(out)], stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, check=True, env=ENV)
    line = next(ln for ln in r.stderr.decode().splitlines() if ln.startswith("STARTUP "))
    m = json.loads(line[8:])
    res = {"loaded": m.pop("loaded")}
    for name, (t, cpu) in m.items():
        res[f"{name}_s"], res[f"{name}_cpu_s"] = t - t0, cpu
    return res


def med(values) -> str:
    v = [x for x in values if x is not None]
    return f"{statistics.median(v):.3f} s (range {min(v):.3f}-{max(v):.3f})" if v else "n/a"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--spec", action="append", default=None,
                    help="datasets to replay (default: rtklibexplorer, sim:car and the simulated KF-GINS files)")
    ap.add_argument("--kf-gins-duration", type=float, default=1800.0,
                    help="[s] of the simulated car drive written as KF-GINS files (0: none)")
    ap.add_argument("--json", default=None, help="also write the results here")
    ap.add_argument("--no-cache", action="store_true",
                    help="the children generate simulated datasets in every run (ZENNAV_CACHE=0)")
    ap.add_argument("--no-pyc", action="store_true",
                    help="keep PYTHONDONTWRITEBYTECODE if set (no .pyc written; those already written are read)")
    args = ap.parse_args()
    if not args.no_pyc:
        ENV.pop("PYTHONDONTWRITEBYTECODE", None)
    if args.no_cache:
        ENV["ZENNAV_CACHE"] = "0"
    print(f"bytecode cache (.pyc): {'off' if ENV.get('PYTHONDONTWRITEBYTECODE') else 'on'}, simulator cache: "
          f"{'off' if ENV.get('ZENNAV_CACHE') == '0' else 'on'}", flush=True)
    results: dict = {}
    wall([str(BIN / "zennav"), "--help"])
    helps = [wall([str(BIN / "zennav"), "--help"]) for _ in range(args.repeat)]
    results["help_s"] = helps
    print(f"zennav --help: median {med(helps)} over {len(helps)} runs (target < 0.3 s)", flush=True)
    with tempfile.TemporaryDirectory(prefix="zennav-startup-") as tmp:
        specs = args.spec or ["rtklibexplorer", "sim:car"]
        if args.kf_gins_duration > 0:
            from zennav.datasets import kfgins
            from zennav.sim.scenarios import make_dataset

            ds = make_dataset("car", duration_s=args.kf_gins_duration)
            specs.append(str(kfgins.write_dataset(ds, Path(tmp) / "kfgins")))
            del ds
        for spec in specs:
            replay_marks(spec, Path(tmp) / "warm")
            runs = [replay_marks(spec, Path(tmp) / str(i)) for i in range(args.repeat)]
            results[spec] = runs
            print(f"zennav replay {Path(spec).name} (seconds from process start; CPU seconds of the process, which the "
                  f"machine's load does not inflate):", flush=True)
            for mk in ("dataset_loaded", "engine_built", "first_sample"):
                print(f"  -> {mk.replace('_', ' '):<15} wall {med(r.get(mk + '_s') for r in runs)}, "
                      f"CPU {med(r.get(mk + '_cpu_s') for r in runs)}"
                      + (" (target < 1 s)" if mk == "first_sample" else ""), flush=True)
            print(f"  heavy modules loaded by then: "
                  f"{', '.join(runs[0]['loaded']) or 'none'}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
