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
    assert reason == "" and (back["query_src"], back["query_seq"], back["kind"], back["t_ns"]) == ("ins.x", 7, "drift", 10)
    s = M.learn_sample_msg(LearnSample(10, "drift", np.zeros(N_IN), np.array([1.0, -1.0])))
    s.update(src="i", seq=0, pub_ns=0)
    assert M.Validator().check(K.learn_samples(), M.encode(s))[1] == ""


def test_predictor_swaps_validated_sets_and_keeps_the_live_one_on_rejection():
    from zennav.services.predictor import PredictorNode

    out, bus_rej = [], []
    node = PredictorNode(out.append, LOG, bus_reject=lambda k, r: bus_rej.append(r))
    key = K.learn_model("anfis-drift")
    q = dict(M.make("learn_query", 1, target="drift", features=[0.5] * N_IN, dt_s=1.0), src="ins", seq=0)
    assert node.on_query(q) is None and node.queries["no_model"] == 1
    v1 = _set(1, seed=1)
    assert node.on_model(key, _wire(M.model_params_msg(v1)), 0)
    assert not node.on_model(key, _wire(M.model_params_msg(v1)), 0)  # the same set again: a duplicate
    assert node.sets["duplicate"] == 1 and node.sets["rejected"] == 0
    for bad in (_set(1, seed=2), _set(2, seed=3, n_in=N_IN - 1), _set(3, seed=4, name="other"),
                _set(4, seed=5, metrics={"sigma": [0.3, 0.4]})):
        assert not node.on_model(key, _wire(M.model_params_msg(bad)), 0)
    assert dict(node.rejected) == {"model_stale_version": 1, "model_shape": 1, "model_schema": 2}
    assert len(bus_rej) == 4 and node.live["drift"].version == 1
    a = node.on_query(q)
    live = paramset.validate(v1)
    assert a["version"] == 1 and a["std"] == [0.3, 0.4] and a["query_seq"] == 0
    assert np.array_equal(a["value"], anfis_numpy.predict(live.arrays, live.norm, np.full(N_IN, 0.5)))
    assert node.on_model(key, _wire(M.model_params_msg(_set(9, seed=9))), 0)
    assert node.on_query(q)["version"] == 9 and node.counters()["live_version_drift"] == 9


def test_predictor_refuses_queries_outside_the_training_range():
    from zennav.services.predictor import PredictorNode

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

    assert query(inside) is not None and query(edge) is not None
    assert query(far) is None and query(below) is None
    assert node.queries["off_domain"] == 2 and node.queries["answered"] == 2 and len(out) == 2


class _FakeNav:
    def __init__(self):
        self.t_ns, self.last_fused_t_ns = 0, -1
        self.samples, self.queries, self.fused = [], [], []

    def pop_samples(self):
        s, self.samples = self.samples, []
        return s

    def pop_queries(self):
        q, self.queries = self.queries, []
        return q

    def on_correction(self, q, value, std):
        self.fused.append((q.t_ns, list(value), list(std)))
        return True


def test_ins_learning_link_matches_answers_to_pending_queries():
    from zennav.learn.link import LearningLink

    sent = []

    def publish(kind, msg):
        msg.update(src="ins.a", seq=len(sent), pub_ns=0)  # what the bus publisher stamps
        sent.append((kind, msg))

    link = LearningLink(publish, LOG, ("drift",), max_age_s=1.0)
    nav = _FakeNav()
    nav.samples = [LearnSample(1, "drift", np.zeros(N_IN), np.zeros(2)), LearnSample(1, "position", np.zeros(11), np.zeros(2))]
    nav.t_ns = 10**9
    nav.queries = [LearnQuery(10**9, "drift", np.zeros(N_IN), 1.0), LearnQuery(10**9, "position", np.zeros(11), 0.5)]
    link.after_imu(nav)
    assert [k for k, _ in sent] == ["sample", "query"]  # only the configured target
    q = sent[1][1]

    def answer(query, **kw):
        return {**M.correction_msg(query, [1.0, 2.0], [0.5, 0.5], "anfis-drift", 4), **kw}

    assert link.on_correction(nav, answer(q)) and nav.fused == [(10**9, [1.0, 2.0], [0.5, 0.5])]
    assert not link.on_correction(nav, answer(q))  # answered twice: the second is dropped
    assert not link.on_correction(nav, answer(q, query_src="ins.other"))
    for t, fused_at, what in ((2 * 10**9, 2 * 10**9, "stale"), (3 * 10**9, -1, "late")):
        nav.t_ns = t
        nav.queries = [LearnQuery(t, "drift", np.zeros(N_IN), 1.0)]
        link.after_imu(nav)
        qq = sent[-1][1]
        nav.last_fused_t_ns = fused_at  # a GNSS fix fused since the query
        if what == "late":
            nav.t_ns = t + 2 * 10**9
        assert not link.on_correction(nav, answer(qq))
    nav.queries = [LearnQuery(nav.t_ns, "drift", np.zeros(N_IN), 1.0)]
    link.after_imu(nav)
    nav.t_ns += 5 * 10**9
    link.after_imu(nav)  # never answered: expires
    st = link.status()
    assert (st["fused"], st["unmatched"], st["stale"], st["late"], st["unanswered"], st["pending"]) == (1, 2, 1, 1, 1, 0)
    assert (st["model"], st["version"]) == ("anfis-drift", 4)


