"""Messages: key grammar, QoS table, codec exactness, validation (each rejection reason, never raising on
garbage), the cseq merge, and the ins node fed over the message layer equals the in-process replay."""
from __future__ import annotations

import logging
import math
import random
from types import SimpleNamespace

import msgpack
import numpy as np
import pytest

from zennav import messages as M
from zennav.nav.types import InitialState, NavConfig

K = M.Keys("car")


def hdr(m, src="a", seq=0):
    m.update(src=src, seq=seq, pub_ns=1)
    return m


def imu(t, cseq=1, src="a", **kw):
    m = M.imu_msg(t, [1e-4, -2e-4, 3e-4], [0.01, 0.0, -0.049], 5_000_000, cseq)
    m.update(kw)
    return hdr(m, src)


def test_key_grammar():
    assert K.imu() == "zennav/@v1/car/sensor/imu/0"
    assert K.alive("ins") == "zennav/@v1/car/@alive/ins"
    assert K.learn_model("anfis") == "zennav/@v1/car/learn/model/anfis"
    assert M.stream_of(K.gnss("rtk")).name == "sensor/gnss"
    assert M.stream_of(K.svc_status("ins")).name == "svc/status"
    assert M.stream_of(K.nav_aid("gnss_vel")).name == "nav/aid"
    assert M.stream_of("zennav/@v2/car/sensor/imu/0") is None
    assert M.stream_of("zennav/@v1/car/sensor/imu/0/x") is None
    for bad in ("a/b", "*", "@x", "", "a b"):
        with pytest.raises(ValueError):
            M.Keys(bad)


def test_nav_prefix_moves_only_the_ins_outputs():
    P = M.Keys("car", nav_prefix="plain")
    assert P.nav_solution() == "zennav/@v1/car/nav/plain/solution"
    assert P.nav_status() == "zennav/@v1/car/nav/plain/status"
    assert P.nav_aid("gnss_pos") == "zennav/@v1/car/nav/plain/aid/gnss_pos"
    assert (P.imu(), P.stream(), P.learn_query()) == (K.imu(), K.stream(), K.learn_query())
    for key, stream in ((P.nav_solution(), "nav/solution"), (P.nav_status(), "nav/status"),
                        (P.nav_aid("gnss_pos"), "nav/aid"), (K.nav_aid("status"), "nav/aid")):
        assert M.stream_of(key).name == stream, key
    for bad in ("aid", "status", "solution", "a/b"):
        with pytest.raises(ValueError):
            M.Keys("car", nav_prefix=bad)
    assert [K.nav_prefix_of(k) for k in (P.nav_status(), P.nav_aid("x"), K.nav_status(), K.nav_aid("x"), K.imu())] \
        == ["plain", "plain", "", "", ""]


def test_aid_report_optional_status_fields():
    from zennav.nav.navigator import AidReport

    rep = AidReport("gnss_pos", 5, [1.0, 2.0, 3.0], [0.1, 0.2, 0.3], [1.0, 1.0, 1.0], 0.5, True)
    assert M.validate_map(hdr(M.aid_report_msg(rep)), K.nav_aid("gnss_pos")) == ""
    rec = SimpleNamespace(**{**vars(rep), "last_fused_t_ns": 5, "faults": ("stale",)})  # a record that has them
    m = hdr(M.aid_report_msg(rec))
    assert (m["last_fused_t_ns"], m["faults"]) == (5, ["stale"])
    assert M.validate_map(M.decode(M.encode(m)), K.nav_aid("gnss_pos")) == ""
    assert M.validate_map({**m, "faults": ["ok", 3]}, K.nav_aid("gnss_pos")).startswith("bad_type: faults[1]")
    assert M.validate_map({**m, "last_fused_t_ns": 1.5}, K.nav_aid("gnss_pos")).startswith("bad_type")


def test_qos_lossless_streams_and_one_sensor_priority():
    q = {s.name: s.qos for s in M.STREAMS}
    for name in ("sensor/imu", "sensor/gnss", "sensor/stream", "nav/solution", "learn/model", "learn/correction"):
        assert q[name].reliability == "reliable" and q[name].congestion == "block", name
    assert len({q[n].priority for n in ("sensor/imu", "sensor/gnss", "sensor/stream")}) == 1
    assert q["svc/status"].latest and q["learn/model"].latest and q["nav/status"].latest
    assert {r["stream"] for r in M.qos_table()} == set(q)


