"""The in-process learning loop: training samples while GNSS is good, queries during an outage, learned
corrections fused as pseudo-measurements; deterministic."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.compensation import make_compensator
from zennav.nav.learning import DRIFT_FEATURES, RATE_FEATURES
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset


@pytest.fixture(scope="module")
def drive():
    return make_dataset("car", duration_s=240.0, imu_rate_hz=100.0, gnss_rate_hz=2.0, seed=5)


def test_anfis_loop_offers_corrections_during_outage_only(drive):
    comp = make_compensator("anfis", "position")
    res = run_replay(drive, outages=[(180.0, 30.0)], compensator=comp)
    learned = [r for r in res.reports if r.source == "learned_position"]
    assert learned, "no learned correction was offered during the outage"
    t0 = drive.initial.t_ns
    assert all(180e9 <= r.t_ns - t0 <= 211e9 for r in learned)
    assert all(r.fused or r.reason == "learned_position_gate" for r in learned)
    assert len(comp.trainings) == 1 and comp.trainings[0]["samples"] > 100
    # Deterministic: the same run gives the same solution.
    again = run_replay(drive, outages=[(180.0, 30.0)], compensator=make_compensator("anfis", "position"))
    assert np.array_equal(again.llh, res.llh)


def test_elman_predicts_only_under_its_error_threshold(drive):
    """Seed 002: the network predicts only while its training error is under the threshold. On this drive the
    per-interval corrections are GNSS noise (no learnable drift), so it must stay silent."""
    comp = make_compensator("elman", "position")
    res = run_replay(drive, outages=[(180.0, 30.0)], compensator=comp)
    assert comp.net is not None and comp.net.train_rmse > comp.threshold
    assert not [r for r in res.reports if r.source.startswith("learned")]
    comp.threshold = comp.net.threshold = 10.0
    comp._residuals.extend([np.zeros(2)] * 10)
    norm = comp.norm()
    inside = (norm["x_min"] + norm["x_max"]) / 2
    query = type("Q", (), {"target": "position", "features": inside})()
    assert comp.predict(query) is not None
    query.features = norm["x_max"] + norm["x_std"]  # a whole training std beyond the learned range: refused
    assert comp.predict(query) is None and comp.off_domain == 1


def test_samples_only_after_convergence_and_queries_only_without_gnss(drive):
    from zennav.nav.navigator import Navigator

    nav = Navigator(drive.config.with_(learning=True, learn_after_s=30.0), drive.initial)
    samples, queries = [], []
    t0 = drive.initial.t_ns
    j = 0
    for k in range(1, len(drive.imu)):
        t = int(drive.imu.t_ns[k])
        while j < len(drive.gnss) and drive.gnss.t_ns[j] <= t:
            if not 100e9 <= drive.gnss.t_ns[j] - t0 < 120e9:
                nav.on_gnss(drive.gnss.fix_at(j))
            j += 1
        nav.on_imu(t, drive.imu.dtheta[k], drive.imu.dvel[k])
        samples += nav.pop_samples()
        queries += nav.pop_queries()
    assert {s.target for s in samples} == {q.target for q in queries} == {"position", "velocity", "drift"}
    assert min(s.t_ns - t0 for s in samples) >= 30e9
    assert all(100e9 < q.t_ns - t0 < 121e9 for q in queries)
    # No samples in the settling time after the outage.
    assert not any(120e9 <= s.t_ns - t0 < 130e9 for s in samples)
    rate = [q for q in queries if q.target == "position"]
    assert rate[0].features.shape == (len(RATE_FEATURES),) and samples[0].value.shape == (2,)
    assert rate[0].dt_s == pytest.approx(0.75, abs=0.02)  # 1.5 GNSS intervals at 2 Hz
    drift_q = [q for q in queries if q.target == "drift"]
    assert drift_q[0].features.shape == (len(DRIFT_FEATURES),)
    taus = [q.features[0] for q in drift_q]  # time since the last fix grows through the outage
    assert taus == sorted(taus) and taus[-1] > 19.0
    # Drift samples: the shadow INS error grows with its age (seeded run, MEMS IMU).
    drift = [s for s in samples if s.target == "drift"]
    old = [np.hypot(*s.value) for s in drift if s.features[0] > 40.0]
    young = [np.hypot(*s.value) for s in drift if s.features[0] < 5.0]
    assert np.median(old) > 5 * np.median(young)
