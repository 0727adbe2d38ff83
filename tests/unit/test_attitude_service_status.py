"""The attitude service's node (no transport) against the core's batch, and the nav_status alignment /
measurement-noise fields: built by the ins node, validated strictly, compatible with messages without them."""
from __future__ import annotations

import copy
import logging
import random
from dataclasses import replace

import numpy as np
import pytest

from zennav import messages as M
from zennav.attitude.complementary import AdaptiveComplementaryFilter
from zennav.nodes.attitude import AttitudeNode, omega_in_n_of
from zennav.params import load_attitude_params as load_config

K = M.Keys("car")
log = logging.getLogger("test")


def _stream(duration_s: float, heading_unknown: bool = False):
    """The messages ingest publishes for sim:car (zennav.stream.stream_messages, with header fields), as
    (key, message) in cseq order."""
    from zennav.datasets.registry import load_dataset
    from zennav.replay import sensor_events
    from zennav.stream import stream_messages

    ds = load_dataset("sim:car", duration_s=duration_s)
    if heading_unknown:
        ds.initial = replace(ds.initial, heading_known=False)
    windows, events = sensor_events(ds)
    key = {"imu": K.imu(), "gnss": K.gnss(), "stream": K.stream()}
    return [(key[kind], {**m, "src": "ingest.x", "seq": 0, "pub_ns": 0})
            for kind, m in stream_messages(ds, windows, events)]


def _reference(msgs, cfg, out):
    """The core's batch over the stream's IMU samples with the omega_in_n, a_b and v_b the node published."""
    imu = [m for _, m in msgs if m["schema"] == "imu"]
    dt = np.array([m["dt_ns"] for m in imu], dtype=float) / 1e9
    omega = np.array([m["dtheta"] for m in imu]) / dt[:, None]
    f = np.array([m["dvel"] for m in imu]) / dt[:, None]
    w_in = np.array([o["omega_in_n"] for o in out])
    a_b, v_b = (None, None) if out[0]["accel_b"] is None else (np.array([o[k] for o in out])
                                                              for k in ("accel_b", "vel_b"))
    return imu, AdaptiveComplementaryFilter(cfg).batch(omega, f, dt=dt, omega_in_n=w_in, a_b=a_b, v_b=v_b)


def test_attitude_node_equals_core_batch_bit_for_bit_in_any_arrival_order():
    """Shuffled arrival (the cseq merge restores the order), the levelling window held and run as one batch,
    then steps: the published quaternions, biases and weights are the core's batch output exactly, and
    omega_in_n from a nav solution is applied once one is there (and published with each sample)."""
    cfg, _ = load_config()
    msgs = _stream(20.0)
    out = []
    node = AttitudeNode(out.append, log, cfg, K.imu())
    head, tail = msgs[:1], msgs[1:]
    rnd = random.Random(1)
    for i in range(0, len(tail) - 8, 8):  # shuffle within blocks of 8
        blk = tail[i:i + 8]
        rnd.shuffle(blk)
        tail[i:i + 8] = blk
    sol = {"t_ns": 0, "llh": [0.53, 1.99, 40.0], "v_n": [10.0, -5.0, 0.1], "q_nb": [1.0, 0.0, 0.0, 0.0]}
    for n, (key, m) in enumerate(head + tail):
        if n == 500:  # a solution arrives: its sample time must be near the IMU's for it to be used
            sol["t_ns"] = m["t_ns"]
            node.on_solution(sol)
        node.on_sensor(key, m)
    imu, ref = _reference(msgs, cfg, out)
    assert len(out) == len(imu) == 4000 and node.follower.done
    assert [o["t_ns"] for o in out] == [m["t_ns"] for m in imu]
    assert np.array_equal(np.array([o["q_nb"] for o in out]), ref.q_nb)
    assert np.array_equal(np.array([o["gyro_bias"] for o in out]), ref.bias_b)
    assert np.array_equal(np.array([o["weight"] for o in out]), ref.weight)
    w = np.array([o["omega_in_n"] for o in out])
    used = np.any(w != 0.0, axis=1)
    assert 0 < used.sum() < len(out) and np.array_equal(w[used][0], omega_in_n_of(sol["llh"], sol["v_n"]))
    assert np.linalg.norm(w[used][0]) == pytest.approx(7.29e-5, rel=0.05)
    assert node.counts["rate_applied"] == used.sum()
    assert out[-1]["euler"] == M.euler_list(*out[-1]["q_nb"])
    v = M.Validator()
    for o in out[:50]:
        assert v.check(K.attitude(), M.encode({**o, "src": "a", "seq": 0, "pub_ns": 0}))[0] is not None
    # against the sim's truth while the car stands (the first 8 s): roll and pitch within 0.25 deg (what is left
    # is the simulated MEMS accelerometer bias, about 0.13 deg here, which no accelerometer levelling removes)
    from zennav.datasets.registry import load_dataset

    truth = load_dataset("sim:car", duration_s=20.0).truth
    t = np.array([o["t_ns"] for o in out])
    idx = np.searchsorted(truth.t_ns, t)
    assert np.array_equal(truth.t_ns[idx], t)
    still = (t - t[0]) < 7.5e9
    err = np.array([o["euler"][:2] for o in out])[still] - truth.euler[idx[still], :2]
    assert np.abs(err).max() < np.radians(0.25)


