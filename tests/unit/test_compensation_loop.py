"""The in-process learning loop: training samples while GNSS is good, queries during an outage, learned
corrections fused as pseudo-measurements; deterministic."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.learn.learner import ElmanOnline
from zennav.learn.loop import InProcessLoop, make_compensator
from zennav.learn.settings import LearnSettings
from zennav.nav.learning import BODY_FEATURES, DRIFT_FEATURES, RATE_FEATURES, TARGETS
from zennav.nav.navigator import Navigator
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
    # one scheduled fit (at min_samples) and one at the outage's first query, through every sample before it
    st = comp.status()
    tc, pc = st["trainer"], st["predictor"]
    assert (tc["sets_position"], pc["sets_accepted"], pc["live_version_position"]) == (2, 2, 2)
    seen = comp.core.live["position"].samples_seen  # the outage's start; the samples after it were not needed
    assert comp.learner.through == seen > comp.settings.min_samples and comp.learner.received > seen
    assert st["link"]["queries"] == pc["queries_answered"] + pc.get("queries_off_domain", 0) >= len(learned)
    # Deterministic: the same run gives the same solution.
    again = run_replay(drive, outages=[(180.0, 30.0)], compensator=make_compensator("anfis", "position"))
    assert np.array_equal(again.llh, res.llh)


def test_elman_predicts_only_under_its_error_threshold(drive):
    """Seed 002: the network predicts only while its training error is under the threshold. On this drive the
    per-interval corrections are GNSS noise (no learnable drift), so no set is made and the loop stays silent."""
    comp = InProcessLoop("position", LearnSettings(model="elman", window=200))  # fills before the outage (2 Hz)
    res = run_replay(drive, outages=[(180.0, 30.0)], compensator=comp)
    net = comp.learner.elman.net
    assert net is not None and net.train_rmse > comp.settings.threshold
    assert not [r for r in res.reports if r.source.startswith("learned")]
    st = comp.status()
    tc = st["trainer"]
    assert tc["elman_not_ready_position"] == tc["fit_points_position"] >= 2
    assert st["predictor"]["queries_no_model"] == st["link"]["queries"] > 0


def test_loop_refuses_queries_outside_the_training_range():
    """A whole training std beyond the learned range: refused (off_domain), inside it answered."""
    from zennav.nav.learning import LearnQuery, LearnSample

    rng = np.random.default_rng(5)
    comp = InProcessLoop("position", LearnSettings(model="elman", window=200, min_samples=100, threshold=10.0))
    x = rng.normal(size=(300, len(RATE_FEATURES)))
    comp.add([LearnSample(int(k * 5e8), "position", x[k], 0.1 * x[k, :2]) for k in range(300)])
    comp.settle()  # the scheduled fits through these samples
    norm = comp.learner.elman.norm()
    inside = (norm["x_min"] + norm["x_max"]) / 2
    assert comp.predict(LearnQuery(0, "position", inside, 1.0)) is not None
    assert comp.predict(LearnQuery(0, "position", norm["x_max"] + norm["x_std"], 1.0)) is None
    assert comp.status()["predictor"]["queries_off_domain"] == 1


def test_body_velocity_correction_observes_the_velocity_error(drive):
    """A body velocity answer (here the true one) pulls an INS velocity error back; a wrong-size answer is
    refused and counted."""
    from zennav.nav.learning import LearnQuery
    from zennav.nav.navigator import Navigator

    nav = Navigator(drive.config.with_(learning=True), drive.initial)
    run_replay(drive, navigator=nav)
    s = nav.state
    v0_n, v_b = s.v_n.copy(), s.C_nb.T @ s.v_n
    s.vn += 1.0  # an INS velocity error of 1 m/s north, and a covariance that admits it
    nav.kf.P[3:6, 3:6] += np.eye(3)
    q = LearnQuery(nav.t_ns, "body_velocity", np.zeros(len(BODY_FEATURES)), 1.0)
    assert not nav.on_correction(q, [0.0, 0.0], [0.1, 0.1])  # 2 values for a 3-output target
    assert nav.counters["correction_malformed"] == 1
    assert nav.on_correction(q, v_b, [0.05, 0.05, 0.05])
    assert np.abs(nav.state.v_n - v0_n).max() < 0.1
    assert nav.counters["learned_body_velocity_fused"] == 1


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
    # every target of the INS (dvl_beam comes only from a DVL: zennav.nav.aid.dvl_learned)
    assert {s.target for s in samples} == {q.target for q in queries} == set(TARGETS) - {"dvl_beam"}
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
    # Body velocity: one sample per fused fix (features over the last second) and one query per second of
    # outage; a car moves forward (sideslip and vertical speed are small against its speed).
    body = [s for s in samples if s.target == "body_velocity"]
    body_q = [q for q in queries if q.target == "body_velocity"]
    assert body[0].features.shape == (len(BODY_FEATURES),) and body[0].value.shape == (3,)
    assert np.median(np.diff([s.t_ns for s in body])) == 5e8  # 2 Hz GNSS
    assert 18 <= len(body_q) <= 21 and all(1.0 <= q.dt_s < 2.0 for q in body_q)
    assert np.median([q.dt_s for q in body_q]) == pytest.approx(1.0, abs=0.02)
    v_b = np.array([s.value for s in body])
    assert np.median(v_b[:, 0]) > 5.0 and np.all(np.abs(v_b[:, 1:]) < 0.1 * np.abs(v_b[:, :1]) + 0.2)
    # Drift samples: the shadow INS error grows with its age (seeded run, MEMS IMU).
    drift = [s for s in samples if s.target == "drift"]
    old = [np.hypot(*s.value) for s in drift if s.features[0] > 40.0]
    young = [np.hypot(*s.value) for s in drift if s.features[0] < 5.0]
    assert np.median(old) > 5 * np.median(young)


def test_body_velocity_window_slides_by_gnss_intervals_and_restarts_after_an_outage():
    """Samples: mean increments over the whole GNSS intervals covering the last second; a rate query in between
    (an outage) restarts the window, so no sample mixes data from both sides of a gap."""
    from zennav.nav.learning import LearningTap
    from zennav.nav.rotation import euler_to_quat
    from zennav.nav.strapdown import NavState

    s = NavState.from_arrays([0.7, 0.2, 10.0], [3.0, 4.0, 0.0], euler_to_quat([0.0, 0.0, 0.0]))
    tap = LearningTap(body_every_s=1.0)
    dt, t = 0.01, 0
    for k in range(200):  # 2 s at 100 Hz, a fix every 0.25 s; the specific force x ramps with k
        dv = (0.001 * k * dt, 0.0, -9.8 * dt)
        tap.on_step((0.0,) * 3, dv, (0.0,) * 3, dv, dt)
        t += 10_000_000
        if (k + 1) % 25 == 0:
            tap.on_fix(t, s, np.zeros(15), True, [0.0] * 3, [0.0] * 3, (0.0,) * 3, (0.0,) * 3)
    body = [x for x in tap.samples if x.target == "body_velocity"]
    assert [x.t_ns for x in body] == [1_000_000_000 + 250_000_000 * i for i in range(5)]
    assert body[-1].features[0] == pytest.approx(0.001 * np.mean(np.arange(100, 200)))  # the last second
    assert body[-1].value == pytest.approx([3.0, 4.0, 0.0])  # level, heading north: v_b = v_n
    tap.samples.clear()
    for _ in range(150):  # 1.5 s without a fix: a rate query splits the window
        tap.on_step((0.0,) * 3, (0.0, 0.0, -9.8 * dt), (0.0,) * 3, (0.0, 0.0, -9.8 * dt), dt)
        t += 10_000_000
        tap.maybe_query(t, s, 0.25)
    tap.on_fix(t, s, np.zeros(15), True, [0.0] * 3, [0.0] * 3, (0.0,) * 3, (0.0,) * 3)
    assert not [x for x in tap.samples if x.target == "body_velocity"]  # less than 1 s since the window restarted


def test_elman_sigma_is_that_of_the_network_running_free():
    """A target the features do not explain (a random walk): the learning network follows it from sample to
    sample, a frozen copy (as in an outage) cannot, and the 1-sigma is the frozen copy's."""
    from zennav.learn import anfis_numpy
    from zennav.learn.elman import Elman
    from zennav.learn.sigma import answer_sigma
    from zennav.nav.learning import BODY_FEATURES

    rng = np.random.default_rng(11)
    n = 1200
    x = rng.normal(size=(n, len(BODY_FEATURES)))
    y = np.cumsum(rng.normal(0.0, 0.05, (n, 3)), axis=0)
    s = LearnSettings(model="elman", window=200, free_run_s=30.0)
    comp = ElmanOnline("body_velocity", s)
    for k in range(n):
        comp.add(int(k * 1e9), x[k], y[k])
    # the one-step residuals of the same network, learning as the online one does
    net = Elman(len(BODY_FEATURES), s.n_hidden, 3, window=s.window, threshold=s.threshold,
                norm=anfis_numpy.fit_normalization(x[:s.window], y[:s.window]), seed=s.seed)
    net.set_aligned()
    one_step = []
    for k in range(n):
        if net.ready:
            one_step.append(net.predict(x[k]) - y[k])
        net.learn(x[k], y[k])
    one_step_sigma = answer_sigma(np.array(one_step[-s.window:]))[0]
    assert np.all(comp.std() > 1.5 * one_step_sigma), (comp.std(), one_step_sigma)


