"""Learned DVL beam errors (seed 003): standardisation, bell-MF ANFIS numpy == torch, the improved PSO schedule and
the anomaly discrimination rule."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.learn import anfis_numpy
from zennav.learn.pso import IMPROVED, Swarm
from zennav.nav.dvl_anomaly import AnomalyRule, BeamDiscriminator
from zennav.nav.learning import FEATURES, MINMAX_FEATURES, OUTPUTS


def _beam_features(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Synthetic (innovation [m/s], lambda, R_vb [(m/s)^2]) and a beam error that grows with the innovation."""
    rng = np.random.default_rng(seed)
    innov = rng.normal(0.0, 0.02, n)
    lam = rng.chisquare(4, n)
    r_vb = 1e-4 * (1.0 + rng.random(n))
    x = np.column_stack([innov, lam, r_vb])
    y = 0.8 * innov + 0.002 * np.tanh(lam - 4.0) + rng.normal(0.0, 0.002, n)
    return x, y[:, None]


def test_dvl_beam_variant_is_declared():
    assert FEATURES["dvl_beam"] == ("innovation", "lambda", "r_vb") and OUTPUTS["dvl_beam"] == ("error",)
    assert MINMAX_FEATURES["dvl_beam"] == (1, 2)


def test_standardisation_z_score_and_min_max_round_trip():
    """Seed 003 step 3.1: the innovation z-scored, lambda and R in [0, 1]; the scaling inverts exactly."""
    x, y = _beam_features(500)
    norm = anfis_numpy.fit_normalization(x, y, minmax=MINMAX_FEATURES["dvl_beam"])
    xn = (x - norm["x_mean"]) / norm["x_std"]
    assert abs(xn[:, 0].mean()) < 1e-12 and abs(xn[:, 0].std() - 1.0) < 1e-12
    for j in (1, 2):
        assert xn[:, j].min() == pytest.approx(0.0, abs=1e-12) and xn[:, j].max() == pytest.approx(1.0)
    np.testing.assert_allclose(xn * norm["x_std"] + norm["x_mean"], x, rtol=1e-12, atol=1e-15)
    # the domain check works in the same units: half a range past the largest lambda is 0.5
    far = x[0].copy()
    far[1] = norm["x_max"][1] + 0.5 * (norm["x_max"][1] - norm["x_min"][1])
    assert anfis_numpy.domain_excess(norm, far) == pytest.approx(0.5)


def test_bell_anfis_numpy_equals_torch_with_the_seed_standardisation():
    """The trainer's torch ANFIS (generalised bell MFs) and the predictor's numpy forward give the same numbers."""
    torch = pytest.importorskip("torch")
    from zennav.learn.anfis_torch import TorchAnfis, TrainConfig, fit_anfis

    x, y = _beam_features(400, seed=1)
    fit = fit_anfis(x, y, n_rules=4, config=TrainConfig(method="ipso", max_epochs=3, seed=0),
                    minmax=MINMAX_FEATURES["dvl_beam"], device="cpu")
    assert np.all(fit.arrays["b"] > 0) and np.all(fit.arrays["a"] > 0)
    xn = (x - fit.norm["x_mean"]) / fit.norm["x_std"]
    y_np = anfis_numpy.forward(fit.arrays, xn)
    with torch.no_grad():
        y_t = TorchAnfis(fit.arrays, device="cpu").forward(xn).numpy()
    np.testing.assert_allclose(y_np, y_t, rtol=1e-10, atol=1e-12)
    assert fit.metrics["method"] == "ipso"
    assert fit.metrics["train_rmse"][0] < 0.5 * float(np.std(y))  # it learned the beam error


def test_improved_pso_schedule_and_convergence():
    """w 0.9 -> 0.4, c1 2.5 -> 0.5, c2 0.5 -> 2.5 linearly over max_iter (Shi-Eberhart 1998, Ratnaweera 2004)."""
    cfg = IMPROVED.__class__(**{**IMPROVED.__dict__, "max_iter": 11, "n_particles": 16})
    sphere = lambda p: np.sum((p - 0.3) ** 2, axis=1)  # noqa: E731
    swarm = Swarm(sphere, -np.ones(4), np.ones(4), cfg, seed=3)
    seen = []
    while swarm.iteration < cfg.max_iter:
        seen.append(swarm.coefficients())
        swarm.step()
    np.testing.assert_allclose(seen[0], (0.9, 2.5, 0.5))
    np.testing.assert_allclose(seen[5], (0.65, 1.5, 1.5))
    np.testing.assert_allclose(seen[-1], (0.4, 0.5, 2.5))
    assert swarm.best_f < 0.05 * swarm.history[0]