def test_codec_float64_bit_exact():
    rng = np.random.default_rng(0)
    vals = list(rng.normal(size=1000) * 10.0 ** rng.integers(-300, 300, 1000)) + [0.0, -0.0, 5e-324, 1.7e308]
    m = hdr(M.make("learn_sample", 1, features=M.floats(np.array(vals)), target=[1 / 3], variant="x"))
    back = M.decode(M.encode(m))
    assert all(a == b and math.copysign(1, a) == math.copysign(1, b) for a, b in zip(vals, back["features"]))
    assert M.validate_map(back, K.learn_samples()) == ""


def test_nav_config_initial_gnss_round_trip():
    cfg = NavConfig(lever_arm_b=np.array([0.1, -0.2, 1 / 3]), end_t_ns=123)
    back = M.map_to_dataclass(NavConfig, M.decode(M.encode(M.dataclass_to_map(cfg))))
    assert np.array_equal(back.lever_arm_b, cfg.lever_arm_b) and back.imu_noise == cfg.imu_noise
    assert back.end_t_ns == 123 and back.start_t_ns is None
    ini = InitialState(5, np.array([0.5, 2.0, 30.0]), np.array([1.0, 2, 3]), np.array([0.1, 0.2, 0.3]),
                       std_gyro_bias=np.array([1e-5] * 3))
    b = M.map_to_dataclass(InitialState, M.decode(M.encode(M.dataclass_to_map(ini))))
    assert b.t_ns == 5 and np.array_equal(b.llh, ini.llh) and np.array_equal(b.std_gyro_bias, ini.std_gyro_bias)
    from zennav.nav.types import GnssFix

    fix = GnssFix(7, np.array([0.5, 2.0, 30.0]), np.array([1.0, 1, 2]), np.array([1.0, 2, 3]), np.array([.1] * 3), 4, 9)
    f2 = M.gnss_fix(M.decode(M.encode(hdr(M.gnss_msg(fix, 3)))))
    assert f2.t_ns == 7 and np.array_equal(f2.llh, fix.llh) and np.array_equal(f2.v_n, fix.v_n) and f2.num_sats == 9


@pytest.mark.parametrize("mutate, code", [
    (lambda m: m.update(dvel=[0.0, math.nan, 0.0]), "not_finite"),
    (lambda m: m.update(dvel=[0.0, math.inf, 0.0]), "not_finite"),
    (lambda m: m.update(dvel=[0.0, 0.0]), "bad_shape"),
    (lambda m: m.update(dvel="abc"), "bad_type"),
    (lambda m: m.update(dtheta=[0.0, "x", 0.0]), "bad_type"),
    (lambda m: m.update(t_ns=1.5), "bad_type"),
    (lambda m: m.update(t_ns=True), "bad_type"),
    (lambda m: m.pop("cseq"), "missing_field"),
    (lambda m: m.update(v=2), "unsupported_version"),
    (lambda m: m.update(schema="gnss"), "wrong_schema"),
    (lambda m: m.update(schema="nope"), "unknown_schema"),
    (lambda m: m.pop("schema"), "missing_field"),
])
def test_validator_rejects_with_reason(mutate, code):
    v = M.Validator()
    m = imu(10)
    mutate(m)
    msg, reason = v.check(K.imu(), M.encode(m))
    assert msg is None and reason.split(":")[0] == code, reason
    assert v.rejected == {code: 1}


def _status(t, src="a"):
    return hdr(M.make("nav_status", t, gnss_state="valid", counters={}, rejected={}, imu_count=0, gnss_count=0,
                      stream={}, model={}), src)


def test_validator_time_per_key_and_source_and_ints_normalised():
    v = M.Validator()
    assert v.check(K.nav_status(), M.encode(_status(10)))[0] is not None
    assert v.check(K.nav_status(), M.encode(_status(10)))[0] is not None  # non-decreasing is enough for status
    assert v.check(K.nav_status(), M.encode(_status(9)))[1].startswith("time_backwards")
    assert v.check(K.nav_status(), M.encode(_status(9, src="b")))[0] is not None  # each publisher its own clock
    assert v.check(M.Keys("car", "p").nav_status(), M.encode(_status(1)))[0] is not None  # another key
    m, _ = v.check(K.imu(), M.encode(imu(11, dvel=[0, 1, 2])))
    assert m["dvel"] == [0.0, 1.0, 2.0] and all(type(x) is float for x in m["dvel"])
    assert v.rejected == {"time_backwards": 1}


