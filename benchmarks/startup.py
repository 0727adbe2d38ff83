#!/usr/bin/env python
"""Start-up benchmark (a script, not a test): how long the `zennav` command takes before it does work.

- ``zennav --help``: wall time of the whole command (the console script), median of --repeat runs.
- ``zennav replay SPEC``: from process start (this script's spawn) to the engine built and to the first IMU sample
  the engine processed, median of --repeat runs after one unmeasured warm-up run (file caches, .pyc). The child
  runs the product's own command line (zennav.cli.main, standalone) with two timestamps added from outside:
  when a Navigator is constructed and when its on_imu is first called ("n/a" when the replay never calls it).
  It also lists the heavy modules the replay loaded (torch, matplotlib, mcap, scipy.stats, ... must not load
  for a plain replay).

    .venv/bin/python benchmarks/startup.py [--repeat 5] [--spec rtklibexplorer] [--spec sim:car ...]
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PY = sys.executable
BIN = Path(PY).parent
HEAVY = ("torch", "matplotlib", "mcap", "scipy.stats", "scipy.signal", "scipy.special", "scipy.optimize",
         "scipy.spatial", "sklearn", "pandas", "numba", "zenoh", "yaml", "zennav.learn.loop")

CHILD = r"""
import json, os, sys, time
from zennav.nav import navigator as _nv
marks = {}
_init, _on_imu = _nv.Navigator.__init__, _nv.Navigator.on_imu
def init(self, *a, **k):
    _init(self, *a, **k)
    marks.setdefault("engine_built", time.monotonic())
def on_imu(self, *a, **k):
    marks.setdefault("first_sample", time.monotonic())
    return _on_imu(self, *a, **k)
_nv.Navigator.__init__, _nv.Navigator.on_imu = init, on_imu
heavy = %r
def report():
    marks["loaded"] = sorted(m for m in heavy if m in sys.modules)
    os.write(2, ("STARTUP " + json.dumps(marks) + "\n").encode())
import atexit
atexit.register(report)
sys.argv = ["zennav", "replay", *sys.argv[1:]]
from zennav.cli import main
main()
"""


def wall(argv: list[str]) -> float:
    t0 = time.monotonic()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return time.monotonic() - t0


def replay_marks(spec: str, out: Path) -> dict:
    """One replay of spec in a fresh process: seconds from spawn to engine built and to first sample, modules."""
    t0 = time.monotonic()
    r = subprocess.run([PY, "-c", CHILD % (HEAVY,), spec, "-q", "--out", str(out)], stdout=subprocess.DEVNULL,
                       stderr=subprocess.PIPE, check=True)
    t1 = time.monotonic()
    line = next(ln for ln in r.stderr.decode().splitlines() if ln.startswith("STARTUP "))
    m = json.loads(line[8:])
    return {"engine_built_s": m["engine_built"] - t0 if "engine_built" in m else None,
            "first_sample_s": m["first_sample"] - t0 if "first_sample" in m else None,
            "whole_s": t1 - t0, "loaded": m["loaded"]}


def med(values) -> str:
    v = [x for x in values if x is not None]
    return f"{statistics.median(v):.3f} s (range {min(v):.3f}-{max(v):.3f})" if v else "n/a"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--spec", action="append", default=None,
                    help="datasets to replay (default: rtklibexplorer, the real 100 Hz drive)")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args()
    results: dict = {}
    wall([str(BIN / "zennav"), "--help"])
    helps = [wall([str(BIN / "zennav"), "--help"]) for _ in range(args.repeat)]
    results["help_s"] = helps
    print(f"zennav --help: median {med(helps)} over {len(helps)} runs (target < 0.3 s)", flush=True)
    with tempfile.TemporaryDirectory(prefix="zennav-startup-") as tmp:
        for spec in args.spec or ["rtklibexplorer"]:
            replay_marks(spec, Path(tmp) / "warm")
            runs = [replay_marks(spec, Path(tmp) / str(i)) for i in range(args.repeat)]
            results[spec] = runs
            print(f"zennav replay {spec}: process start -> engine built {med(r['engine_built_s'] for r in runs)}; "
                  f"-> first IMU sample processed {med(r['first_sample_s'] for r in runs)} (target < 1 s); "
                  f"whole command {med(r['whole_s'] for r in runs)}; heavy modules loaded: "
                  f"{', '.join(runs[0]['loaded']) or 'none'}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