def test_discrimination_compensates_a_bias_jump_and_leaves_clean_beams_alone():
    rule = AnomalyRule(k_sigma=3.0, probability=0.99, window=5, min_count=3)
    disc = BeamDiscriminator(rule)
    R = np.full(4, 0.01**2)  # 1 cm/s beam noise
    ok, valid = np.ones(4, dtype=bool), np.ones(4, dtype=bool)
    rng = np.random.default_rng(0)
    for _ in range(20):  # clean: predicted errors of the size of the noise, lambda chi-square(4) distributed
        corr, dec = disc.decide(rng.normal(0, 0.01, 4) * 0.5, ok, valid, float(rng.chisquare(4)), R, 4)
        assert dec == ["normal"] * 4 and not np.any(corr)
    # beam 2 jumps by 0.2 m/s: the innovation fails the chi-square test at once
    pred = np.array([0.001, -0.002, 0.2, 0.0])
    corr, dec = disc.decide(pred, ok, valid, 400.0, R, 4)
    assert dec == ["normal", "normal", "compensated", "normal"] and corr[2] == 0.2 and corr[[0, 1, 3]].sum() == 0
    # later the VB R has grown and lambda is small: the persistent large prediction still compensates
    corr, dec = disc.decide(pred, ok, valid, 3.0, np.array([1e-4, 1e-4, 1e-3, 1e-4]), 4)
    assert dec[2] == "normal"  # 2 of 5: not yet persistent
    corr, dec = disc.decide(pred, ok, valid, 3.0, np.array([1e-4, 1e-4, 1e-3, 1e-4]), 4)
    assert dec[2] == "compensated" and corr[2] == 0.2
    # a large lambda alone (an INS error, small predicted errors) compensates nothing
    corr, dec = disc.decide(np.full(4, 0.005), ok, valid, 400.0, R, 4)
    assert dec == ["normal"] * 4
    corr, dec = disc.decide(pred, np.array([True, False, True, True]), np.array([True, True, True, False]), 400.0,
                            R, 3)
    assert dec == ["normal", "no_answer", "compensated", "invalid"]
    assert disc.counts["compensated"] == 3 and disc.counts["no_answer"] == 1 and disc.counts["invalid"] == 1
    st = disc.get_state()
    other = BeamDiscriminator(rule)
    other.set_state(st)
    assert other.get_state() == st


def test_rule_rejects_bad_thresholds():
    with pytest.raises(ValueError):
        AnomalyRule(min_count=6, window=5)