def test_sensor_time_order_is_the_merge_not_the_validator():
    """One far-future sample on the live source used to set the validator's last time and get every later
    sample rejected (the stream stalled): sensor keys are ordered and time-checked by the consumers' cseq merge
    (zennav.stream), so the validator passes them whatever their time."""
    v = M.Validator()
    assert all(M.stream_of(k).time == "cseq" for k in (K.imu(), K.gnss(), K.stream()))
    for t in (10, 10 + 10**12, 11, 9):
        assert v.check(K.imu(), M.encode(imu(t)))[1] == ""
    assert not v.rejected


def test_imu_batch_validates_and_expands():
    th = [[1e-4 * i, -2e-4, 3e-4] for i in range(3)]
    dv = [[0.01, 0.0, -0.049 * i] for i in range(3)]
    b = hdr(M.imu_batch_msg([10, 20, 30], [10, 10, 10], th, dv, 5))
    v = M.Validator()
    msg, reason = v.check(K.imu("0"), M.encode(b))
    assert reason == ""
    one = M.samples(msg)
    assert [(m["schema"], m["cseq"], m["t_ns"], m["dt_ns"]) for m in one] == [("imu", 5, 10, 10), ("imu", 6, 20, 10),
                                                                            ("imu", 7, 30, 10)]
    assert [m["dtheta"] for m in one] == th and [m["dvel"] for m in one] == dv
    assert all(M.validate_map(m, K.imu("0")) == "" for m in one)  # each expanded sample is a valid imu message
    assert M.samples(imu(40)) == [imu(40)]
    for bad, code in ((dict(t_ns_list=[10, 30, 20], t_ns=20), "bad_value"), (dict(t_ns=31), "bad_value"),
                      (dict(dtheta=[0.0] * 8), "bad_shape"), (dict(dt_ns_list=[10, 10]), "bad_shape"),
                      (dict(t_ns_list=[], dt_ns_list=[], dtheta=[], dvel=[]), "bad_shape"),
                      (dict(t_ns_list=[10, 20.0, 30]), "bad_type"), (dict(dvel=[math.nan] * 9), "not_finite")):
        assert M.Validator().check(K.imu("0"), M.encode(dict(b, **bad)))[1].split(":")[0] == code, bad
    assert M.Validator().check(K.gnss("0"), M.encode(b))[1].startswith("wrong_schema")


def test_validator_never_raises_on_garbage():
    v = M.Validator()
    rnd = random.Random(1)
    for i in range(3000):
        n = rnd.randrange(0, 200)
        payload = bytes(rnd.getrandbits(8) for _ in range(n))
        if i % 3 == 0:  # structured garbage: valid msgpack of odd shapes
            payload = msgpack.packb(rnd.choice([
                [1, 2], "x", None, {"schema": 1}, {"schema": "imu", "v": 1}, {b"k": b"v"},
                {"schema": "imu", "v": 1, "t_ns": 2**64 - 1}, {"schema": "model_params", "v": 1, "arrays": {"a": 1}},
                hdr(imu(i)) | {"dtheta": [[1.0]] * 3}]))
        msg, reason = v.check(K.imu(), payload)
        assert (msg is None) == bool(reason)
    assert sum(v.rejected.values()) + v.accepted == 3000 and v.accepted <= 1


def test_model_params_arrays_and_checksum():
    m = M.make("model_params", 1, name="anfis", version=2, kind="anfis", created_t_ns=3, norm={"mu": [0.0, 1.0]},
               arrays={"w": M.array_map(np.arange(6.0).reshape(2, 3))}, metrics={"rmse": 0.1}, checksum="")
    m["checksum"] = M.params_checksum(m)
    hdr(m)
    v = M.Validator()
    back, reason = v.check(K.learn_model("anfis"), M.encode(m))
    assert reason == "" and M.params_checksum(back) == m["checksum"]
    assert np.array_equal(M.map_array(back["arrays"]["w"]), np.arange(6.0).reshape(2, 3))
    m["arrays"]["w"]["shape"] = [4, 2]
    assert v.check(K.learn_model("anfis"), M.encode(m))[1].startswith("bad_shape")


def test_sequence_merger_orders_holds_dedups_and_skips_gaps():
    out = []
    m = M.SequenceMerger(1, max_hold=3)
    for c in (1, 3, 2, 2, 1, 5, 6, 7, 8):
        m.push(c, c, out.append)
    # 4 never comes: with more than 3 held the gap is skipped
    assert out == [1, 2, 3, 5, 6, 7, 8]
    assert m.counts["duplicate"] == 2 and m.counts["gap"] == 1 and m.held == 0
    m.push(10, 10, out.append)
    m.flush(out.append)
    assert out[-1] == 10 and m.counts["gap"] == 2