def test_elman_starts_after_min_samples_and_its_normalisation_follows_the_window():
    """Learning starts with the normalisation of the first min_samples samples; every min_samples samples it is
    refit from the window's samples (here: targets whose level moves, so the first ones would misscale later)."""

    rng = np.random.default_rng(3)
    n = 700
    x = rng.normal(size=(n, len(BODY_FEATURES))) + np.linspace(0.0, 5.0, n)[:, None]
    y = rng.normal(size=(n, 3)) + np.linspace(0.0, 20.0, n)[:, None]
    comp = ElmanOnline("body_velocity", LearnSettings(model="elman", window=300, min_samples=100))
    for k in range(99):
        comp.add(int(k * 1e9), x[k], y[k])
    assert comp.net is None
    comp.add(int(99e9), x[99], y[99])
    np.testing.assert_allclose(comp.net.y_mean, y[:100].mean(axis=0))
    for k in range(100, n):
        comp.add(int(k * 1e9), x[k], y[k])
    assert comp.learned == n  # the first 100 too, once the network exists; refits at 100, 200, .. 700 learned
    last = slice(n - 300, n)  # the window at the last refit
    np.testing.assert_allclose(comp.net.x_mean, x[last].mean(axis=0))
    np.testing.assert_allclose(comp.net.y_std, y[last].std(axis=0))
    np.testing.assert_allclose(comp.net.win_y, (y[last] - comp.net.y_mean) / comp.net.y_std, atol=1e-9)