def _underwater_nav():
    """An engine with the learned tight DVL, 2.5 s after its start without GNSS (outage declared)."""
    from zennav.nav.navigator import Navigator
    from zennav.nav.types import NS, InitialState, NavConfig

    t0 = 1000 * NS
    nav = Navigator(NavConfig(has_dvl=True, learning=True, dvl_learned=True),
                    InitialState(t0, np.array([0.5, 1.0, -20.0]), np.array([1.5, 0.0, 0.0]), np.zeros(3)))
    for k in range(1, 251):
        nav.on_imu(t0 + k * NS // 100, [0.0, 0.0, 0.0], [0.0, 0.0, -0.0980665])
    assert nav.gnss_state != "valid"
    return nav


def _step(nav, n: int) -> None:
    for _ in range(n):
        nav.on_imu(nav.t_ns + 10_000_000, [0.0, 0.0, 0.0], [0.0, 0.0, -0.0980665])


def _dvl(nav, bias=(0.0, 0.0, 0.0, 0.0)):
    from zennav.nav.beams import janus_directions
    from zennav.nav.types import DvlSample

    B = janus_directions(nav.config.dvl_tilt, nav.config.dvl_layout)
    beams = B @ (nav.state.C_nb.T @ nav.state.v_n) + np.asarray(bias)
    return DvlSample(nav.t_ns, beams, np.ones(4, dtype=bool))


def test_training_target_is_the_beam_error_the_calibration_states_do_not_model():
    """The target of a training sample is the measured beam minus the filter's predicted beam with its calibration
    states: a beam bias the filter already estimates is not learned again (it would be corrected twice)."""
    nav = _underwater_nav()
    src = nav.sources["dvl"]
    from zennav.nav.eskf import N_STATES
    from zennav.nav.types import DvlSample

    nav._aug_x[src.bias.start - N_STATES + 2] = 0.05  # the filter's estimate of beam 3's bias [m/s]
    nav._aug_x[src.scale.start - N_STATES] = 0.01  # and of the scale-factor error
    B = src.B
    v_d = nav.state.C_nb.T @ nav.state.v_n
    beams = 1.01 * (B @ v_d) + np.array([0.2, 0.0, 0.05, 0.0])  # beam 1: 0.2 m/s not modelled; beam 3: its bias
    src._samples(nav, src.trial(nav, DvlSample(nav.t_ns, beams, np.ones(4, dtype=bool))))
    samples = nav.pop_samples()
    assert [s.target for s in samples] == ["dvl_beam"] * 4
    np.testing.assert_allclose([float(s.value[0]) for s in samples], [0.2, 0.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose([float(s.features[0]) for s in samples], [-0.2, 0.0, 0.0, 0.0], atol=1e-9)


def test_held_sample_is_fused_uncompensated_after_the_data_time_timeout():
    """Under water a DVL sample waits for its 4 beam answers; none comes: fused as measured after
    dvl_answer_timeout_s of data time, every beam counted no_answer."""
    nav = _underwater_nav()
    fused0 = nav.counters["dvl_fused"]
    assert nav.on_aid("dvl", _dvl(nav)) is False
    queries = nav.pop_queries()
    assert [q.beam for q in queries] == [0, 1, 2, 3] and all(q.target == "dvl_beam" for q in queries)
    assert queries[0].features.shape == (3,)
    _step(nav, 49)  # 0.49 s: still held
    assert nav.counters["dvl_fused"] == fused0 and nav.sources["dvl"].held is not None
    _step(nav, 2)
    assert nav.counters["dvl_fused"] == fused0 + 1 and nav.counters["dvl_learned_no_answer"] == 4
    assert nav.sources["dvl"].held is None
    report = [r for r in nav.pop_reports() if r.source == "dvl"][-1]
    assert "learned_no_answer_1" in report.faults and "corrected" not in report.faults


def test_answers_release_the_sample_and_the_rule_compensates_only_the_jumped_beam():
    nav = _underwater_nav()
    nav.pop_reports()
    nav.on_aid("dvl", _dvl(nav, bias=np.array([0.0, 0.0, 0.3, 0.0])))  # beam 3 jumps by 0.3 m/s
    queries = nav.pop_queries()
    lam = queries[0].features[1]
    assert lam > 13.3  # the jump fails the chi-square test (chi2 99 % of 4 dof)
    for q in queries[:3]:
        assert nav.on_correction(q, [0.3 if q.beam == 2 else 0.001], [0.01]) is False  # still waiting for beam 4
    nav.on_refusal(queries[3], "off_domain")  # the last settles it: released now
    c = nav.counters
    assert c["dvl_learned_compensated"] == 1 and c["dvl_learned_normal"] == 2 and c["dvl_learned_refused"] == 1
    report = [r for r in nav.pop_reports() if r.source == "dvl"][-1]
    assert report.fused and "corrected" in report.faults and "learned_compensated_3" in report.faults
    assert max(abs(x) for x in report.innovation) < 0.05  # the compensated beam agrees with the INS again
    # fused with its noise plus the correction squared (the model's uncertainty), the others at the nominal R
    assert report.innovation_var[2] > 0.3**2 + min(report.innovation_var[i] for i in (0, 1, 3))
    assert nav.sources["dvl"].status()["learned"]["compensated"] == 1


def test_replay_on_a_short_simulated_auv_trains_at_the_surface_and_answers_under_water():
    """The in-process loop of `zennav replay --target dvl_beam --compensation anfis-ipso` on sim:auv: training
    samples only while GNSS is valid, queries only under water, answered by a model trained at the surface, a
    bias jump on beam 2 under water compensated, every decision counted."""
    pytest.importorskip("torch")
    from dataclasses import replace

    from zennav.learn.loop import InProcessLoop
    from zennav.learn.settings import LearnSettings
    from zennav.replay import run_replay
    from zennav.sim.auv import make_auv_dataset

    ds = make_auv_dataset(duration_s=140.0, seed=1, surface_s=90.0, dvl_bottom_loss="", dvl_bias_jump="110:2:0.3")
    ds = replace(ds, config=ds.config.with_(vb_dvl=True))
    loop = InProcessLoop("dvl_beam", LearnSettings(optimizer="ipso", max_epochs=3, retrain_samples=10**6, seed=0))
    seen: dict[str, list] = {"samples": [], "queries": []}
    add, predict = loop.add, loop.predict

    def spy_add(samples):
        seen["samples"] += [s.t_ns for s in samples if s.target == "dvl_beam"]
        add(samples)

    def spy_predict(query):
        if query.target == "dvl_beam":
            seen["queries"].append(query.t_ns)
        return predict(query)

    loop.add, loop.predict = spy_add, spy_predict  # type: ignore[method-assign]
    res = run_replay(ds, compensator=loop)
    under = res.t_ns[res.outage]
    t_dive = int(under[0])
    assert seen["samples"] and max(seen["samples"]) < t_dive
    assert seen["queries"] and min(seen["queries"]) >= t_dive
    st = loop.status()
    assert st["trainer"]["sets_dvl_beam"] >= 1 and st["predictor"]["queries_answered"] > 100
    c = res.status["counters"]
    decided = sum(c.get(f"dvl_learned_{d}", 0) for d in ("compensated", "normal", "no_answer", "refused"))
    assert decided == len(seen["queries"])
    assert c.get("dvl_learned_compensated", 0) > 0 and c.get("dvl_learned_normal", 0) > 0


def test_trainer_publishes_signed_dvl_beam_sets_the_predictor_answers_and_a_saved_model_loads_frozen(tmp_path):
    """The services' cores: the trainer fits dvl_beam by the improved swarm and signs the set; the predictor
    verifies it (numpy only) and answers a beam query with the seed's standardisation; a loop's saved model loads
    into a frozen loop that answers the same and learns nothing."""
    pytest.importorskip("torch")
    import logging

    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    from zennav import messages as M
    from zennav.learn.loop import InProcessLoop
    from zennav.learn.settings import LearnSettings
    from zennav.learn.signing import Signer, Verifier
    from zennav.nav.learning import LearnQuery, LearnSample
    from zennav.nodes.predictor import PredictorNode
    from zennav.nodes.trainer import TrainerNode

    log = logging.getLogger("test")
    K = M.Keys("auv")
    key = Ed25519PrivateKey.generate()
    settings = LearnSettings(optimizer="ipso", min_samples=200, max_epochs=3, seed=1)
    published = []
    trainer = TrainerNode(lambda name, msg: published.append(msg), log, ("dvl_beam",), settings, signer=Signer(key))
    x, y = _beam_features(200, seed=2)
    samples = [LearnSample(10**12 + i * 10**8, "dvl_beam", x[i], y[i]) for i in range(200)]
    for s in samples:
        trainer.on_sample(M.learn_sample_msg(s))
    msg = trainer.train("dvl_beam")
    assert msg is not None and msg["metrics"]["method"] == "ipso" and msg["signature"]
    wire, reason = M.Validator().check(K.learn_model(msg["name"]), M.encode(dict(msg, src="t", seq=0, pub_ns=0)))
    assert reason == ""
    pred = PredictorNode(lambda m: None, log, verifier=Verifier(key.public_key()))
    assert pred.on_model(K.learn_model(msg["name"]), wire, 0)
    live = pred.live["dvl_beam"]
    np.testing.assert_allclose(live.norm["x_mean"][1:], x[:, 1:].min(axis=0))  # lambda, R: min-max
    np.testing.assert_allclose(live.norm["x_std"][1:], np.ptp(x[:, 1:], axis=0))
    query = LearnQuery(2 * 10**12, "dvl_beam", x[5], 0.0, beam=2)
    ans = pred.on_query(dict(M.learn_query_msg(query, 200), src="ins", seq=1))
    assert ans.get("refused") is None and abs(ans["value"][0] - y[5, 0]) < 0.02
    loop = InProcessLoop("dvl_beam", settings)
    loop.add(samples)
    path = tmp_path / "dvl_beam.msgpack"
    loop.save_model(path)
    frozen = InProcessLoop("dvl_beam", settings)
    frozen.load_model(path)
    value, _ = frozen.predict(query)
    assert value[0] == pytest.approx(loop.predict(query)[0][0])
    frozen.add(samples[:10])
    assert frozen.status()["trainer"]["ignored"] == 10 and frozen.learner.received == 0
    with pytest.raises(ValueError):
        InProcessLoop("drift", settings).load_model(path)


def test_a_held_sample_survives_a_checkpoint():
    """Navigator.get_state / set_state carry the held sample and the rule's memory: the restored engine releases
    it at the same data time with the same decisions."""
    nav = _underwater_nav()
    nav.on_aid("dvl", _dvl(nav, bias=(0.0, 0.3, 0.0, 0.0)))
    queries = nav.pop_queries()
    nav.on_correction(queries[1], [0.3], [0.01])
    other = _underwater_nav()
    other.set_state(nav.get_state())
    for engine in (nav, other):
        for q in (queries[0], queries[2]):
            engine.on_correction(q, [0.0], [0.01])
        _step(engine, 60)
    assert nav.counters == other.counters and nav.counters["dvl_learned_no_answer"] == 1
    assert nav.counters["dvl_learned_compensated"] == 1
    np.testing.assert_array_equal(nav.state.v_n, other.state.v_n)
