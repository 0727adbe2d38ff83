"""The AUV's sensors on the bus (issue 14 item 7): the dvl and depth schemas and their validation, their place in
the one selection of sensor events (zennav.replay.sensor_events) and in the stream (zennav.stream), and the ins
core (zennav.nodes.ins.InsNode) handing them to the engine as the in-process replay does."""
from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from zennav import messages as M
from zennav.datasets.registry import load_dataset
from zennav.nav.types import DvlSample
from zennav.replay import run_replay, sensor_events
from zennav.stream import stream_messages

K = M.Keys("auv")
KEY = {"imu": K.imu(), "gnss": K.gnss(), "dvl": K.dvl(), "depth": K.depth(), "stream": K.stream()}
log = logging.getLogger("test")


def _head(msg: dict, src: str = "ingest.a") -> dict:
    return {**msg, "src": src, "seq": 0, "pub_ns": 0}


def auv_like(duration_s: float = 60.0):
    """A short simulated AUV (zennav.sim.auv): 20 s at the surface with GNSS, then a dive with DVL beams (a beam
    lost now and then, the bottom lost for 3 s) and depth; the engine runs its DVL and depth sources."""
    return load_dataset("sim:auv", duration_s=duration_s, surface_s=20.0, dvl_bottom_loss="40:3", dvl_dropout=0.05)


def _msgs(ds, batch: int = 1) -> list[tuple[str, dict]]:
    windows, events = sensor_events(ds)
    return [(KEY[kind], _head(m)) for kind, m in stream_messages(ds, windows, events, batch)]


def test_dvl_schema_accepts_both_kinds_and_refuses_what_is_malformed():
    beams = DvlSample(5, np.array([1.0, np.nan, 2.0, 3.0]), np.array([True, False, True, True]))
    m = _head(M.dvl_msg(beams, 7))
    assert m["beams"] == [1.0, 0.0, 2.0, 3.0] and m["beam_valid"] == [True, False, True, True]
    assert M.validate_map(m, K.dvl()) == ""
    back = M.dvl_sample(m)
    assert back.t_ns == 5 and np.isnan(back.beams[1]) and back.beams[3] == 3.0 and back.beam_valid.tolist() == \
        [True, False, True, True] and back.velocity_d is None
    vel = _head(M.dvl_msg(DvlSample(6, velocity_d=np.array([1.0, 0.1, 0.0]), velocity_valid=True), 8))
    assert M.validate_map(vel, K.dvl()) == "" and "beams" not in vel
    assert M.dvl_sample(vel).velocity_d.tolist() == [1.0, 0.1, 0.0]
    lost = M.dvl_msg(DvlSample(7, velocity_d=np.array([np.nan, 0.0, 0.0]), velocity_valid=True), 9)
    assert lost["velocity_valid"] is False and lost["velocity_d"] == [0.0, 0.0, 0.0]  # NaN never travels
    bad = {
        "not_finite": {**m, "beams": [1.0, math.nan, 2.0, 3.0]},
        "bad_shape": {**m, "beams": [1.0, 2.0, 3.0]},
        "bad_type": {**m, "beam_valid": [1, 0, 1, 1]},
        "bad_type ": {**m, "beam_valid": [True, True, True]},
        "missing_field": {k: v for k, v in m.items() if k not in ("beams", "beam_valid")},
        "bad_shape ": {**vel, "velocity_valid": None},
        "wrong_schema": {**m, "schema": "depth", "depth_m": 3.0},
    }
    for code, msg in bad.items():
        assert M.validate_map(msg, K.dvl()).split(":")[0] == code.strip(), code
    assert M.validate_map(bad["not_finite"], K.dvl()).startswith("not_finite: beams[1]")
    depth = _head(M.depth_msg(M.depth_sample({"t_ns": 3, "depth_m": 12.5}), 4))
    assert M.validate_map(depth, K.depth()) == "" and M.depth_sample(depth).depth_m == 12.5
    assert M.validate_map({**depth, "depth_m": math.inf}, K.depth()).startswith("not_finite")
    assert M.validate_map(depth, K.dvl()).startswith("wrong_schema")
    v = M.Validator()  # the bus's path: decode, validate, count the reason
    assert v.check(K.dvl(), M.encode(bad["bad_shape"]))[0] is None and v.rejected["bad_shape"] == 1
    assert M.stream_of(K.dvl("fwd")).qos == M.stream_of(K.gnss()).qos and M.stream_of(K.depth()).time == "cseq"