def _stream_messages(ds, outages=()):
    """The messages the ingest publishes for ds (zennav.stream.stream_messages), with their headers."""
    from zennav.replay import sensor_events
    from zennav.stream import stream_messages

    windows, events = sensor_events(ds, outages)
    return [hdr(m, "ingest", i) for i, (_kind, m) in enumerate(stream_messages(ds, windows, events))]


@pytest.mark.parametrize("shuffle", [False, True])
def test_ins_node_over_messages_equals_replay(shuffle):
    """ingest's event order + codec + validator + cseq merge + InsNode, without a network, reproduce
    run_replay bit for bit, also when messages arrive out of order (within a window)."""
    from zennav.nodes.ins import InsNode
    from zennav.replay import run_replay
    from zennav.sim.scenarios import make_dataset

    ds = make_dataset("car", duration_s=40.0, seed=4)
    outages = [(15.0, 10.0)]
    msgs = _stream_messages(ds, outages)
    if shuffle:
        rnd = random.Random(0)
        body = msgs[1:]
        for i in range(0, len(body), 7):
            chunk = body[i:i + 7]
            rnd.shuffle(chunk)
            body[i:i + 7] = chunk
        msgs = [msgs[0]] + body
    out = {"solution": [], "aid": [], "status": []}
    node = InsNode(lambda kind, m: out[kind].append(M.decode(M.encode(m))), logging.getLogger("t"))
    v = M.Validator()
    for m in msgs:
        key = {"imu": K.imu(), "gnss": K.gnss()}.get(m["schema"], K.stream())
        dec, reason = v.check(key, M.encode(m)) if not shuffle else (M.decode(M.encode(m)), "")
        assert reason == ""
        node.on_sensor(key, dec)
    ref = run_replay(ds, outages=outages)
    sols = out["solution"]
    assert len(sols) == len(ref.t_ns) and node.follower.done
    assert np.array_equal([s["t_ns"] for s in sols], ref.t_ns)
    assert np.array_equal(np.array([s["llh"] for s in sols]), ref.llh)
    assert np.array_equal(np.array([s["v_n"] for s in sols]), ref.v_n)
    assert np.array_equal(np.array([s["q_nb"] for s in sols]), ref.q_nb)
    assert [(a["source"], a["t_ns"], a["fused"]) for a in out["aid"]] == \
        [(r.source, r.t_ns, r.fused) for r in ref.reports]
    assert out["status"][-1]["stream"]["done"] and out["status"][-1]["imu_count"] == len(ref.t_ns)
    assert node.follower.merger.counts.get("gap", 0) == 0 and node.follower.merger.counts.get("duplicate", 0) == 0


def test_solution_fast_path_matches_core_solution():
    from zennav.nav.navigator import Navigator
    from zennav.sim.scenarios import make_dataset

    ds = make_dataset("car", duration_s=10.0, seed=2)
    nav = Navigator(ds.config, ds.initial)
    for k in range(len(ds.imu)):
        if ds.imu.t_ns[k] <= ds.initial.t_ns:
            continue
        ok = nav.on_imu(int(ds.imu.t_ns[k]), ds.imu.dtheta[k], ds.imu.dvel[k])
        if k % 97 == 0:
            assert ok
            a = M.nav_solution_msg_of(nav, k, 0)
            b = M.nav_solution_msg(nav.solution(), k, 0)
            for f in b:
                if isinstance(b[f], list):
                    assert np.allclose(a[f], b[f], rtol=0, atol=1e-15), f
                else:
                    assert a[f] == b[f], f


def test_euler_list_is_the_rotation_helper():
    """messages.euler_list (the hot path's inlined ZYX conversion, used by the ins's solution and the attitude
    service) equals zennav.nav.rotation.quat_to_euler, on random and gimbal-near quaternions."""
    from zennav.nav.rotation import quat_to_euler, rotvec_to_quat

    rng = np.random.default_rng(7)
    qs = [q / np.linalg.norm(q) for q in rng.normal(size=(500, 4))]
    qs += [rotvec_to_quat([0.0, np.pi / 2 - e, 0.3]) for e in (1e-3, 1e-7, 0.0)]
    for q in qs:
        assert np.allclose(M.euler_list(*q.tolist()), quat_to_euler(q), rtol=0, atol=2e-15), q


