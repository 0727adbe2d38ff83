"""In-motion alignment from an unknown heading: yaw = course, the acceleration method (GNSS velocity changes against
the IMU's, zennav.nav.alignment.heading_from_vector_pairs), auto (the course once the changes confirm it) and dvl (a
DVL's body velocity against the GNSS velocity; the course without a DVL), beside the heading given.

For each dataset the run starts with its initial yaw declared unknown (``zennav replay --heading-unknown``) and the
parameter file's filter with the dataset's vehicle profile, the in-motion method forced to each of --methods. Printed
per group of datasets (medians over its runs): the share that left coarse alignment, the time to do so [s], the
heading error at the hand-over [deg] (the heading handed over, start_heading_rad, against the reference at that time:
before any update of the same epoch) against the filter's 1-sigma then (as a ratio: above 3 is overconfident), the
median heading error after it [deg] and the horizontal RMS [m] of the whole run.

    .venv/bin/python benchmarks/alignment_in_motion.py --methods course,acceleration,auto,dvl  # ANSFL, sim, A-KIT
    .venv/bin/python benchmarks/alignment_in_motion.py --groups ansfl --methods acceleration
"""
from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from zennav.datasets.registry import akit_specs, ansfl_specs, load_dataset, vehicle_of
from zennav.metrics import evaluate
from zennav.nav.rotation import quat_to_euler, wrap_angle
from zennav.params import load_filter_params, nav_config
from zennav.replay import run_replay

GROUPS: dict[str, Callable[[], list[tuple[str, dict]]]] = {
    "ansfl": lambda: [(s, {}) for s in ansfl_specs()],
    "sim-multirotor": lambda: [("sim:multirotor", {"seed": k}) for k in range(5)],
    "sim-car": lambda: [("sim:car", {"seed": k, "duration_s": 300.0}) for k in range(5)],
    "sim-auv": lambda: [("sim:auv", {"seed": k}) for k in range(5)],
    "akit": lambda: [(s, {}) for s in akit_specs()],
}


def run_one(spec: str, options: dict, method: str | None) -> dict:
    """One replay: heading given (method None) or unknown with that in-motion method; its figures."""
    ds = load_dataset(spec, **options)
    settings = load_filter_params(None, vehicle_of(spec))
    if method is not None:
        settings["align_in_motion"] = method
        ds.initial = replace(ds.initial, heading_known=False)
    ds.config = nav_config(ds.config, settings)
    res = run_replay(ds)
    m = evaluate(ds, res)
    truth = ds.truth
    assert truth is not None and truth.euler is not None, f"{spec}: no attitude truth"
    yaw_ref = np.unwrap(truth.euler[:, 2])  # interpolated to the solution's times (A-KIT's reference is at 1 Hz)
    err = np.degrees(np.abs(wrap_angle(quat_to_euler(res.q_nb)[:, 2] - np.interp(res.t_ns, truth.t_ns, yaw_ref))))
    al = res.status["alignment"]
    out = {"left_coarse": al["state"] != "coarse", "h_rms": m["horizontal_rms_m"]}
    t_fine = al["times_ns"].get("fine", al["times_ns"].get("aligned")) if method is not None else int(res.t_ns[0])
    if out["left_coarse"] and t_fine is not None:
        i = int(np.searchsorted(res.t_ns, t_fine))
        if method is None:
            err0 = float(err[min(i, len(err) - 1)])
        else:  # the heading handed over, before any update at the same epoch (a DVL sample's)
            yaw = np.interp(t_fine, truth.t_ns, yaw_ref)
            err0 = math.degrees(abs(float(wrap_angle(al["start_heading_rad"] - yaw))))
        out.update(t_s=(t_fine - int(res.t_ns[0])) / 1e9, err0=err0,
                   after=float(np.median(err[i:])) if i < len(err) else math.nan,
                   ratio=err0 / math.degrees(al["start_heading_std_rad"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--groups", default=",".join(GROUPS), help=f"comma-separated from {', '.join(GROUPS)}")
    ap.add_argument("--methods", default="course,acceleration,auto",
                    help="in-motion methods (course, acceleration, auto, dvl)")
    args = ap.parse_args()
    methods: list[str | None] = [None, *args.methods.split(",")]
    print(f"{'group':15s} {'heading':13s} {'runs':>4s} {'left coarse':>11s} {'t [s]':>7s} {'err0 [deg]':>10s} "
          f"{'err0/sigma':>10s} {'err after':>9s} {'h RMS [m]':>9s}")
    for group in args.groups.split(","):
        runs = GROUPS[group]()
        for method in methods:
            rows = [run_one(spec, opt, method) for spec, opt in runs]
            done = [r for r in rows if "t_s" in r]

            def med(key: str, rs=done) -> float:
                v = [r[key] for r in rs if math.isfinite(r.get(key, math.nan))]
                return float(np.median(v)) if v else math.nan

            label = "given" if method is None else f"unknown/{method[:5]}"
            print(f"{group:15s} {label:13s} {len(rows):4d} {len(done):5d}/{len(rows):<5d} {med('t_s'):7.2f} "
                  f"{med('err0'):10.2f} {med('ratio'):10.2f} {med('after'):9.2f} {med('h_rms', rows):9.3f}")


if __name__ == "__main__":
    main()