def test_aid_samples_go_before_the_imu_sample_that_reaches_their_time():
    """In the one selection, every DVL and depth sample of the run (after the initial time, up to the last IMU
    sample; GNSS outages do not withhold them) comes right before the first IMU sample at or after its time; the
    stream counts them, and an imu_batch is cut before each."""
    ds = auv_like()
    windows, plan = sensor_events(ds, [(10.0, 5.0)])
    events = list(plan)
    assert len(events) == len(plan) and plan.counts() == {k: sum(e[0] == k for e in events) for k in plan.counts()}
    t_imu = ds.imu.t_ns
    for i, (kind, k) in enumerate(events):
        if kind in M.AID_STREAMS:
            t = getattr(ds, kind).t_ns[k]
            nxt = next(e for e in events[i:] if e[0] == "imu")
            prev = next((e for e in events[i::-1] if e[0] == "imu"), None)
            assert t_imu[nxt[1]] >= t and (prev is None or t_imu[prev[1]] < t)
    t0 = ds.initial.t_ns
    for kind in M.AID_STREAMS:
        t = getattr(ds, kind).t_ns
        want = np.flatnonzero((t > t0) & (t <= t_imu[-1])).tolist()
        assert [k for e, k in events if e == kind] == want
    for batch in (1, 50):
        msgs = [m for _, m in _msgs(ds, batch)]
        counts = msgs[0]["counts"]
        assert counts == msgs[-1]["counts"] and set(counts) == {"imu", "gnss", "dvl", "depth"}
        assert counts["dvl"] == sum(1 for m in msgs if m["schema"] == "dvl") > 200
        assert counts["depth"] == sum(1 for m in msgs if m["schema"] == "depth") > 200
        cseqs = [c for m in msgs for c in ([m["cseq"] + i for i in range(len(m["t_ns_list"]))]
                                           if m["schema"] == "imu_batch" else [m["cseq"]])]
        assert cseqs == list(range(len(cseqs)))
        assert all(M.validate_map(m, KEY[m["schema"] if m["schema"] in KEY else "imu"]) == "" for m in msgs
                   if m["schema"] not in ("stream_start", "stream_end"))
    plain = load_dataset("sim:car", duration_s=30.0)  # no aid streams: the stream as before
    assert set(_msgs(plain)[0][1]["counts"]) == {"imu", "gnss"}


def test_ins_core_hands_aid_samples_to_the_engine_as_the_replay_does():
    """InsNode over the stream (as the bus delivers it, in order and shuffled within the merge's window): every
    DVL and depth sample reaches the engine (counted, stream end complete) and the solutions are the in-process
    replay's, bit for bit."""
    from zennav.nodes.ins import InsNode

    ds = auv_like()
    ref = run_replay(ds)
    msgs = _msgs(ds)
    rng = np.random.default_rng(1)
    shuffled = list(msgs)
    for i in range(1, len(shuffled) - 8, 8):  # reorder within blocks of 8 (the merge restores cseq order)
        block = shuffled[i:i + 8]
        rng.shuffle(block)
        shuffled[i:i + 8] = block
    for order in (msgs, shuffled):
        out: dict = {"solution": [], "status": [], "aid": []}
        node = InsNode(lambda kind, m, out=out: out[kind].append(m), log)
        for key, m in order:
            node.on_sensor(key, m)
        end = out["status"][-1]
        start = msgs[0][1]
        assert node.follower.done and end["aid_counts"] == {"dvl": start["counts"]["dvl"],
                                                            "depth": start["counts"]["depth"]}
        assert M.validate_map(_head(end), K.nav_status()) == ""
        assert [m["t_ns"] for m in out["solution"]] == ref.t_ns.tolist()
        assert np.array_equal(np.array([m["llh"] for m in out["solution"]]), ref.llh)
        assert np.array_equal(np.array([m["v_n"] for m in out["solution"]]), ref.v_n)
        assert [(r["source"], r["t_ns"], r["fused"], r["reason"]) for r in out["aid"]] == \
            [(r.source, r.t_ns, r.fused, r.reason) for r in ref.reports]
        fused = {s: sum(1 for r in out["aid"] if r["source"] == s and r["fused"]) for s in ("dvl", "depth")}
        assert fused["dvl"] > 200 and fused["depth"] > 200
        assert end["counters"]["dvl_beams_0"] > 0 and end["counters"]["dvl_beams_3"] > 0