def _truth_tilt_deg(out, duration_s):
    """Tilt error of published attitudes against sim:car's truth [deg], per sample."""
    from zennav.datasets.registry import load_dataset
    from zennav.nav.rotation import euler_to_quat, quat_to_dcm

    truth = load_dataset("sim:car", duration_s=duration_s).truth
    idx = np.searchsorted(truth.t_ns, [o["t_ns"] for o in out])
    d_true = np.array([quat_to_dcm(euler_to_quat(e))[2] for e in truth.euler[idx]])  # down axis in b
    d_est = np.array([quat_to_dcm(np.array(o["q_nb"]))[2] for o in out])
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", d_true, d_est), -1.0, 1.0)))


def test_attitude_node_velocity_reference_from_the_ins_and_stale_velocity_rejected():
    """Velocity source ins (the default): the ins core's solutions reach the attitude node after each IMU sample, as
    live, and stop at 60 s (a dead ins). Until then a_b is applied to every sample and the tilt stays within 1 deg
    of the truth through the drive's accelerations (the filter alone, source none, exceeds 5 deg); after
    60 + accel_max_age s the velocity is stale: not used (zeros published), counted; the output is the core's batch
    with the published a_b, v_b bit for bit; the status says which reference."""
    from zennav.nodes.ins import InsNode

    cfg, _ = load_config()
    msgs = _stream(90.0)
    states = []
    runs = {}
    for source in ("ins", "none"):
        out = []
        node = AttitudeNode(out.append, log, cfg, K.imu(), velocity_source=source, gnss_key=K.gnss(),
                            on_state=states.append)
        stop_ns = msgs[0][1]["initial"]["t_ns"] + 60_000_000_000

        def on_ins(kind, m, node=node, stop_ns=stop_ns):
            if kind == "solution" and m["t_ns"] <= stop_ns:
                node.on_solution(m)

        ins = InsNode(on_ins, log)
        for key, m in msgs:
            node.on_sensor(key, m)
            ins.on_sensor(key, m)
        runs[source] = (out, node)
    out, node = runs["ins"]
    imu, ref = _reference(msgs, cfg, out)
    assert np.array_equal(np.array([o["q_nb"] for o in out]), ref.q_nb)
    t = (np.array([o["t_ns"] for o in out]) - msgs[0][1]["initial"]["t_ns"]) / 1e9
    a_b = np.array([o["accel_b"] for o in out])
    used = np.any(a_b != 0.0, axis=1)
    assert used[t <= 60.0].all() and not used[t > 61.5].any()
    c = node.counters()
    assert c["velocity_source"] == "ins" and c["accel_applied"] == used.sum() > 0
    assert c["accel_stale"] == (t > 61.5).sum() > 0 and c["accel_none"] == 0
    assert "gravity reference: ins velocity (nav/solution) compensated" in states[0]
    assert "gravity reference: accelerometer alone" in states[-1]
    err = _truth_tilt_deg(out, 90.0)
    alone = _truth_tilt_deg(runs["none"][0], 90.0)
    assert err[t <= 60.0].max() < 1.0 and alone[t <= 60.0].max() > 5.0, (err.max(), alone.max())
    assert runs["none"][0][0]["accel_b"] is None and "accel_applied" not in runs["none"][1].counters()
    print(f"\ntilt vs truth, first 60 s of sim:car: ins reference max {err[t <= 60.0].max():.2f} deg, filter alone "
          f"{alone[t <= 60.0].max():.2f} deg; after the ins stopped: {c['accel_stale']} samples stale")