def test_body_features_are_the_time_weighted_mean_and_spread_of_the_rates():
    """FeatureWindow.body_features: mean and standard deviation of f_b and omega_ib_b over uneven IMU intervals,
    as numpy's weighted statistics of the per-interval rates; a zero-length interval changes nothing."""
    from zennav.nav.learning import FeatureWindow

    rng = np.random.default_rng(11)
    dt = rng.uniform(0.004, 0.006, 200)
    f, w = rng.normal(0.0, 2.0, (200, 3)) + [0.5, -0.2, -9.8], rng.normal(0.0, 0.1, (200, 3))
    win = FeatureWindow()
    for k in range(200):
        win.add(w[k] * dt[k], f[k] * dt[k], dt[k])
    win.add([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.0)
    rates = np.hstack([f, w])
    mean = np.average(rates, axis=0, weights=dt)
    std = np.sqrt(np.average((rates - mean) ** 2, axis=0, weights=dt))
    feats = win.body_features()
    assert feats.shape == (len(BODY_FEATURES),)
    np.testing.assert_allclose(feats, np.concatenate([mean, std]), rtol=1e-9, atol=1e-12)


def test_a_compensator_of_another_target_runs_without_the_drift_shadows(drive):
    """run_replay turns the drift target's shadow INSs off for a body_velocity compensator: the same solution."""
    engines: list = []
    res = run_replay(drive, outages=[(180.0, 30.0)], compensator=make_compensator("elman", "body_velocity"),
                     on_epoch=engines.append)
    with_shadows = run_replay(drive, outages=[(180.0, 30.0)], compensator=make_compensator("elman", "body_velocity"),
                              navigator=Navigator(drive.config.with_(learning=True), drive.initial))
    assert np.array_equal(res.llh, with_shadows.llh) and np.array_equal(res.q_nb, with_shadows.q_nb)
    assert any(r.source == "learned_body_velocity" and r.fused for r in res.reports)
    tap = engines[-1].tap
    assert tap is not None and not tap.drift and tap.shadows == []


def test_block_loop_and_deferred_fits_give_the_step_wise_run_of_the_trainer(drive):
    """With a compensator the block loop runs from one learning event to the next (Navigator.run_imu) and the
    in-process loop makes its scheduled fits only when a set may be used (InProcessLoop.settle): the same rows,
    reports, counters and sets as the step-wise run with a loop that fits as the samples arrive (the trainer)."""

    class Eager(InProcessLoop):  # the trainer's cadence: every fit as soon as its samples are in
        def add(self, samples):
            super().add(samples)
            self.settle()

    settings = LearnSettings(model="elman", min_samples=100, retrain_samples=20)
    step_loop, block_loop = Eager("body_velocity", settings), InProcessLoop("body_velocity", settings)
    step = run_replay(drive, outages=[(180.0, 30.0)], compensator=step_loop, loop="step")
    epochs: list[int] = []
    block = run_replay(drive, outages=[(180.0, 30.0)], compensator=block_loop, loop="python",
                       on_epoch=lambda nav: epochs.append(nav.t_ns), epoch_due=lambda: 2**62)  # none due: stretches
    assert len(epochs) < len(block.t_ns) // 10  # stretches, not samples
    for a, b in ((step.t_ns, block.t_ns), (step.llh, block.llh), (step.v_n, block.v_n), (step.q_nb, block.q_nb),
                 (step.std_pos_ned, block.std_pos_ned), (step.outage, block.outage)):
        assert np.array_equal(a, b)
    assert repr(step.status) == repr(block.status)
    assert [vars(r) for r in step.reports] == [vars(r) for r in block.reports]
    assert any(r.source == "learned_body_velocity" and r.fused for r in block.reports)
    last_query = max(r.t_ns for r in block.reports if r.source == "learned_body_velocity")
    assert block_loop.last_set is not None and block_loop.last_set["created_t_ns"] <= last_query  # none after it
    assert step_loop.last_set is not None and step_loop.last_set["created_t_ns"] > last_query
    assert block_loop.status() == step_loop.status()  # settled: the trainer's sets and counters
