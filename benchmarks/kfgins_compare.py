"""zennav and KF-GINS (i2Nav-WHU/KF-GINS, built from its public source) side by side on the same KF-GINS files.

Two cases:
- ``rtk``: the rtklibexplorer car drive converted to KF-GINS files by the product's writer
  (zennav.datasets.kfgins.write_dataset) with the receiver's own RTK 1-sigma (about 1 cm) and the IMU's datasheet
  noise (issue 18: a KF-GINS user's configuration), position fixes only (KF-GINS fuses no GNSS velocity).
- ``uav``: the simulated multirotor (zennav.sim, 5 Hz GNSS) in KF-GINS files; full GNSS and 30/60/120 s outages.

``--stale S`` (repeatable) adds a full-GNSS row whose configuration starts S seconds later but keeps the initial
state of the original start (a user who cuts the start of a file and forgets the initial state; issue 18): zennav
tests the configured state against the first fixes (zennav.nav.alignment) and aligns from the fixes when they
contradict it. Its row also gives the horizontal RMS from the filter's start after that alignment ("after align").

Outages are applied the same way to both programs: the GNSS epochs inside the windows are left out of the GNSS
file; zennav's windows (zennav.replay.outage_windows, from the run's first IMU sample) decide which, and both
solutions are scored by zennav.metrics.evaluate against the same truth. zennav runs as ``zennav replay`` does
(zennav.replay_cli.replay_dataset's steps: load the YAML, the ins's parameter file, run_replay, evaluate).

    python benchmarks/kfgins_compare.py --kf-gins /tmp/kfgins/bin/KF-GINS rtk
    python benchmarks/kfgins_compare.py --kf-gins /tmp/kfgins/bin/KF-GINS uav --outage 30 --outage 60
    python benchmarks/kfgins_compare.py rtk --stale 5 --stale 20 --stale 60
    python benchmarks/kfgins_compare.py uav --stale 5 --stale 20 --stale 60

Without --kf-gins only zennav runs. KF-GINS builds from its public source with its bundled third-party libraries
(Eigen 3.3.9, yaml-cpp 0.7.0, abseil): ``cmake -S KF-GINS -B KF-GINS/build -DCMAKE_BUILD_TYPE=Release && make -C
KF-GINS/build``, the binary in KF-GINS/bin/ (its dataset/ files are not needed).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from zennav.datasets import kfgins, rtklibexplorer
from zennav.datasets.registry import load_dataset
from zennav.metrics import antenna_llh, evaluate, ned_errors
from zennav.nav.rotation import euler_to_quat
from zennav.nav.types import NS, Dataset
from zennav.params import load_filter_params, nav_config
from zennav.replay import ReplayResult, outage_windows, run_end_ns, run_replay


def rtk_case() -> Dataset:
    """The rtklibexplorer drive as a KF-GINS user writes it: RTK std as reported, datasheet noise, no velocity."""
    ds = load_dataset("rtklibexplorer")
    ds.config = ds.config.with_(imu_noise=rtklibexplorer.DATASHEET_NOISE)
    ds.gnss = replace(ds.gnss, v_n=None, std_v_n=None)
    return ds


def uav_case(seed: int = 0, velocity: bool = False) -> Dataset:
    """The simulated multirotor flight with 5 Hz GNSS; position fixes only (what KF-GINS fuses) unless velocity
    (then the files carry the zennav velocity file too, which only zennav reads)."""
    ds = load_dataset("sim:multirotor", duration_s=600.0, gnss_rate_hz=5.0, seed=seed)
    if not velocity:
        ds.gnss = replace(ds.gnss, v_n=None, std_v_n=None)
    return ds


def export(ds: Dataset, folder: Path, windows: list[tuple[int, int]], stale_s: float = 0.0) -> Path:
    """KF-GINS files of ds in folder by the product's writer, without the GNSS epochs inside windows; the YAML.
    stale_s [s]: the YAML's starttime that much later, its initial state still that of ds's start."""
    keep = np.ones(len(ds.gnss), dtype=bool)
    for a, b in windows:
        keep &= ~((ds.gnss.t_ns >= a) & (ds.gnss.t_ns < b))
    initial = replace(ds.initial, t_ns=ds.initial.t_ns + int(stale_s * NS))
    written = replace(ds, gnss=ds.gnss.slice(keep), initial=initial)
    return kfgins.write_dataset(written, folder, "run")


def run_zennav(yaml_path: Path, windows, params: Path | None) -> dict:
    """zennav replay of the KF-GINS files (the ins's parameter file on the files' sensors) -> metrics."""
    ds = load_dataset(str(yaml_path))
    ds.config = nav_config(ds.config, load_filter_params(params))
    res = run_replay(ds)
    res.windows = windows
    metrics = evaluate(ds, res)
    times = res.status["alignment"]["times_ns"]
    if "coarse" in times and ds.truth is not None:  # the filter started after a coarse alignment: RMS from its start
        t = ds.truth.t_ns
        sel = (t >= times["fine"]) & (t <= res.t_ns[-1])
        k = np.searchsorted(res.t_ns, t[sel])
        e = ned_errors(antenna_llh(res.llh[k], res.q_nb[k], ds.config.lever_arm_b), ds.truth.llh[sel])
        metrics["horizontal_rms_after_align_m"] = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
    return metrics


def run_kfgins(binary: Path, yaml_path: Path, windows) -> dict:
    """KF-GINS on the same files (run in their folder: KF-GINS resolves relative paths from its working directory)
    -> metrics of its KF_GINS_Navresult.nav by zennav.metrics.evaluate."""
    folder = yaml_path.parent
    proc = subprocess.run([str(binary.resolve()), yaml_path.name], cwd=folder, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"KF-GINS failed ({proc.returncode}): {proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    ds = load_dataset(str(yaml_path))
    nav = kfgins.load_nav(folder / "KF_GINS_Navresult.nav")
    week = int(ds.imu.t_ns[0] // kfgins.WEEK_NS)
    t_ns = nav.t_ns + week * kfgins.WEEK_NS
    assert nav.euler is not None and nav.v_n is not None  # load_nav reads all fields by default
    q_nb = np.array([euler_to_quat(e) for e in nav.euler])
    n = len(t_ns)
    res = ReplayResult("KF-GINS", t_ns, nav.llh, nav.v_n, q_nb, np.zeros((n, 3)), np.zeros(n, bool), windows)
    return evaluate(ds, res)


def compare(ds: Dataset, outage_s: float | None, kf_gins: Path | None, params: Path | None, every_s: float,
            stale_s: float = 0.0) -> dict:
    """Both programs on ds with outages of outage_s seconds every every_s seconds (None: full GNSS); stale_s: the
    files' start that much later with ds's initial state (export)."""
    t0 = int(ds.initial.t_ns) + int(stale_s * NS)
    windows = [] if outage_s is None else outage_windows(t0, run_end_ns(ds), every=(every_s, outage_s,
                                                                                  every_s - outage_s))
    with tempfile.TemporaryDirectory(prefix="kfgins_compare_") as tmp:
        yaml_path = export(ds, Path(tmp), windows, stale_s)
        week_ns = int(ds.imu.t_ns[0] // kfgins.WEEK_NS) * kfgins.WEEK_NS  # the files' times: seconds of week
        windows = [(a - week_ns, b - week_ns) for a, b in windows]
        out = {"zennav": run_zennav(yaml_path, windows, params)}
        if kf_gins is not None:
            out["KF-GINS"] = run_kfgins(kf_gins, yaml_path, windows)
    return out


def _fmt(x) -> str:
    return "n/a" if x is None else f"{x:.3f}"


def print_rows(label: str, result: dict) -> None:
    for program, m in result.items():
        print(f"{label:<14} {program:<8} h_rms {_fmt(m['horizontal_rms_m']):>8} m"
              f"  v_rms {_fmt(m['vertical_rms_m']):>7} m"
              f"  outage max drift RMS {_fmt(m['outage_max_horizontal_rms_m']):>8} m"
              f"  max {_fmt(m['outage_max_horizontal_max_m']):>8} m  ({len(m['outages'])} windows)"
              + (f"  after align {m['horizontal_rms_after_align_m']:.3f} m" if "horizontal_rms_after_align_m" in m
                 else ""))
        counters = m["engine"].get("counters") if m.get("engine") else None
        if counters:
            shown = {k: v for k, v in sorted(counters.items()) if not k.endswith("_fused")}
            fused = {k: v for k, v in sorted(counters.items()) if k.endswith("_fused")}
            print(f"{'':<14} {'':<8} fused {fused}")
            print(f"{'':<14} {'':<8} counters {shown}")
        monitor = m["engine"].get("consistency") if m.get("engine") else None
        if monitor:
            print(f"{'':<14} {'':<8} consistency {monitor}")
        initial = m["engine"]["alignment"].get("initial_state") if m.get("engine") else None
        if initial:
            print(f"{'':<14} {'':<8} initial state {initial}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("case", choices=("rtk", "uav"))
    ap.add_argument("--kf-gins", type=Path, default=None, help="the KF-GINS binary (built from i2Nav-WHU/KF-GINS)")
    ap.add_argument("--params", type=Path, default=None, help="the ins's parameter file (default deploy/ins.yaml)")
    ap.add_argument("--outage", type=float, action="append", default=None,
                    help="outage length [s] (repeatable; the uav case's default without --stale: 30, 60, 120)")
    ap.add_argument("--every", type=float, default=None, help="outage period [s] (default: 4 x the outage, >= 60 s)")
    ap.add_argument("--seed", type=int, default=0, help="simulator seed of the uav case")
    ap.add_argument("--velocity", action="store_true", help="uav case: GNSS velocity in the files (zennav only)")
    ap.add_argument("--stale", type=float, action="append", default=[],
                    help="also full GNSS with the files' start this many seconds later and the initial state of the "
                         "original start (repeatable)")
    args = ap.parse_args(argv)
    ds = rtk_case() if args.case == "rtk" else uav_case(args.seed, args.velocity)
    outages = args.outage if args.outage is not None else ([] if args.case == "rtk" or args.stale
                                                           else [30.0, 60.0, 120.0])
    print(f"{ds.name}: {(run_end_ns(ds) - ds.initial.t_ns) / NS:.0f} s, IMU noise {ds.config.imu_noise}")
    print_rows("full GNSS", compare(ds, None, args.kf_gins, args.params, 0.0))
    for stale in args.stale:
        print_rows(f"stale +{stale:g}s", compare(ds, None, args.kf_gins, args.params, 0.0, stale))
    for dur in outages:
        every = args.every or max(60.0, 4.0 * dur)
        print_rows(f"outage {dur:.0f}s/{every:.0f}s", compare(ds, dur, args.kf_gins, args.params, every))
    return 0


if __name__ == "__main__":
    sys.exit(main())