def test_attitude_node_gnss_velocity_reference_stale_in_an_outage():
    """Velocity source gnss: the fixes' speed in the sensor stream; in a 10 s GNSS outage the estimate goes stale
    accel_max_age after the last fix and is not used until two fixes are back; bit for bit the core's batch."""
    from zennav.datasets.registry import load_dataset
    from zennav.replay import sensor_events
    from zennav.stream import stream_messages

    ds = load_dataset("sim:car", duration_s=40.0)
    windows, events = sensor_events(ds, outages=[(15.0, 10.0)])
    key = {"imu": K.imu(), "gnss": K.gnss(), "stream": K.stream()}
    msgs = [(key[kind], {**m, "src": "ingest.x", "seq": 0, "pub_ns": 0})
            for kind, m in stream_messages(ds, windows, events)]
    cfg, _ = load_config()
    out = []
    node = AttitudeNode(out.append, log, cfg, K.imu(), velocity_source="gnss", gnss_key=K.gnss(),
                        accel_max_age_s=1.5)
    for k, m in msgs:
        node.on_sensor(k, m)
    imu, ref = _reference(msgs, cfg, out)
    assert np.array_equal(np.array([o["q_nb"] for o in out]), ref.q_nb)
    t = (np.array([o["t_ns"] for o in out]) - ds.initial.t_ns) / 1e9
    used = np.any(np.array([o["accel_b"] for o in out]) != 0.0, axis=1)
    c = node.counters()
    assert c["velocity_source"] == "gnss" and c["velocity_samples"] == 30  # 40 fixes at 1 Hz, 10 withheld
    assert not used[(t > 15.5) & (t < 26.0)].any() and used[(t >= 2.0) & (t <= 15.5)].all() and used[t >= 26.0].all()
    # stale: the outage's samples from 1.5 s after the last fix (14 s) until the second fix after it (26 s)
    assert c["accel_stale"] == ((t > 15.5) & (t < 26.0)).sum() and c["accel_none"] == (t < 2.0).sum()
    assert c["accel_applied"] == used.sum()


def test_attitude_node_takes_imu_batches_as_their_samples():
    """ingest --batch: runs of consecutive imu messages sent as imu_batch give the same attitudes."""
    cfg, _ = load_config()
    msgs = _stream(12.0)

    def run(stream):
        out = []
        node = AttitudeNode(out.append, log, cfg, K.imu())
        for key, m in stream:
            node.on_sensor(key, m)
        return out

    batched, run_ = [], []

    def flush():
        if run_:
            ts = [m["t_ns"] for m in run_]
            b = M.imu_batch_msg(ts, [m["dt_ns"] for m in run_], [m["dtheta"] for m in run_],
                                [m["dvel"] for m in run_], run_[0]["cseq"])
            b.update(src="ingest.x", seq=0, pub_ns=0)
            batched.append((K.imu(), b))
            run_.clear()

    for key, m in msgs:
        if m["schema"] == "imu":
            run_.append(m)
            if len(run_) == 9:
                flush()
        else:
            flush()
            batched.append((key, m))
    flush()
    assert len(batched) < len(msgs) / 4
    assert run(batched) == run(msgs)


def test_attitude_node_late_join_and_without_solution_zero_rate():
    """Started after the stream began: joins at the first IMU sample it receives, with the stream's start asked
    for (fetch_start, the ingest's latest value on the bus), and levels from there."""
    cfg, _ = load_config()
    msgs = _stream(5.0)
    out = []
    asked = []
    node = AttitudeNode(out.append, log, cfg, K.imu(), fetch_start=lambda src: asked.append(src) or msgs[0][1])
    first = next(i for i in range(101, len(msgs)) if msgs[i][1]["schema"] == "imu")
    for key, m in msgs[101:]:  # stream_start and the first 100 messages missed
        node.on_sensor(key, m)
    assert asked == ["ingest.x"] and node.follower.counts["late_join"] == 1 and node.follower.done
    n_imu = sum(m["schema"] == "imu" for _, m in msgs[first:])
    assert len(out) == n_imu and out[0]["t_ns"] == msgs[first][1]["t_ns"]
    assert all(o["omega_in_n"] == [0.0, 0.0, 0.0] for o in out)


def _ins_status(duration_s, adaptive_r: bool = False, **kw):
    from zennav.nodes.ins import InsNode

    out = []
    node = InsNode(lambda kind, m: out.append((kind, m)), log, {"adaptive_r": adaptive_r})
    for key, m in _stream(duration_s, **kw):
        node.on_sensor(key, m)
    return [m for kind, m in out if kind == "status"]


