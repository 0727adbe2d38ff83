"""The floor of DVL-aided navigation on the A-KIT trajectories (issue 14, target "clean drift under 0.5 %"): the drift
of the DVL's own dead reckoning with the reference attitude (akit_dvl.dvl_dead_reckoning, from the last GNSS fix, as
akit_dvl scores a filter), raw and with a DVL calibration taken out (yaw misalignment and scale factor,
v_d = (1 + scale) R_z(yaw) v_b, least squares of the DVL's horizontal velocity against the reference's in the body
frame), fitted three ways:
- surface: on the first --gnss-s seconds only (what a misalignment/scale state can learn while GNSS is there, at best:
  from the reference's own velocity, not from noisy fixes);
- others: the mean of the fits of the OTHER trajectories (a calibration from training trajectories, leave-one-out);
- own: on the whole trajectory itself (the best constant calibration of the VELOCITY; not of the drift, which a
  velocity that disagrees with the reference's positions sets: it can be worse than raw).
A calibration that lowers the drift on some trajectories and raises it on others is no fix: what remains is the
DVL-vs-reference disagreement that varies within a trajectory (zennav.datasets.akit: the reference is a Delph
solution of the same Phins and DVL, not independent).

    .venv/bin/python benchmarks/akit_dvl_floor.py [--trajectories 1-13] [--gnss-s 60]
"""
from __future__ import annotations

import argparse

import numpy as np
from akit_dvl import dvl_dead_reckoning, parse_trajectories

from zennav.datasets.registry import akit_specs, load_dataset
from zennav.nav.rotation import euler_to_dcm
from zennav.nav.types import NS, Dataset


def fit_calibration(ds: Dataset, until_ns: int | None = None) -> tuple[float, float]:
    """(yaw [rad], scale [-]) of v_d = (1 + scale) R_z(yaw) v_b by linear least squares (small angle) of the DVL's
    horizontal velocity against the reference's body-frame velocity at the DVL rows up to until_ns (None: all)."""
    truth, dvl = ds.truth, ds.dvl
    assert truth is not None and truth.euler is not None and truth.v_n is not None
    assert dvl is not None and dvl.velocity_d is not None
    k = (dvl.t_ns >= truth.t_ns[0]) & (dvl.t_ns <= (truth.t_ns[-1] if until_ns is None else until_ns))
    t_ns, v_d = dvl.t_ns[k], dvl.velocity_d[k]
    euler = np.column_stack([np.interp(t_ns, truth.t_ns, np.unwrap(truth.euler[:, i])) for i in range(3)])
    v_n = np.column_stack([np.interp(t_ns, truth.t_ns, truth.v_n[:, i]) for i in range(3)])
    v_b = np.array([euler_to_dcm(e).T @ v for e, v in zip(euler, v_n, strict=True)])
    r = v_d - v_b  # ~ scale v_b + yaw (-v_b,y, v_b,x)
    A = np.vstack([np.column_stack([v_b[:, 0], -v_b[:, 1]]), np.column_stack([v_b[:, 1], v_b[:, 0]])])
    scale, yaw = np.linalg.lstsq(A, np.concatenate([r[:, 0], r[:, 1]]), rcond=None)[0]
    return float(yaw), float(scale)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trajectories", default=f"1-{len(akit_specs())}", help="e.g. 1-13 or 1,4,8")
    ap.add_argument("--gnss-s", type=float, default=60.0, help="derived GNSS during the first S seconds")
    args = ap.parse_args()
    trajectories = parse_trajectories(args.trajectories)
    data = {n: load_dataset(f"akit:Trajectory{n}", gnss_s=args.gnss_s) for n in trajectories}
    own = {n: fit_calibration(ds) for n, ds in data.items()}
    print(f"DVL dead-reckoning drift [%] from the last GNSS fix ({args.gnss_s:g} s), reference attitude; calibration "
          "yaw [deg] / scale [%]")
    print(f"{'trajectory':<13}{'raw':>7}{'surface fit':>22}{'others (mean)':>22}{'own':>22}")
    for n, ds in data.items():
        surface = fit_calibration(ds, int(ds.initial.t_ns) + round(args.gnss_s * NS))
        others = tuple(np.mean([own[m] for m in own if m != n], axis=0)) if len(own) > 1 else (0.0, 0.0)
        cells = [f"{np.degrees(c[0]):+.2f}/{100 * c[1]:+.2f} {dvl_dead_reckoning(ds, *c):.3f}"
                 for c in (surface, others, own[n])]
        print(f"Trajectory{n:<3}{dvl_dead_reckoning(ds):>7.3f}" + "".join(f"{c:>22}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
