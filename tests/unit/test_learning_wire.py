"""The learning loop's transport-free parts: parameter sets on the wire (model_params <-> paramset), the predictor's
validation and swap, the ins's query/answer matching and the trainer's schedule (issue 6)."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from zennav import messages as M
from zennav.learn import anfis_numpy, paramset
from zennav.nav.learning import BODY_FEATURES, DRIFT_FEATURES, LearnQuery, LearnSample

K = M.Keys("car")
N_IN = len(DRIFT_FEATURES)
LOG = logging.getLogger("test")


def _set(version=1, seed=0, n_in=N_IN, name="anfis-drift", metrics=None):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(40, n_in))
    arrays = anfis_numpy.cluster_rulebase(x, 3, seed=seed)
    arrays["consequents"] = rng.normal(size=(3, n_in + 1, 2))
    norm = anfis_numpy.fit_normalization(x, rng.normal(size=(40, 2)))
    return paramset.build(name, version, arrays, norm, metrics or {"target": "drift", "sigma": [0.3, 0.4]},
                          created_t_ns=5)


def _wire(msg: dict) -> dict:
    """Through the codec and the bus validator, as a subscriber gets it."""
    msg = dict(msg, src="t", seq=0, pub_ns=0)
    back, reason = M.Validator().check(K.learn_model(msg["name"]), M.encode(msg))
    assert reason == "", reason
    return back


def test_model_params_round_trip_is_byte_exact_and_checksum_verified():
    ps = _set()
    back = M.paramset_of(_wire(M.model_params_msg(ps)))
    assert back == ps  # every array's bytes, the metrics and the trainer's checksum, unchanged
    live = paramset.validate(back, n_in=N_IN, n_out=2, name="anfis-drift")
    assert live.checksum == ps["checksum"] and live.arrays["rules"].dtype == np.int64


def test_model_params_tampering_and_bad_arrays_are_rejected():
    m = M.model_params_msg(_set())
    m["arrays"]["c"]["data"][0] += 1e-12
    with pytest.raises(paramset.ParamSetRejected) as e:
        paramset.validate(M.paramset_of(_wire(m)))
    assert e.value.reason == "checksum"
    m = M.model_params_msg(_set())
    m["arrays"]["rules"]["data"][0] = 0.5  # a float in the int64 rule table
    with pytest.raises(paramset.ParamSetRejected) as e:
        paramset.validate(M.paramset_of(_wire(m)))
    assert e.value.reason == "schema"
    m = M.model_params_msg(_set())
    del m["format"]  # an old-style model_params set is not a paramset
    with pytest.raises(paramset.ParamSetRejected) as e:
        paramset.validate(M.paramset_of(_wire(m)))
    assert e.value.reason == "schema"


def test_learn_query_and_correction_messages_validate():
    q = M.learn_query_msg(LearnQuery(10, "drift", np.arange(N_IN, dtype=float), 1.5))
    q.update(src="ins.x", seq=7, pub_ns=0)
    back, reason = M.Validator().check(K.learn_query(), M.encode(q))
    assert reason == "" and back["features"] == list(map(float, range(N_IN)))
    c = M.correction_msg(back, np.array([1.0, 2.0]), (0.1, 0.2), "anfis-drift", 3)
    c.update(src="p", seq=0, pub_ns=0)
    back, reason = M.Validator().check(K.learn_correction(), M.encode(c))
    assert reason == ""
    assert (back["query_src"], back["query_seq"], back["kind"], back["t_ns"]) == ("ins.x", 7, "drift", 10)
    s = M.learn_sample_msg(LearnSample(10, "drift", np.zeros(N_IN), np.array([1.0, -1.0])))
    s.update(src="i", seq=0, pub_ns=0)
    assert M.Validator().check(K.learn_samples(), M.encode(s))[1] == ""


def test_predictor_swaps_validated_sets_and_keeps_the_live_one_on_rejection():
    from zennav.nodes.predictor import PredictorNode

    out, bus_rej = [], []
    node = PredictorNode(out.append, LOG, bus_reject=lambda k, r: bus_rej.append(r))
    key = K.learn_model("anfis-drift")
    q = dict(M.make("learn_query", 1, target="drift", features=[0.5] * N_IN, dt_s=1.0), src="ins", seq=0)
    assert node.on_query(q)["refused"] == "no_model" and node.core.queries["no_model"] == 1
    v1 = _set(1, seed=1)
    assert node.on_model(key, _wire(M.model_params_msg(v1)), 0)
    assert not node.on_model(key, _wire(M.model_params_msg(v1)), 0)  # the same set again: a duplicate
    assert node.core.sets["duplicate"] == 1 and node.core.sets["rejected"] == 0
    for bad in (_set(1, seed=2), _set(2, seed=3, n_in=N_IN - 1), _set(3, seed=4, name="other"),
                _set(4, seed=5, metrics={"sigma": [0.3, 0.4]})):
        assert not node.on_model(key, _wire(M.model_params_msg(bad)), 0)
    assert dict(node.core.rejected) == {"model_stale_version": 1, "model_shape": 1, "model_schema": 2}
    assert len(bus_rej) == 4 and node.live["drift"].version == 1
    a = node.on_query(q)
    live = paramset.validate(v1)
    assert a["version"] == 1 and a["std"] == [0.3, 0.4] and a["query_seq"] == 0
    assert np.array_equal(a["value"], anfis_numpy.predict(live.arrays, live.norm, np.full(N_IN, 0.5)))
    assert node.on_model(key, _wire(M.model_params_msg(_set(9, seed=9))), 0)
    assert node.on_query(q)["version"] == 9 and node.counters()["live_version_drift"] == 9


def test_predictor_refuses_queries_outside_the_training_range():
    from zennav.nodes.predictor import PredictorNode

    out = []
    node = PredictorNode(out.append, LOG, max_domain_excess=0.5)
    ps = _set(1, seed=1)
    assert node.on_model(K.learn_model("anfis-drift"), _wire(M.model_params_msg(ps)), 0)
    norm = paramset.validate(ps).norm
    inside = (norm["x_min"] + norm["x_max"]) / 2
    edge = inside.copy()
    edge[4] = norm["x_max"][4] + 0.4 * norm["x_std"][4]  # 0.4 std beyond the range: still answered
    far, below = inside.copy(), inside.copy()
    far[4] = norm["x_max"][4] + 0.6 * norm["x_std"][4]
    below[0] = norm["x_min"][0] - 2.0 * norm["x_std"][0]
    assert anfis_numpy.domain_excess(norm, inside) == 0.0
    assert anfis_numpy.domain_excess(norm, far) == pytest.approx(0.6)

    def query(x):
        return node.on_query(dict(M.make("learn_query", 1, target="drift", features=list(map(float, x)), dt_s=1.0),
                                  src="ins", seq=0))

    assert "refused" not in query(inside) and "refused" not in query(edge)
    assert query(far)["refused"] == query(below)["refused"] == "off_domain"
    assert node.core.queries["off_domain"] == 2 and node.core.queries["answered"] == 2 and len(out) == 4


class _FakeNav:
    def __init__(self):
        self.t_ns = 0
        self.samples, self.queries, self.fused, self.refused = [], [], [], []

    def pop_samples(self):
        s, self.samples = self.samples, []
        return s

    def pop_queries(self):
        q, self.queries = self.queries, []
        return q

    def on_correction(self, q, value, std):
        self.fused.append((q.t_ns, list(value), list(std)))
        return True

    def on_refusal(self, q, reason):
        self.refused.append((q.t_ns, reason))


def test_ins_learning_link_matches_answers_to_pending_queries():
    from zennav.learn.link import LearningLink
    from zennav.messages.learn import refusal_msg

    sent = []

    def publish(kind, msg):
        msg.update(src="ins.a", seq=len(sent), pub_ns=0)  # what the bus publisher stamps
        sent.append((kind, msg))

    link = LearningLink(publish, LOG, ("drift",), max_age_s=1.0)
    nav = _FakeNav()
    nav.samples = [LearnSample(1, "drift", np.zeros(N_IN), np.zeros(2)), LearnSample(1, "position", np.zeros(11),
                                                                                      np.zeros(2)),
                   LearnSample(2, "drift", np.zeros(N_IN), np.zeros(2))]
    nav.t_ns = 10**9
    nav.queries = [LearnQuery(10**9, "drift", np.zeros(N_IN), 1.0), LearnQuery(10**9, "position", np.zeros(11), 0.5)]
    link.after_imu(nav)
    assert [k for k, _ in sent] == ["sample", "sample", "query"]  # only the configured target
    q = sent[2][1]
    assert q["n_samples"] == 2  # the drift samples sent before it

    def answer(query, **kw):
        return {**M.correction_msg(query, [1.0, 2.0], [0.5, 0.5], "anfis-drift", 4), **kw}

    assert link.on_correction(nav, answer(q)) and nav.fused == [(10**9, [1.0, 2.0], [0.5, 0.5])]
    assert not link.on_correction(nav, answer(q))  # answered twice: the second is dropped
    assert not link.on_correction(nav, answer(q, query_src="ins.other"))
    nav.t_ns = 4 * 10**9
    nav.queries = [LearnQuery(nav.t_ns, "drift", np.zeros(N_IN), 1.0)]
    link.after_imu(nav)
    assert not link.on_correction(nav, refusal_msg(sent[-1][1], "off_domain")) and len(nav.fused) == 1
    assert nav.refused == [(nav.t_ns, "off_domain")]  # the engine is told (a held DVL sample stops waiting)
    nav.queries = [LearnQuery(nav.t_ns, "drift", np.zeros(N_IN), 1.0)]
    link.after_imu(nav)
    nav.t_ns += 5 * 10**9
    link.after_imu(nav)  # never answered: expires
    st = link.status()
    assert (st["fused"], st["unmatched"], st["refused_off_domain"], st["unanswered"], st["pending"], st["queries"],
            st["samples"]) == (1, 2, 1, 1, 0, 3, 2)
    assert (st["model"], st["version"], st["lockstep"]) == ("anfis-drift", 4, False)


def test_ins_learning_link_in_lockstep_waits_for_the_answer_before_returning():
    """Lockstep: after_imu returns only once its queries are answered, fused by the answer thread while it waits
    on the shared lock (held by the caller, as the serial bus's callback lock is); a missing answer times out."""
    import threading

    from zennav.learn.link import LearningLink

    lock = threading.RLock()
    sent = []

    def publish(kind, msg):
        msg.update(src="ins.a", seq=len(sent), pub_ns=0)
        sent.append((kind, msg))
        if kind == "query" and len(sent) == 1:
            def reply():
                with lock:  # the correction callback runs under the bus's callback lock
                    link.on_correction(nav, M.correction_msg(msg, [1.0, 2.0], [0.5, 0.5], "anfis-drift", 1))
            threading.Thread(target=reply).start()

    link = LearningLink(publish, LOG, ("drift",), max_age_s=1.0, lockstep_timeout_s=10.0, lock=lock)
    nav = _FakeNav()
    nav.queries = [LearnQuery(0, "drift", np.zeros(N_IN), 1.0)]
    with lock:  # the sensor callback holds it
        link.after_imu(nav)
        assert nav.fused == [(0, [1.0, 2.0], [0.5, 0.5])]  # fused before after_imu returned
    link.lockstep_timeout_s = 0.05
    nav.queries = [LearnQuery(0, "drift", np.zeros(N_IN), 1.0)]
    with lock:
        link.after_imu(nav)  # nobody answers
    assert link.counts["lockstep_timeouts"] == 1 and link.status()["pending"] == 1


def _samples(n, target="drift", seed=0, t0=0):
    """Learnable synthetic samples of a target (features, a smooth function of them)."""
    from zennav.nav.learning import FEATURES, OUTPUTS

    rng = np.random.default_rng(seed)
    n_in, n_out = len(FEATURES[target]), len(OUTPUTS[target])
    x = rng.normal(size=(n, n_in))
    y = np.stack([np.tanh(x[:, k]) + 0.3 * x[:, k + 1] for k in range(n_out)], axis=1) + rng.normal(0, 0.05, (n, n_out))
    return [LearnSample(t0 + int(i * 25e7), target, x[i], y[i]) for i in range(n)]


def test_trainer_schedule_in_sample_counts_and_published_set_accepted_by_the_predictor():
    pytest.importorskip("torch")
    from zennav.learn.settings import LearnSettings
    from zennav.nodes.predictor import PredictorNode
    from zennav.nodes.trainer import TrainerNode

    published = []
    node = TrainerNode(lambda name, msg: published.append((name, msg)), LOG, ("drift",),
                       LearnSettings(min_samples=100, retrain_samples=120, max_epochs=3))
    for s in _samples(99):
        node.on_sample(M.learn_sample_msg(s))
    node.on_sample(M.make("learn_sample", 0, features=[0.0], target=[0.0, 0.0], variant="drift"))  # bad shape
    node.on_sample(M.make("learn_sample", 0, features=[0.0], target=[0.0], variant="position"))  # not learned
    assert node.due() == [] and node.counts["ignored_shape"] == node.counts["ignored_variant"] == 1
    rest = _samples(150, seed=1, t0=10**12)
    node.on_sample(M.learn_sample_msg(rest[0]))
    assert node.due() == ["drift"]  # min_samples held: the first scheduled fit
    node.seen_version("drift", 6)  # a set v6 exists on the bus: continue above it
    msg = node.train("drift")
    assert node.due() == [] and published[0][0] == "anfis-drift" and msg["version"] == 7
    assert msg["metrics"]["samples_seen"] == msg["metrics"]["samples"] == 100 and msg["metrics"]["n_rules"] == 1
    for s in rest[1:30]:
        node.on_sample(M.learn_sample_msg(s))
    q = dict(M.learn_query_msg(LearnQuery(1, "drift", np.zeros(N_IN), 1.0), 125), src="ins", seq=0)
    node.on_query(q)  # a query through 125 samples: due once those are in (129 are)
    assert node.due() == ["drift"] and node.train("drift")["metrics"]["samples_seen"] == 125
    node.on_query(q)  # the latest set is through 125 already
    assert node.due() == []
    for s in rest[30:]:
        node.on_sample(M.learn_sample_msg(s))
    assert node.train("drift")["metrics"]["samples_seen"] == 220  # scheduled: 100 + 120
    pred = PredictorNode(lambda m: None, LOG)
    assert pred.on_model(K.learn_model("anfis-drift"), _wire(msg), 0) and pred.live["drift"].version == 7
    c = node.counters()
    assert (c["sets_drift"], c["through_drift"], c["received_drift"], c["version_drift"]) == (3, 220, 249, 9)
    by_mean = sum(m["metrics"]["skill"].count(0) for _, m in published)  # outputs the mean answers, counted
    assert c["outputs_by_mean_drift"] == by_mean and all(len(m["metrics"]["skill"]) == 2 for _, m in published)


@pytest.mark.parametrize("compensation", ["anfis", "anfis-pso", "elman"])
def test_trainer_and_in_process_loop_make_the_same_sets_and_answers(compensation):
    """The trainer's node (on its wire messages, a query's n_samples) and the in-process loop (the replay's calls),
    fed the same samples and queries, fit at the same points and make the same sets, bit for bit (arrays,
    normalisation, sigma), and the predictor answers as the in-process loop does. The ANFIS loop fits in a child
    process (zennav.learn.fit_worker, as `zennav replay` runs them), the node in its own."""
    if compensation != "elman":
        pytest.importorskip("torch")
    from zennav.learn.fit_worker import FitWorker
    from zennav.learn.loop import make_compensator
    from zennav.nodes.predictor import PredictorNode
    from zennav.nodes.trainer import TrainerNode

    loop = make_compensator(compensation, "body_velocity", seed=3, fit_worker=True)
    assert (loop.fitter is not None) == (compensation != "elman")
    loop.close()
    settings = loop.settings.with_(min_samples=120, retrain_samples=150, max_epochs=4)
    if compensation == "elman":
        settings = settings.with_(window=150, threshold=5.0, free_run_s=10.0)
    loop = type(loop)("body_velocity", settings, None if compensation == "elman" else FitWorker().start())
    published = []
    node = TrainerNode(lambda name, msg: published.append(msg), LOG, ("body_velocity",), settings)
    pred = PredictorNode(lambda m: None, LOG)
    samples = _samples(400, "body_velocity", seed=4)
    qx = samples[0].features * 0.5
    answers_loop, answers_bus = [], []
    for k, (a, b) in enumerate(((0, 200), (200, 330), (330, 400))):  # an "outage" after each chunk
        loop.add(samples[a:b])
        for s in samples[a:b]:
            node.on_sample(M.learn_sample_msg(s))
        for t in range(2):  # two queries per outage: the first fits through b, the second reuses that set
            query = LearnQuery(10**13 + k * 10**10 + t, "body_velocity", qx, 1.0)
            answers_loop.append(loop.predict(query))
            q = dict(M.learn_query_msg(query, b), src="ins", seq=2 * k + t)
            node.on_query(q)
            while node.due():
                pm = node.train("body_velocity")
                if pm is not None:
                    assert pred.on_model(K.learn_model(pm["name"]), _wire(pm), 0)
            a_bus = pred.on_query(q)
            answers_bus.append(None if "refused" in a_bus else (a_bus["value"], a_bus["std"]))
    live_loop = loop.core.live["body_velocity"]
    points = [120, 200, 270, 330, 400]  # min_samples, query, min + retrain, query, query
    assert [m["metrics"]["samples_seen"] for m in published] == points[compensation == "elman":]  # (not ready at 120)
    assert loop.learner.counts["fit_points"] == node.learners["body_velocity"].counts["fit_points"] == 5
    assert loop.status()["trainer"]["sets_body_velocity"] == len(published) and loop.version == published[-1]["version"]
    live_bus = pred.live["body_velocity"]
    for k in ("arrays", "norm"):
        for name, v in getattr(live_loop, k).items():
            assert np.array_equal(v, getattr(live_bus, k)[name]), (k, name)
    assert live_loop.std == live_bus.std  # (the metrics differ: the fit's wall time)
    assert len(answers_loop) == 6 and all(a is not None for a in answers_loop)
    for al, ab in zip(answers_loop, answers_bus):
        assert np.array_equal(al[0], ab[0]) and list(al[1]) == ab[1]
    if compensation == "anfis":  # sets that answer something beyond the target's mean, trained past epoch 0
        assert any(1 in m["metrics"]["skill"] and m["metrics"]["epochs"] > 0 for m in published)
    loop.close()


def test_body_velocity_sets_have_three_outputs_end_to_end():
    """The 3-output target (forward, right, down body velocity) through trainer, wire and predictor; a set with
    the wrong output count for its target is refused."""
    pytest.importorskip("torch")
    from zennav.learn.settings import LearnSettings
    from zennav.nodes.predictor import PredictorNode
    from zennav.nodes.trainer import TrainerNode

    published = []
    node = TrainerNode(lambda name, msg: published.append(msg), LOG, ("body_velocity",),
                       LearnSettings(min_samples=200, retrain_samples=200, max_epochs=3))
    rng = np.random.default_rng(2)
    n_in = len(BODY_FEATURES)
    node.on_sample(M.make("learn_sample", 0, features=[0.0] * n_in, target=[0.0, 0.0], variant="body_velocity"))
    assert node.counts["ignored_shape"] == 1  # two values for a three-output target
    for i in range(200):
        x, e = rng.normal(size=n_in), rng.normal(0.0, 0.1, 3)
        node.on_sample(M.make("learn_sample", i, features=list(x), target=list([10 + x[0], 0.5 * x[5], 0.0] + e),
                              variant="body_velocity"))
    msg = node.train("body_velocity")
    assert len(msg["metrics"]["sigma"]) == 3 and msg["metrics"]["sigma"][0] < 0.5
    pred = PredictorNode(lambda m: None, LOG)
    key = K.learn_model("anfis-body_velocity")
    assert pred.on_model(key, _wire(msg), 0)
    q = dict(M.make("learn_query", 1, target="body_velocity", features=[0.1] * n_in, dt_s=1.0), src="ins", seq=3)
    a = pred.on_query(q)
    assert len(a["value"]) == 3 and a["std"] == msg["metrics"]["sigma"] and abs(a["value"][0] - 10.1) < 0.5
    two = _set(msg["version"] + 1, n_in=n_in, name="anfis-body_velocity",
               metrics={"target": "body_velocity", "sigma": [0.3, 0.4]})
    assert not pred.on_model(key, _wire(M.model_params_msg(two)), 0)
    assert dict(pred.core.rejected) == {"model_shape": 1} and pred.live["body_velocity"].version == msg["version"]


def test_elman_trainer_publishes_once_ready_and_the_predictor_runs_the_same_network():
    """--model elman: online learning in order; no set until the network is under its threshold; the
    predictor's answers are the trainer's network stepped from the published context."""
    from zennav.learn import elman
    from zennav.learn.settings import LearnSettings
    from zennav.nodes.predictor import PredictorNode
    from zennav.nodes.trainer import TrainerNode

    published = []
    node = TrainerNode(lambda name, msg: published.append((name, msg)), LOG, ("drift",),
                       LearnSettings(model="elman", min_samples=50, retrain_samples=50))
    rng = np.random.default_rng(1)
    xs = rng.normal(size=(700, N_IN))
    ys = np.stack([0.5 * xs[:, 0], -0.3 * xs[:, 1]], axis=1)  # a learnable map
    for i in range(50):
        node.on_sample(M.make("learn_sample", i, features=list(xs[i]), target=list(ys[i]), variant="drift"))
    assert node.due() == ["drift"] and node.train("drift") is None and not published  # learning, not ready yet
    assert node.counters()["elman_not_ready_drift"] == 1
    for i in range(50, 700):
        node.on_sample(M.make("learn_sample", i, features=list(xs[i]), target=list(ys[i]), variant="drift"))
    while node.due():
        node.train("drift")
    msg = published[-1][1]
    assert published[-1][0] == "elman-drift" and msg["kind"] == "elman"
    assert msg["metrics"]["samples_seen"] == msg["metrics"]["samples"] == 700
    comp = node.learners["drift"].elman
    pred = PredictorNode(lambda m: None, LOG)
    assert pred.on_model(K.learn_model("elman-drift"), _wire(msg), 0)
    ctx, gain = comp.net.context.copy(), comp.net.context_gain
    for x in xs[:3] * 0.5:
        a = pred.on_query(dict(M.make("learn_query", 1, target="drift", features=list(map(float, x)), dt_s=1.0),
                               src="ins", seq=0))
        want, ctx = elman.step(comp.net.arrays(), comp.norm(), x, ctx, gain)
        assert a["model"] == "elman-drift" and np.allclose(a["value"], want, rtol=0, atol=1e-12)
        assert a["std"] == pytest.approx(list(comp.std()))


def test_lockstep_answer_waits_for_the_set_through_n_unless_the_trainer_says_none_will_come():
    import threading
    import time

    from zennav.learn.predictor_core import PredictorCore

    core = PredictorCore()
    x = np.zeros(N_IN)
    assert core.answer("drift", x, 10, wait_s=0.05) == "no_model" and core.queries["late_model"] == 1
    core.trainer_progress("drift", min_samples=100, set_through=0, through=0)
    t0 = time.perf_counter()
    assert core.answer("drift", x, 10, wait_s=5.0) == "no_model"  # below min_samples: no set will come
    v1 = _set(1, seed=1, metrics={"target": "drift", "sigma": [0.3, 0.4], "samples_seen": 120})
    core.offer("anfis-drift", v1)
    assert core.answer("drift", x, 120, wait_s=5.0)[2].version == 1  # the set through exactly 120
    v2 = _set(2, seed=2, metrics={"target": "drift", "sigma": [0.3, 0.4], "samples_seen": 200})
    threading.Timer(0.2, core.offer, ("anfis-drift", v2)).start()
    assert core.answer("drift", x, 200, wait_s=5.0)[2].version == 2  # waited for it
    core.trainer_progress("drift", 100, set_through=200, through=260)  # a fit point at 260 without a set
    assert core.answer("drift", x, 260, wait_s=5.0)[2].version == 2
    assert time.perf_counter() - t0 < 2.0 and core.queries["late_model"] == 1
    assert core.answer("drift", x, 300, wait_s=0.05)[2].version == 2 and core.queries["late_model"] == 2


def test_learning_ins_block_loop_publishes_the_step_wise_samples_queries_and_solutions(block_samples):
    """ins --learning with the block loop (as Python: the compiled loop's code) on imu_batch messages across a GNSS
    outage, answered after each message with the engine's own body velocity: every solution, aid report, published
    sample and query, and the link's counts equal the step-wise ins's; the block loop ran most samples."""
    from zennav.datasets.registry import load_dataset
    from zennav.learn.link import LearningLink
    from zennav.nodes.ins import InsNode
    from zennav.replay import sensor_events
    from zennav.stream import stream_messages

    ds = load_dataset("sim:car", duration_s=60.0)
    windows, events = sensor_events(ds, [(40.0, 10.0)])
    key = {"imu": K.imu(), "gnss": K.gnss(), "stream": K.stream()}
    msgs = [(key[kind], {**m, "src": "ingest.a", "seq": 0, "pub_ns": 0})
            for kind, m in stream_messages(ds, windows, events, 50)]
    out: dict = {None: [], "python": []}
    nodes = {}
    for b in out:
        link = LearningLink(lambda kind, m, b=b: out[b].append((kind, m)), LOG, ("body_velocity",))
        nodes[b] = InsNode(lambda kind, m, b=b: out[b].append((kind, m)), LOG, learning=link, block_loop=b)
    for key_, m in msgs:
        for node in nodes.values():
            node.on_sensor(key_, m)
            link = node.learn
            assert node.nav is not None and link is not None
            for (src, seq), q in list(link.pending.items()):  # answered at once: the INS's body velocity
                s = node.nav.state
                node.on_correction("", {**M.correction_msg({**M.learn_query_msg(q, 0), "src": src, "seq": seq},
                                                           (s.C_nb.T @ s.v_n).tolist(), [0.2] * 3, "m", 1)})
    step, block = out[None], out["python"]
    assert block_samples[0] > 0.8 * nodes[None].imu_count
    assert sum(kind == "query" for kind, _ in step) >= 8 and sum(kind == "sample" for kind, _ in step) >= 8
    assert [(k, m) for k, m in block if k != "status"] == [(k, m) for k, m in step if k != "status"]
    assert nodes["python"].learn.counts == nodes[None].learn.counts and nodes[None].learn.counts["fused"] > 0
    assert nodes["python"].nav.counters == nodes[None].nav.counters