def test_ins_status_carries_alignment_and_live_r_and_validates():
    st = _ins_status(100.0, heading_unknown=True, adaptive_r=True)
    states = [m["alignment"]["state"] for m in st]
    seen = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert seen == ["coarse", "fine", "aligned"]
    last = st[-1]
    assert last["adaptive_r"] is True and set(last["measurement_noise"]) == {"gnss_pos", "gnss_vel"}
    r = last["measurement_noise"]["gnss_pos"]
    assert len(r["R_diag"]) == 3 and min(r["R_diag"]) > 0 and len(r["ratio"]) == 3
    assert r["branch"] in ("inflate", "fading")
    al = last["alignment"]
    assert al["method"] == "in_motion" and al["heading_std_rad"] < np.radians(0.5)
    assert al["times_ns"]["coarse"] < al["times_ns"]["fine"] < al["times_ns"]["aligned"]
    v = M.Validator()
    for m in st:
        assert v.check(K.nav_status(), M.encode({**m, "src": "ins", "seq": 0, "pub_ns": 0}))[0] is not None
    # adaptive off: R is the one used, no ratio, branch 'fixed'
    off = _ins_status(30.0, adaptive_r=False)[-1]
    assert off["adaptive_r"] is False and off["measurement_noise"]["gnss_pos"]["branch"] == "fixed"
    assert off["measurement_noise"]["gnss_pos"]["ratio"] is None and off["alignment"]["method"] == "given"


def _status(**extra):
    m = M.make("nav_status", 5, gnss_state="valid", counters={}, rejected={}, imu_count=0, gnss_count=0,
               stream={}, model={}, **extra)
    m.update(src="ins", seq=0, pub_ns=0)
    return m


GOOD_AL = {"state": "fine", "method": "in_motion", "heading_std_rad": 0.02, "times_ns": {"coarse": 1, "fine": 3},
           "tilt_source": "levelling", "gyrocompass": "", "initial_state": "accepted"}
GOOD_R = {"gnss_pos": {"R_diag": [1.0, 1.0, 4.0], "ratio": [1.5, 1.5, 1.0], "branch": "fading", "k": 30,
                       "inflate": 0, "fading": 10},
          "gnss_vel": {"R_diag": [0.01] * 3, "ratio": None, "branch": "fixed"}}


@pytest.mark.parametrize("mutate, code", [
    (lambda m: m["alignment"].update(state="done"), "bad_value"),
    (lambda m: m["alignment"].update(method=3), "bad_type"),
    (lambda m: m["alignment"].update(initial_state=None), "bad_type"),
    (lambda m: m["alignment"].update(heading_std_rad=-1.0), "bad_value"),
    (lambda m: m["alignment"].update(times_ns={"coarse": 1.5}), "bad_value"),
    (lambda m: m["alignment"].update(heading_std_rad=float("nan")), "not_finite"),
    (lambda m: m.update(adaptive_r=1), "bad_type"),
    (lambda m: m.update(alignment="aligned"), "bad_type"),
    (lambda m: m["measurement_noise"]["gnss_pos"].update(R_diag=[1.0, -1.0, 1.0]), "bad_value"),
    (lambda m: m["measurement_noise"]["gnss_pos"].update(ratio=[1.0, 1.0]), "bad_value"),
    (lambda m: m["measurement_noise"]["gnss_pos"].pop("branch"), "bad_type"),
    (lambda m: m["measurement_noise"]["gnss_pos"].update(k=1.0), "bad_type"),
    (lambda m: m["measurement_noise"].update({"a/b": GOOD_R["gnss_vel"]}), "bad_value"),
    (lambda m: m["measurement_noise"].update(gnss_pos=[1.0]), "bad_type"),
])
def test_nav_status_extras_validated_strictly(mutate, code):
    good = _status(alignment=copy.deepcopy(GOOD_AL), adaptive_r=True, measurement_noise=copy.deepcopy(GOOD_R))
    assert M.validate_map(copy.deepcopy(good), K.nav_status()) == ""
    bad = copy.deepcopy(good)
    mutate(bad)
    r = M.validate_map(bad, K.nav_status())
    assert r.split(":")[0] == code, r


def test_nav_status_and_attitude_without_the_new_fields_still_valid():
    """Compatible addition: a v1 message of an older ins/attitude service (no optional fields) validates."""
    assert M.validate_map(_status(), K.nav_status()) == ""
    assert M.validate_map(_status(alignment=None, measurement_noise=None), K.nav_status()) == ""
    att = M.make("attitude", 1, q_nb=[1.0, 0.0, 0.0, 0.0], euler=[0.0] * 3, gyro_bias=[0.0] * 3, weight=1.0)
    att.update(src="a", seq=0, pub_ns=0)
    assert M.validate_map(att, K.attitude()) == ""
    assert M.validate_map({**att, "omega_in_n": [1.0, 2.0]}, K.attitude()).startswith("bad_shape")


