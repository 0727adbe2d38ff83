"""DVL aiding on the simulated AUV (sim:auv, exact truth): the seed's partial-beam cases, and loose / tight / tight+VB
with injected DVL anomalies.

1. Partial beams (seed 003 step 2.4): the mission starts with 120 s at the surface (GNSS), then dives; from the
   dive on (the last GNSS fix) only the beams of one case stay valid (4; 3: beam 3 lost; 2 orthogonal: beams 1, 2;
   2 parallel: beams 1, 3; 1: beam 1; 0: none). Horizontal position error [m] 300 s later for the tight filter (a
   missing beam is left out of H) and the loose one (velocity from >= 3 beams, or 2 adjacent ones with the
   reconstruction under the no-vertical-velocity assumption; otherwise no update).
2. Anomalies: the same mission clean and with injected DVL anomalies (outliers 2 % per beam of 0.5-1 m/s, two 30 s
   noise bursts x10, a 0.1 m/s bias jump on beam 2, a 20 s bottom loss): horizontal RMS and final error [m] under
   water for loose, tight and tight with variational-Bayes R.

Every run is zennav.replay.run_replay with the shipped parameter file (deploy/ins.yaml) and the mode switched, as
`zennav replay sim:auv --dvl MODE [--vb dvl]` runs it.

    .venv/bin/python benchmarks/dvl_partial_beams.py [--seed 0] [--imu-rate 100] [--grade tactical]
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from zennav.datasets.registry import load_dataset
from zennav.nav import earth
from zennav.nav.types import NS, Dataset
from zennav.params import load_filter_params, nav_config
from zennav.replay import run_replay

UNDER_WATER_S = 300.0
CASES = {"4": (1, 1, 1, 1), "3": (1, 1, 0, 1), "2_orthogonal": (1, 1, 0, 0), "2_parallel": (1, 0, 1, 0),
         "1": (1, 0, 0, 0), "0": (0, 0, 0, 0)}
ANOMALIES = {"dvl_outlier_prob": 0.02, "dvl_outlier_mps": 0.5, "dvl_burst": "250:30,400:30",
             "dvl_bias_jump": "300:2:0.1", "dvl_bottom_loss": "350:20"}


def horizontal_error(ds: Dataset, t_ns: np.ndarray, llh: np.ndarray) -> np.ndarray:
    """Horizontal position error [m] of solutions llh (N, 3) at t_ns (N,) against the dataset's truth."""
    tr = ds.truth
    assert tr is not None  # the simulator's exact truth
    i = np.searchsorted(tr.t_ns, t_ns)
    r_m, r_n = earth.radii(tr.llh[i, 0])
    d = llh - tr.llh[i]
    return np.hypot(d[:, 0] * (r_m + tr.llh[i, 2]), d[:, 1] * (r_n + tr.llh[i, 2]) * np.cos(tr.llh[i, 0]))


def run(ds: Dataset, **settings):
    ds.config = nav_config(ds.config, load_filter_params()).with_(**settings)
    res = run_replay(ds)
    return res, horizontal_error(ds, res.t_ns, res.llh)


def with_beams_from(ds: Dataset, t_ns: int, mask) -> Dataset:
    """ds with only the beams of mask (4,) valid from t_ns on."""
    dvl = ds.dvl
    assert dvl is not None and dvl.beams is not None and dvl.beam_valid is not None  # sim:auv's beams
    valid = dvl.beam_valid.copy()
    valid[dvl.t_ns >= t_ns] &= np.array(mask, dtype=bool)
    return replace(ds, dvl=replace(dvl, beams=np.where(valid, dvl.beams, np.nan), beam_valid=valid))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--imu-rate", type=float, default=100.0, help="IMU rate [Hz]")
    ap.add_argument("--grade", default="tactical", help="IMU grade (zennav.sim.scenarios.IMU_GRADES)")
    args = ap.parse_args()
    common = dict(duration_s=120.0 + UNDER_WATER_S + 10.0, seed=args.seed, imu_rate_hz=args.imu_rate,
                  imu_grade=args.grade)
    ds = load_dataset("sim:auv", **common, dvl_bottom_loss="")
    t_dive = int(ds.gnss.t_ns[-1])
    t_at = t_dive + int(UNDER_WATER_S * NS)
    print(f"sim:auv seed {args.seed}, {args.grade} IMU at {args.imu_rate:.0f} Hz, last GNSS fix at "
          f"{(t_dive - ds.imu.t_ns[0]) / NS:.0f} s; injected: {ds.notes['injected']}")
    print(f"\n1. partial beams from the dive on: horizontal error {UNDER_WATER_S:.0f} s later [m]")
    print(f"{'case':>14}{'valid beams':>13}{'tight':>9}{'loose':>9}   counted (tight)")
    for case, mask in CASES.items():
        part = with_beams_from(ds, t_dive, mask)
        res_t, err_t = run(part, dvl_mode="tight")
        res_l, err_l = run(part, dvl_mode="loose")
        counted = res_t.status["counters"].get(f"dvl_beams_{case}", 0)
        beams = ",".join(str(i + 1) for i, v in enumerate(mask) if v) or "-"
        print(f"{case:>14}{beams:>13}{np.interp(t_at, res_t.t_ns, err_t):>9.2f}"
              f"{np.interp(t_at, res_l.t_ns, err_l):>9.2f}   dvl_beams_{case}: {counted}")
    print("\n2. anomalies under water: horizontal RMS / final error [m]")
    print(f"{'data':>10}{'loose':>16}{'tight':>16}{'tight+VB':>16}")
    for label, extra in (("clean", {"dvl_bottom_loss": ""}), ("anomalies", ANOMALIES)):
        data = load_dataset("sim:auv", **common, **extra)
        cells = []
        for settings in ({"dvl_mode": "loose"}, {"dvl_mode": "tight"}, {"dvl_mode": "tight", "vb_dvl": True}):
            res, err = run(data, **settings)
            under = res.t_ns > int(data.gnss.t_ns[-1])
            cells.append(f"{np.sqrt(np.mean(err[under] ** 2)):.2f} / {err[-1]:.2f}")
        print(f"{label:>10}" + "".join(f"{c:>16}" for c in cells))


if __name__ == "__main__":
    main()
