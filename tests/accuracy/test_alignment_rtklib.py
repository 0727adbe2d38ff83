"""The rtklibexplorer car drive started with the heading unknown (issue 5): in-motion alignment from the GNSS
velocity against the run started from the loader's initial state (yaw = GNSS course, roll and pitch levelled).
No attitude truth exists on this drive, so the reference heading is the converged solution of the given run."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from zennav.metrics import evaluate
from zennav.nav.rotation import quat_to_euler, wrap_angle
from zennav.nav.types import NS
from zennav.replay import run_replay


@pytest.fixture(scope="module")
def runs(rtklib_dataset):
    given = run_replay(rtklib_dataset)
    ds = replace(rtklib_dataset, initial=replace(rtklib_dataset.initial, heading_known=False,
                                                 euler=rtklib_dataset.initial.euler + [0.0, 0.0, math.pi]))
    unknown = run_replay(ds)
    return given, evaluate(rtklib_dataset, given), unknown, evaluate(ds, unknown)


def test_heading_unknown_aligns_in_motion_and_agrees_with_the_given_run(runs):
    given, _, unknown, _ = runs
    assert np.array_equal(given.t_ns, unknown.t_ns)
    diff = np.degrees(np.abs(wrap_angle(quat_to_euler(unknown.q_nb)[:, 2] - quat_to_euler(given.q_nb)[:, 2])))
    t_s = (unknown.t_ns - unknown.t_ns[0]) / NS
    al = unknown.status["alignment"]
    fine_s = (al["times_ns"]["fine"] - unknown.t_ns[0]) / NS
    # Two filters, no attitude truth. In the drive's 130 deg turn at 5 m/s (braking into it from 260 s, out of it by
    # 290 s) they part by up to 3.3 deg, and the GNSS course lies on either side of both (given -4.6 to +3.0 deg from
    # it, heading unknown -6.0 to +4.2 deg): neither is the truth there. Elsewhere they agree within 1 deg.
    turn = (t_s >= 260.0) & (t_s < 290.0)
    agree_s = t_s[np.flatnonzero((diff >= 1.0) & ~turn)[-1] + 1]
    print(f"heading unknown: in motion at {fine_s:.2f} s, within 1 deg of the given run for good (the turn aside) "
          f"from {agree_s:.2f} s, aligned (1-sigma < 0.5 deg) at "
          f"{(al['times_ns']['aligned'] - unknown.t_ns[0]) / NS:.2f} s; in the turn at most {diff[turn].max():.2f} deg")
    assert al["method"] == "in_motion" and al["state"] == "aligned" and fine_s < 5.0
    assert agree_s < 30.0
    assert diff[(t_s > agree_s) & ~turn].max() < 1.0 and diff[turn].max() < 5.0


def test_heading_unknown_whole_run_metrics_equal_or_better(runs):
    _, m_given, _, m_unknown = runs
    for key in ("horizontal_rms_m", "vertical_rms_m", "velocity_rms_mps"):
        print(f"{key}: given {m_given[key]:.5f}, heading unknown {m_unknown[key]:.5f}")
        # Equal within 1 mm (or 1 mm/s): the RTK reference itself is good to about 1 cm.
        assert m_unknown[key] <= m_given[key] + 1e-3, key