def test_ins_refuses_aid_samples_out_of_the_stream_time():
    """A DVL sample whose time is far from the stream's (forged, or a clock jump) is refused at its turn (counted
    time_jump / time_backwards, its slot left open for the genuine one), never handed to the engine."""
    from zennav.nodes.ins import InsNode

    ds = auv_like(10.0)
    msgs = _msgs(ds)
    i = next(i for i, (_k, m) in enumerate(msgs) if m["schema"] == "dvl")
    key, genuine = msgs[i]
    node = InsNode(lambda kind, m: None, log)
    for k, m in msgs[:i]:
        node.on_sensor(k, m)
    node.on_sensor(key, {**genuine, "t_ns": genuine["t_ns"] + 60 * 10**9})
    node.on_sensor(key, {**genuine, "t_ns": genuine["t_ns"] - 60 * 10**9})
    for k, m in msgs[i:]:
        node.on_sensor(k, m)
    st = node.follower.status()
    assert st["time_jump"] == 1 and st["time_backwards"] == 1 and node.follower.done
    assert node.aid_count["dvl"] == msgs[0][1]["counts"]["dvl"]


@pytest.mark.parametrize("n", [0, 1])
def test_checkpoint_keeps_the_aid_counts(tmp_path, n):
    """The aid counts survive a checkpoint resume (a restarted ins reports the whole stream's counts), and the
    resumed engine continues as the replay, bit for bit (n=0: the same ins without a checkpoint)."""
    from zennav.checkpoint import Checkpointer
    from zennav.nodes.ins import InsNode

    ds = auv_like(20.0)
    msgs = _msgs(ds)
    path = tmp_path / "ins.ckpt"
    first = InsNode(lambda kind, m: None, log, checkpoint=Checkpointer(path, 5.0))
    cut = next(i for i, (_k, m) in enumerate(msgs) if m["t_ns"] > ds.initial.t_ns + 12 * 10**9)
    for key, m in msgs[:cut]:
        first.on_sensor(key, m)
    status: list = []
    sols: dict = {}
    second = InsNode(lambda kind, m: (status.append(m) if kind == "status" else
                                      sols.__setitem__(m["t_ns"], m) if kind == "solution" else None), log,
                     checkpoint=Checkpointer(path if n else None, 5.0))
    for key, m in (msgs[cut - 500:] if n else msgs):  # from before the checkpoint (duplicates for the merge)
        second.on_sensor(key, m)
    assert second.follower.done and second.recovery["resumed"] == n
    assert status[-1]["aid_counts"] == {a: msgs[0][1]["counts"][a] for a in ("dvl", "depth")}
    ref = run_replay(ds)  # resumed (the DVL and depth sources' states in the checkpoint) or not: the replay's
    t = sorted(sols)
    keep = ref.t_ns >= t[0]
    assert np.array_equal(t, ref.t_ns[keep]) and np.array_equal([sols[x]["llh"] for x in t], ref.llh[keep])