def test_trainer_schedule_and_published_set_accepted_by_the_predictor():
    pytest.importorskip("torch")
    from zennav.services.predictor import PredictorNode
    from zennav.services.trainer import TrainerNode

    published = []
    node = TrainerNode(lambda name, msg: published.append((name, msg)), LOG, ("drift",), min_samples=100,
                       retrain_samples=120, retrain_every_s=0, n_rules=8, max_epochs=3)
    rng = np.random.default_rng(0)
    for i in range(119):
        x = rng.normal(size=N_IN)
        node.on_sample(M.make("learn_sample", i, features=list(x), target=[x[0], 2 * x[1]], variant="drift"))
    node.on_sample(M.make("learn_sample", 0, features=[0.0], target=[0.0, 0.0], variant="drift"))  # bad shape
    node.on_sample(M.make("learn_sample", 0, features=[0.0], target=[0.0], variant="position"))  # not learned
    assert node.due() == [] and node.counts["ignored_shape"] == node.counts["ignored_variant"] == 1
    node.on_sample(M.make("learn_sample", 200, features=[0.0] * N_IN, target=[0.0, 0.0], variant="drift"))
    assert node.due() == ["drift"]
    node.seen_version("drift", 6)  # a set v6 exists on the bus: continue above it
    msg = node.train("drift")
    assert node.due() == [] and published[0][0] == "anfis-drift" and msg["version"] == 7
    assert msg["metrics"]["samples"] == 120 and msg["metrics"]["n_rules"] == 2  # 120 // (4 * 14) rules
    pred = PredictorNode(lambda m: None, LOG)
    assert pred.on_model(K.learn_model("anfis-drift"), _wire(msg), 0) and pred.live["drift"].version == 7


def test_body_velocity_sets_have_three_outputs_end_to_end():
    """The 3-output target (forward, right, down body velocity) through trainer, wire and predictor; a set with
    the wrong output count for its target is refused."""
    pytest.importorskip("torch")
    from zennav.services.predictor import PredictorNode
    from zennav.services.trainer import TrainerNode

    published = []
    node = TrainerNode(lambda name, msg: published.append(msg), LOG, ("body_velocity",), min_samples=100,
                       retrain_samples=200, retrain_every_s=0, max_epochs=3)
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
    assert dict(pred.rejected) == {"model_shape": 1} and pred.live["body_velocity"].version == msg["version"]


def test_elman_trainer_publishes_once_ready_and_the_predictor_runs_the_same_network():
    """--model elman: online learning in arrival order; no set until the network is under its threshold; the
    predictor's answers are the trainer's network stepped from the published context."""
    from zennav.learn import elman
    from zennav.services.predictor import PredictorNode
    from zennav.services.trainer import TrainerNode

    published = []
    node = TrainerNode(lambda name, msg: published.append((name, msg)), LOG, ("drift",), model="elman",
                       min_samples=50, retrain_samples=50, retrain_every_s=0)
    rng = np.random.default_rng(1)
    xs = rng.normal(size=(700, N_IN))
    ys = np.stack([0.5 * xs[:, 0], -0.3 * xs[:, 1]], axis=1)  # a learnable map
    first = node.elman["drift"].min_samples - 1
    for i in range(first):
        node.on_sample(M.make("learn_sample", i, features=list(xs[i]), target=list(ys[i]), variant="drift"))
    assert node.due() == ["drift"] and node.train("drift") is None and not published  # not learning yet
    for i in range(first, 700):
        node.on_sample(M.make("learn_sample", i, features=list(xs[i]), target=list(ys[i]), variant="drift"))
    msg = node.train("drift")
    assert msg is not None and published[-1][0] == "elman-drift" and msg["kind"] == "elman"
    assert msg["metrics"]["samples"] == 700
    comp = node.elman["drift"]
    pred = PredictorNode(lambda m: None, LOG)
    assert pred.on_model(K.learn_model("elman-drift"), _wire(msg), 0)
    ctx, gain = comp.net.context.copy(), comp.net.context_gain
    for x in xs[:3] * 0.5:
        a = pred.on_query(dict(M.make("learn_query", 1, target="drift", features=list(map(float, x)), dt_s=1.0),
                               src="ins", seq=0))
        want, ctx = elman.step(comp.net.arrays(), comp.norm(), x, ctx, gain)
        assert a["model"] == "elman-drift" and np.allclose(a["value"], want, rtol=0, atol=1e-12)
        assert a["std"] == pytest.approx(list(comp.std()))