def test_ins_takes_the_attitude_tilt_only_in_coarse_alignment_at_rest_unrejected():
    """--attitude-alignment: roll/pitch from the attitude service replace an uncertain initial tilt while the
    heading is unknown and the vehicle stands; a rejected sample (weight < 1) is not taken."""
    from zennav.nodes.ins import InsNode

    msgs = _stream(10.0, heading_unknown=True)
    msgs[0][1]["initial"]["std_euler"][:2] = [np.radians(10.0)] * 2
    node = InsNode(lambda kind, m: None, log)
    for key, m in msgs[:300]:
        node.on_sensor(key, m)
    nav = node.nav
    assert nav.align_state == "coarse"
    att = {"t_ns": nav.t_ns, "euler": [0.01, -0.02, 1.0], "weight": 0.5}
    assert not node.on_attitude(att, np.radians(1.0))
    assert node.on_attitude({**att, "weight": 1.0}, np.radians(1.0))
    al = nav.status()["alignment"]
    assert al["tilt_source"] == "attitude_source" and node.attitude_taken == 1
    roll, pitch, _ = M.euler_list(*nav.state.q_nb.tolist())
    assert roll == pytest.approx(0.01, abs=1e-9) and pitch == pytest.approx(-0.02, abs=1e-9)


def test_monitor_state_and_table_show_alignment_r_and_attitude():
    from zennav.nodes.monitor import MonitorState, format_table

    st = MonitorState(K)
    m = _status(alignment=copy.deepcopy(GOOD_AL), adaptive_r=True, measurement_noise=copy.deepcopy(GOOD_R))
    st.on_sample(K.nav_status(), M.encode(m), 0)
    att = M.make("attitude", 7, q_nb=[1.0, 0.0, 0.0, 0.0], euler=[0.01, -0.02, 0.5], gyro_bias=[1e-5, 0.0, 0.0],
                 weight=0.75, omega_in_n=[6e-5, 0.0, -4e-5])
    att.update(src="att", seq=0, pub_ns=0)
    st.on_sample(K.attitude(), M.encode(att), 0)
    snap = st.snapshot()
    al = snap["nav"]["alignment"]
    # [s] since coarse began (rounded to ms)
    assert al["state"] == "fine" and al["times_s"] == {"coarse": 0.0, "fine": 0.0}
    assert al["heading_std_deg"] == pytest.approx(np.degrees(0.02), abs=1e-4)
    assert snap["nav"]["measurement_noise"] == GOOD_R and snap["nav"]["adaptive_r"] is True
    assert snap["attitude"]["gyro_bias_dph"][0] == pytest.approx(2.0626, rel=1e-4)
    text = format_table(snap)
    for s in ("alignment fine", "heading 1-sigma 1.146 deg", "adaptive R on", "R gnss_pos", "branch fading",
              "R/reported [1.50, 1.50, 1.00]", "R/reported -", "weight 0.75", "earth+transport rate applied"):
        assert s in text, (s, text)


def test_monitor_keeps_a_second_ins_apart():
    """A second ins on the same stream publishes under a nav prefix (zennav-ins --nav-prefix plain): the monitor
    keeps its status and aid sources apart from the first ins's, and shows both."""
    from zennav.nodes.monitor import MonitorState, format_table

    plain = M.Keys("car", nav_prefix="plain")
    st = MonitorState(K)
    st.on_sample(K.nav_status(), M.encode(_status(alignment=copy.deepcopy(GOOD_AL))), 0)
    other = _status()
    other.update(gnss_state="outage", imu_count=7, stream={"done": True})
    st.on_sample(plain.nav_status(), M.encode(other), 0)
    rep = M.make("aid_report", 5, source="gnss_pos", observation=[1.0], innovation=[0.1], innovation_var=[1.0],
                 test_ratio=0.5, fused=True, reason="")
    rep.update(src="ins-plain", seq=0, pub_ns=0)
    st.on_sample(plain.nav_aid("gnss_pos"), M.encode(rep), 0)
    snap = st.snapshot()
    assert snap["nav"]["gnss_state"] == "valid" and snap["nav"]["alignment"]["state"] == "fine"
    assert snap["navs"]["plain"]["gnss_state"] == "outage" and snap["navs"]["plain"]["imu_count"] == 7
    assert set(snap["aid"]) == {"plain/gnss_pos"}
    assert sum(sum(k["rejected"].values()) for k in snap["keys"].values()) == 0
    assert "NAV/plain  gnss outage  imu 7" in format_table(snap)