def test_dives_score_each_stretch_under_water():
    """zennav.metrics.dives: a truth under water between 30 and 50 s (5 m below the surface) and a solution that
    drifts north at 0.1 m/s from 30 s: one dive, its path length, 2 m error at its end, drift = 2 m / distance;
    with GNSS fixes under water until 40 s (A-KIT's derived ones), the dive counts from the last, at 40 s."""
    from zennav.metrics import dives, ned_errors
    from zennav.nav import earth
    from zennav.replay import ReplayResult

    ds = load_dataset("sim:car", duration_s=60.0)
    tr = ds.truth
    s = (tr.t_ns - ds.initial.t_ns) / 1e9
    t_fix = (ds.gnss.t_ns - ds.initial.t_ns) / 1e9
    gnss_until_40 = ds.gnss.slice(t_fix <= 40.0)
    ds.gnss = ds.gnss.slice((t_fix < 30.0) | (t_fix > 50.0))
    ds.config = ds.config.with_(depth_surface_h_m=0.0)
    tr.llh[:, 2] = np.where((s >= 30.0) & (s < 50.0), -5.0, 0.0)
    north = np.clip(s - 30.0, 0.0, None) * 0.1
    dlat, _, _ = earth.ned_to_dllh(np.stack([north, 0 * north, 0 * north]), tr.llh[:, 0], tr.llh[:, 2])
    llh = tr.llh + np.column_stack([dlat, 0 * north, 0 * north])
    res = ReplayResult("x", tr.t_ns, llh, np.zeros_like(llh), np.tile([1.0, 0, 0, 0], (len(s), 1)),
                       np.zeros_like(llh), np.zeros(len(s), bool), [])
    (d,) = dives(ds, res)
    inside = (s >= 30.0) & (s < 50.0)
    step = ned_errors(tr.llh[inside][1:], tr.llh[inside][:-1])
    assert d["start_s"] == pytest.approx(30.0, abs=0.02) and d["end_s"] == pytest.approx(50.0, abs=0.02)
    assert d["distance_m"] == pytest.approx(np.hypot(step[:, 0], step[:, 1]).sum()) and d["distance_m"] > 50.0
    assert d["end_horizontal_m"] == pytest.approx(2.0, abs=0.01) == d["max_horizontal_m"]
    assert d["drift_pct"] == pytest.approx(100.0 * d["end_horizontal_m"] / d["distance_m"])
    ds.gnss = gnss_until_40
    (d40,) = dives(ds, res)
    assert d40["start_s"] == pytest.approx(40.0, abs=0.02) and d40["end_s"] == d["end_s"]
    assert d40["distance_m"] == pytest.approx(d["distance_m"] / 2, rel=0.1) and d40["end_horizontal_m"] == d[
        "end_horizontal_m"]


def test_a_dive_bobbing_at_the_surface_without_a_fix_is_one_stretch():
    """Under water 30-40 s and 42-50 s, near the surface between (above the 0.5 m threshold, as A-KIT T11's last two
    minutes): without a GNSS fix there the vehicle dead-reckoned on, so one stretch 30..50 s scores it (not a drift of
    hundreds of percent over a metre); a fix at the surface splits it in two."""
    from zennav.metrics import dives
    from zennav.replay import ReplayResult

    ds = load_dataset("sim:car", duration_s=60.0)
    tr = ds.truth
    s = (tr.t_ns - ds.initial.t_ns) / 1e9
    t_fix = (ds.gnss.t_ns - ds.initial.t_ns) / 1e9
    all_fixes = ds.gnss
    ds.gnss = all_fixes.slice((t_fix < 30.0) | (t_fix > 50.0))
    ds.config = ds.config.with_(depth_surface_h_m=0.0)
    tr.llh[:, 2] = np.where(((s >= 30.0) & (s < 40.0)) | ((s >= 42.0) & (s < 50.0)), -5.0, -0.2)
    res = ReplayResult("x", tr.t_ns, tr.llh.copy(), np.zeros_like(tr.llh), np.tile([1.0, 0, 0, 0], (len(s), 1)),
                       np.zeros_like(tr.llh), np.zeros(len(s), bool), [])
    (d,) = dives(ds, res)
    assert d["start_s"] == pytest.approx(30.0, abs=0.02) and d["end_s"] == pytest.approx(50.0, abs=0.02)
    ds.gnss = all_fixes.slice((t_fix < 30.0) | (t_fix > 50.0) | ((t_fix > 40.5) & (t_fix < 41.5)))
    first, second = dives(ds, res)
    assert first["end_s"] == pytest.approx(40.0, abs=0.02) and second["start_s"] == pytest.approx(42.0, abs=0.02)