def test_solution_packer_gives_the_bytes_of_the_map():
    """SolutionPacker (the ins's hot path) packs exactly encode() of the nav_solution map that
    nav_solution_msg_of_row builds and Publisher.put stamps: random floats (signs, subnormals, huge), every GNSS
    state, and ints at each of msgpack's size boundaries (t_ns, cseq, publish times, seq)."""
    rng = np.random.default_rng(11)
    packer = M.SolutionPacker()
    bounds = [0, 1, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**63 - 1, -1, -32, -33, -128, -129,
              -32768, -32769, -2**31, -2**31 - 1, -2**63]

    class Nav:
        gyro_bias = [1e-5, -2e-6, 3.5e-300]
        accel_bias = [0.01, -0.02, 5e-324]

    for k in range(400):
        std = list(np.abs(rng.normal(size=9)))
        if k % 2:  # extreme values
            row = list(rng.normal(size=10) * 10.0 ** rng.integers(-300, 300, size=10))
            ints = [int(x) for x in rng.choice(bounds, size=5)]
        else:  # a realistic solution
            q = rng.normal(size=4)
            row = [0.6, 2.1, 50.0, *rng.normal(size=3), *(q / np.linalg.norm(q))]
            ints = [356400 * 10**9 + k, k, 1_700_000_000 * 10**9, k, 1_700_000_001 * 10**9]
        Nav.gnss_state = ("valid", "outage", "unknown")[k % 3]
        t_ns, cseq, imu_pub, seq, pub = ints
        m = M.nav_solution_msg_of_row(Nav, t_ns, row, std[0:3], std[3:6], std[6:9], cseq, imu_pub)
        m.update(src="ins.4f2a", seq=seq, pub_ns=pub)
        b = packer.pack(t_ns, row, std, Nav.gyro_bias, Nav.accel_bias, Nav.gnss_state, cseq, imu_pub, "ins.4f2a",
                        seq, pub)
        assert b == M.encode(m), k
        if k % 2 == 0:  # a realistic message: valid on the bus
            assert M.validate_map(M.decode(b)) == "", k


def test_solution_batch_stands_for_its_solutions_and_refuses_bad_shapes():
    """nav_solution_batch: expanded (zennav.messages.solutions), each row is the nav_solution the ins would publish
    alone (the map SolutionPacker packs, with the batch's header); rows that do not add up, times that do not
    increase or do not end at t_ns are refused by the validator."""
    rng = np.random.default_rng(5)
    n = 4
    q = rng.normal(size=(n, 4))
    rows = np.column_stack([0.6 + rng.normal(size=n) * 1e-6, 2.1 + rng.normal(size=n) * 1e-6,
                            50 + rng.normal(size=n), rng.normal(size=(n, 3)), q / np.linalg.norm(q, axis=1)[:, None]])
    std = np.abs(rng.normal(size=(n, 9)))

    class Nav:
        gyro_bias, accel_bias, gnss_state = [1e-5, -2e-6, 3e-7], [0.01, -0.02, 0.003], "outage"

    t = [356400 * 10**9 + 5_000_000 * i for i in range(n)]
    cseq, pub = [10 + i for i in range(n)], [1_700_000_000 * 10**9 + i for i in range(n)]
    b = M.nav_solution_batch_msg(Nav, t, rows, std, cseq, pub)
    b.update(src="ins.4f2a", seq=7, pub_ns=99)
    b = M.decode(M.encode(b))
    key = "zennav/@v1/car/nav/solution"
    assert M.validate_map(b, key) == ""
    packer = M.SolutionPacker()
    got = M.solutions(b)
    assert len(got) == n
    for i, m in enumerate(got):
        alone = packer.pack(t[i], rows[i].tolist(), std[i].tolist(), Nav.gyro_bias, Nav.accel_bias, Nav.gnss_state,
                            cseq[i], pub[i], "ins.4f2a", 7, 99)
        assert M.encode(m) == alone, i
    assert M.solutions(got[0]) == [got[0]]
    for bad, code in ((dict(llh=b["llh"][:-1]), "bad_shape"), (dict(imu_cseq=cseq[:-1]), "bad_shape"),
                      (dict(t_ns_list=[t[1], t[0], *t[2:]]), "bad_value"), (dict(t_ns=t[-1] + 1), "bad_value"),
                      (dict(t_ns_list=[], imu_cseq=[], imu_pub_ns=[]), "bad_shape")):
        assert M.validate_map({**b, **bad}, key).startswith(code), bad
