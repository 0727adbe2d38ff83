"""The navigation core on the rtklibexplorer car drive, scored against the receiver's RTK fixes
(the only reference this drive has; inside outages the withheld fixes are independent of the solution)."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from zennav.datasets import kfgins
from zennav.datasets.registry import load_dataset
from zennav.metrics import evaluate
from zennav.replay import run_replay


@pytest.fixture(scope="module")
def full_gnss(rtklib_dataset):
    res = run_replay(rtklib_dataset)
    return res, evaluate(rtklib_dataset, res)


def test_full_gnss_tracks_rtk(full_gnss):
    res, m = full_gnss
    # 4 Hz RTK (about 1 cm formal sigma) fused with a vibrating consumer IMU: a few cm expected.
    assert m["horizontal_rms_m"] < 0.15
    assert m["vertical_rms_m"] < 0.10
    assert m["velocity_rms_mps"] < 0.20
    assert m["attitude_rms_deg"] is None  # no attitude truth on this drive
    counters = res.status["counters"]
    assert counters.get("gate_reset", 0) == 0
    assert counters["gnss_pos_fused"] > 0.99 * (counters["gnss_pos_fused"] + counters.get("gnss_pos_gate", 0))


def test_periodic_outages_are_scored_against_withheld_fixes(rtklib_dataset, full_gnss):
    res = run_replay(rtklib_dataset, outage_every=(90.0, 30.0, 60.0))
    m = evaluate(rtklib_dataset, res)
    assert [round(o["start_s"]) for o in m["outages"]] == [60, 150, 240, 330, 420]
    assert all(o["duration_s"] == 30.0 for o in m["outages"])
    drifts = np.array([o["max_horizontal_m"] for o in m["outages"]])
    # Unaided consumer MEMS for 30 s drifts metres to a few hundred metres; the solution must be
    # drifting (the windows are really withheld) and bounded, and recover to cm level after each outage.
    assert drifts.min() > 1.0
    assert m["outage_max_horizontal_rms_m"] < 150.0
    assert m["outage_max_horizontal_rms_m"] == pytest.approx(np.sqrt(np.mean(drifts**2)))
    assert res.outage.any() and not res.outage[-1000:-400].any()
    assert m["horizontal_rms_m"] > full_gnss[1]["horizontal_rms_m"]


def test_kf_gins_files_give_the_same_solution(rtklib_dataset, full_gnss, tmp_path):
    yaml_path = kfgins.write_dataset(copy.deepcopy(rtklib_dataset), tmp_path)
    converted = load_dataset(str(yaml_path))
    res = run_replay(converted)
    ref = full_gnss[0]
    assert len(res.t_ns) == len(ref.t_ns)
    # Same epochs (KF-GINS files count seconds of the week, the native loader seconds since 1980).
    assert len(np.unique(ref.t_ns - res.t_ns)) == 1
    assert np.max(np.abs(res.llh[:, :2] - ref.llh[:, :2])) < 1e-13  # rad, i.e. < 1 um
    assert np.max(np.abs(res.llh[:, 2] - ref.llh[:, 2])) < 1e-6
    assert np.max(np.abs(res.v_n - ref.v_n)) < 1e-9