def test_replay_metrics_of_an_auv_score_its_dives():
    """`zennav replay sim:auv` (evaluate, format_table): metrics.json carries each dive's drift, the table a row per
    dive, as the page of `zennav report`; a car (no DVL, no depth sensor) gets no dive entry, whatever its heights."""
    from zennav.metrics import dives, evaluate, format_table
    from zennav.report import accuracy_rows

    ds = auv_like(40.0)
    res = run_replay(ds)
    m = evaluate(ds, res)
    (d,) = m["dives"]
    assert m["dives"] == dives(ds, res) and 20.0 < d["start_s"] < 30.0 and d["distance_m"] > 10.0
    assert d["drift_pct"] == pytest.approx(100.0 * d["end_horizontal_m"] / d["distance_m"])
    row = next(line for line in format_table(m).splitlines() if line.startswith("under water"))
    assert f"end {d['end_horizontal_m']:.2f} m" in row and f"drift {d['drift_pct']:.3f} %" in row
    (page_row,) = [vals for name, vals in accuracy_rows(m) if name.startswith("under water")]  # zennav report's
    assert page_row == [row.split("  ", 1)[1].strip().rsplit(" of ", 1)[0]]
    car = load_dataset("sim:car", duration_s=5.0)
    assert "dives" not in evaluate(car, run_replay(car))


def test_monitor_shows_the_dvl_and_depth_records_and_counters():
    """What the ins publishes for an AUV stream, fed to the monitor's core: the nav/aid/dvl and nav/aid/depth
    records per source (fused, rejected), the DVL and depth samples consumed and the engine's partial-beam
    counters in its table."""
    from zennav.nodes.ins import InsNode
    from zennav.nodes.monitor import MonitorState, format_table

    ds = auv_like(30.0)
    mon = MonitorState(K)
    seq: dict = {}

    def publish(kind: str, m: dict) -> None:
        key = {"solution": K.nav_solution(), "status": K.nav_status()}.get(kind) or K.nav_aid(m["source"])
        seq[key] = seq.get(key, -1) + 1
        mon.on_sample(key, M.encode({**m, "src": "ins.x", "seq": seq[key], "pub_ns": 0}), 0)

    node = InsNode(publish, log)
    for key, m in _msgs(ds):
        node.on_sensor(key, m)
    snap = mon.snapshot()
    counts = _msgs(ds)[0][1]["counts"]
    assert snap["nav"]["aid_counts"] == {"dvl": counts["dvl"], "depth": counts["depth"]}
    assert snap["aid"]["dvl"]["fused"] > 100 and snap["aid"]["depth"]["fused"] > 100
    table = format_table(snap)
    assert f"dvl {counts['dvl']}  depth {counts['depth']}  engine {{" in table and "'dvl_beams_4': " in table
    assert "aid dvl " in table and "aid depth " in table


def test_ins_with_the_loose_dvl_publishes_its_records_as_the_replay():
    """An ins whose parameter file says dvl_mode: loose (the baseline): its nav/aid/dvl_loose records and its
    solutions are the in-process replay's with the same settings."""
    from zennav.nodes.ins import InsNode
    from zennav.params import nav_config

    ds = auv_like(40.0)
    msgs = _msgs(ds)
    out: dict = {"solution": [], "status": [], "aid": []}
    node = InsNode(lambda kind, m: out[kind].append(m), log, filter_params={"dvl_mode": "loose"})
    for key, m in msgs:
        node.on_sensor(key, m)
    ds.config = nav_config(ds.config, {"dvl_mode": "loose"})
    ref = run_replay(ds)
    loose = [(r["t_ns"], r["fused"]) for r in out["aid"] if r["source"] == "dvl_loose"]
    assert len(loose) == msgs[0][1]["counts"]["dvl"] and sum(f for _, f in loose) > 100
    assert not any(r["source"] == "dvl" for r in out["aid"])
    assert loose == [(r.t_ns, r.fused) for r in ref.reports if r.source == "dvl_loose"]
    assert np.array_equal(np.array([m["llh"] for m in out["solution"]]), ref.llh)


def test_auv_demo_cli_refuses_what_does_not_apply(tmp_path):
    """`zennav demo --vehicle auv`: GNSS outages are not chosen (GNSS is absent under water), and a dataset without
    a DVL is refused before any process starts."""
    from click.testing import CliRunner

    from zennav.demo_cli import demo

    r = CliRunner().invoke(demo, ["--vehicle", "auv", "--outage", "10:5", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "no GNSS under water" in r.output
    r = CliRunner().invoke(demo, ["--vehicle", "auv", "--dataset", "sim:car", "--duration", "30",
                                  "--out", str(tmp_path)])
    assert r.exit_code == 1 and "has no DVL" in r.output and not (tmp_path / "launch.log").exists()
