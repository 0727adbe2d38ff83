"""The distributed pipeline (ingest -> ins over Zenoh, separate processes) against the in-process replay."""
from __future__ import annotations

import math
import random
import re

import msgpack
import numpy as np
import pytest
from zennav_harness import Collector, wait_until

from zennav import messages as M

OUTAGE = (200.0, 60.0)  # GNSS withheld 200..260 s


def _replay(duration_s, outages):
    from zennav.datasets.registry import load_dataset
    from zennav.replay import run_replay

    return run_replay(load_dataset("sim:car", duration_s=duration_s), outages=outages)


def _check_equal(sols, ref, tol=1e-9):
    t = np.array([m["t_ns"] for m in sols], dtype=np.int64)
    assert len(t) == len(ref.t_ns)
    assert np.array_equal(t, ref.t_ns)
    llh = np.array([m["llh"] for m in sols])
    v = np.array([m["v_n"] for m in sols])
    q = np.array([m["q_nb"] for m in sols])
    std = np.array([m["std_pos_ned"] for m in sols])
    err = {"lat_rad": np.abs(llh[:, :2] - ref.llh[:, :2]).max(), "h_m": np.abs(llh[:, 2] - ref.llh[:, 2]).max(),
           "v_mps": np.abs(v - ref.v_n).max(), "q": np.abs(q - ref.q_nb).max(),
           "std_m": np.abs(std - ref.std_pos_ned).max()}
    assert max(err.values()) <= tol, err
    outage = np.array([m["gnss_state"] != "valid" for m in sols])
    assert np.array_equal(outage, ref.outage)
    return err


def test_pipeline_10min_200hz_full_speed_equals_replay_no_loss(cluster):
    """600 s of 200 Hz IMU (120,000 samples) from the simulated drive, GNSS outage 200..260 s, streamed as fast
    as the ins drains: every solution equals the in-process replay to 1e-9 (in fact bit for bit), no sample is
    lost or duplicated anywhere (ingest counts, ins counts, solution sequence, per-publisher seq)."""
    k = cluster.keys
    sols = Collector(cluster.bus, k.nav_solution())
    aids = Collector(cluster.bus, k.nav_aid())
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    cluster.service("ins")
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=600", "--speed", "0",
                          "--outage", f"{OUTAGE[0]}:{OUTAGE[1]}", wait=False)
    ref = _replay(600.0, [OUTAGE])
    st = status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")), None), 240,
                     "ins to finish the stream")
    assert ing.wait(60) == 0
    n = len(ref.t_ns)
    assert n == 120_000
    sols.wait(lambda c: len(c.msgs()) >= n, 60, "all solutions")
    msgs = sols.msgs()
    # nothing lost or duplicated
    assert st["imu_count"] == n and st["stream"]["solutions"] == n
    assert st["stream"].get("gap", 0) == 0 and st["stream"].get("duplicate", 0) == 0
    assert st["rejected"] == {"foreign_source": 0, "no_stream": 0, "duplicate_start": 0, "late_join": 0,
                              "takeover_refused": 0}
    cseq = [m["imu_cseq"] for m in msgs]
    assert len(set(cseq)) == n and cseq == sorted(cseq)
    assert [m["seq"] for m in msgs] == list(range(n))
    err = _check_equal(msgs, ref)
    print(f"\nmax |distributed - replay|: {err}; ins consumed {n} IMU in {st['stream']['wall_s']:.2f} s "
          f"({n / st['stream']['wall_s']:.0f}/s)")
    # the aiding reports are the same too
    rep = [(r.source, r.t_ns, r.fused) for r in ref.reports]
    got = [(m["source"], m["t_ns"], m["fused"]) for m in
           aids.wait(lambda c: c.msgs() if len(c.msgs()) >= len(rep) else None, 30, "every aid report")]
    assert sorted(got) == sorted(rep)
    assert cluster.bus.rejected == {}


@pytest.mark.parametrize("ins_args", [(), ("--compiled",), ("--compiled", "--solution-batch", "3")],
                         ids=["step", "compiled", "solution-batch"])
def test_batched_ingest_gives_the_same_solution(cluster, ins_args):
    """ingest --batch 7 (imu_batch messages, cut before every GNSS fix), to the step-wise ins and to the ins's
    compiled block loop (whole batches, solutions packed from its rows; or, --solution-batch 3, a stretch's solutions
    in nav_solution_batch messages of at most 3, which the subscription hands over one by one): the same 24,000
    solutions as the in-process replay, bit for bit, one per IMU sample, nothing lost or duplicated."""
    k = cluster.keys
    sols = Collector(cluster.bus, k.nav_solution())
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    cluster.service("ins", *ins_args, timeout=120)  # --compiled: the first run on a machine compiles the kernels
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=120", "--speed", "0", "--batch", "7",
                          "--outage", "50:20", wait=False)
    ref = _replay(120.0, [(50.0, 20.0)])
    st = status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")), None), 120,
                     "ins to finish the stream")
    assert ing.wait(60) == 0
    n = len(ref.t_ns)
    sols.wait(lambda c: len(c.msgs()) >= n, 60, "all solutions")
    msgs = sols.msgs()
    assert st["imu_count"] == n == 24_000 and st["stream"]["solutions"] == n
    assert st["stream"].get("gap", 0) == 0 and st["stream"].get("duplicate", 0) == 0
    assert [m["imu_cseq"] for m in msgs] == sorted({m["imu_cseq"] for m in msgs})
    assert max(_check_equal(msgs, ref, tol=0.0).values()) == 0.0
    assert cluster.bus.rejected == {}


def _bad(kind: str, key: str, src: str, t_old: int) -> bytes:
    """One bad payload of the given kind for ``key``."""
    if kind == "random":
        return bytes(random.Random(hash(key) & 0xFFFF).getrandbits(8) for _ in range(64))
    stream = M.stream_of(key)
    schema = stream.schemas[0]
    if kind == "wrong_schema":
        m = M.service_status_msg("intruder", "running")
    else:
        m = _valid(schema, t_old)
        if kind == "nan":  # NaN in the first float list, else inside the first map field
            fields = M.SCHEMAS[schema].fields
            f = next((f for f, s in fields.items() if isinstance(s, tuple) and s[0] in ("vec", "floats")), None)
            if f is not None:
                m[f] = [math.nan] + list(m[f])[1:]
            else:
                f = next(f for f, s in fields.items() if s == "map")
                m[f] = {"x": math.nan}
    m.update(src=src if kind == "backwards" else "intruder", seq=0, pub_ns=0)
    return msgpack.packb(m)


def _valid(schema: str, t: int) -> dict:
    base = {"imu": dict(cseq=1, dt_ns=5_000_000, dtheta=[0.0] * 3, dvel=[0.0] * 3),
            "gnss": dict(cseq=1, llh=[0.5, 2.0, 30.0], std_ned=[1.0] * 3, v_n=None, std_v_n=None, fix=1, num_sats=9),
            "stream_start": dict(cseq=0, dataset="x", config={}, initial={}, counts={}, outages=[]),
            "correction": dict(kind="pos_ned", value=[1.0, 2.0, 3.0], std=[1.0] * 3, model="m", version=1),
            "learn_sample": dict(features=[1.0, 2.0], target=[0.5], variant="a"),
            "model_params": dict(name="m", version=1, kind="anfis", created_t_ns=0, norm={}, arrays={}, metrics={},
                                 checksum=""),
            "nav_status": dict(gnss_state="valid", counters={}, rejected={}, imu_count=0, gnss_count=0, stream={},
                               model={})}[schema]
    return M.make(schema, t, **base)


def test_bad_payloads_rejected_counted_services_survive_solution_unchanged(cluster):
    """Random bytes, a wrong schema, NaN and time going backwards on every key a service subscribes to, during
    a stream: each is rejected and counted by each subscriber, every service keeps running, and the
    navigation solution equals the clean in-process replay."""
    k = cluster.keys
    sols = Collector(cluster.bus, k.nav_solution())
    starts = Collector(cluster.bus, k.stream())
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    svc = Collector(cluster.bus, k.svc_status(), channel="ring")
    for name in ("ins", "attitude", "predictor", "trainer"):
        cluster.service(name)
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=60", "--speed", "4", "--outage", "20:10",
                          "--wait-for", "ins,attitude", wait=False)
    start = starts.wait(lambda c: next(iter(c.msgs("stream_start")), None), 60, "stream start")
    sols.wait(lambda c: len(c.msgs()) > 400, 60, "the stream to be under way")
    ins_src = status.wait(lambda c: next((m["src"] for m in c.msgs()), None), 30, "an ins status")
    # time going backwards is judged per publisher: use the real publisher of the key (ingest for the sensor
    # keys, ins for nav/status); keys nobody publishes here first get one valid message from the test
    own_src = "tester-bad"
    srcs = {k.imu(): start["src"], k.gnss(): start["src"], k.stream(): start["src"], k.nav_status(): ins_src,
            k.learn_correction(): own_src, k.learn_samples(): own_src, k.learn_model("anfis"): own_src}
    t_bad = start["t_ns"] - 1_000_000_000
    injected = 0
    for key, src in srcs.items():
        pub = cluster.bus.publisher(key, latest=False)
        if src == own_src and M.stream_of(key).time != "none":
            good = _valid(M.stream_of(key).schemas[0], start["t_ns"])
            good.update(src=own_src, seq=0, pub_ns=0)
            pub.put_raw(msgpack.packb(good))
        for kind in ("random", "wrong_schema", "nan", "backwards"):
            if kind == "backwards" and M.stream_of(key).time == "none":
                continue
            pub.put_raw(_bad(kind, key, src, t_bad))
            injected += 1
    assert injected == 27
    st = status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")), None), 120,
                     "ins to finish the stream")
    assert ing.wait(60) == 0
    expect = {  # service -> reason codes it must have counted (each of its keys got each kind once)
        # the sensor keys' time order is the stream merge's: their "backwards" samples (cseq already consumed)
        # are dropped there as duplicates, below
        "ins": {"decode_error": 4, "wrong_schema": 4, "not_finite": 4, "time_backwards": 1},
        "attitude": {"decode_error": 3, "wrong_schema": 3, "not_finite": 3},
        "predictor": {"decode_error": 2, "wrong_schema": 2, "not_finite": 2, "time_backwards": 1},
        "trainer": {"decode_error": 1, "wrong_schema": 1, "not_finite": 1, "time_backwards": 1},
    }

    def counted():
        last = {}
        for m in svc.msgs():
            last[m["service"]] = m["rejected"]
        return all(last.get(s, {}) == e for s, e in expect.items()) and last

    got = wait_until(counted, 30, f"rejection counters {expect} (have: {svc.msgs()[-4:] if svc.msgs() else None})",
                     svc.event)
    print(f"\nrejections counted per service: {got}")
    cluster.wait_alive(["ins", "attitude", "predictor", "trainer"], 5)
    assert all(p.alive() for p in cluster.procs if p.name != "ingest")
    sols.wait(lambda c: len(c.msgs()) >= st["stream"]["solutions"], 30, "all solutions")
    ref = _replay(60.0, [(20.0, 10.0)])
    _check_equal(sols.msgs(), ref)
    assert st["stream"].get("gap", 0) == 0 and st["stream"].get("duplicate", 0) == 2  # the imu and gnss ones
    assert st["rejected"]["duplicate_start"] == 1


def test_second_ins_with_nav_prefix_beside_the_first(cluster, tmp_path):
    """The demo's no-learning row over the bus: a second ins (--name ins-plain --nav-prefix plain) on the same
    stream publishes on <base>/nav/plain/...: both solutions equal the in-process replay bit for bit, the ingest
    waits for both acknowledgements, and `zennav record --until-stream-end` stops only once both are recorded."""
    from zennav.recording import read_mcap

    k = cluster.keys
    plain = M.Keys(k.vehicle, nav_prefix="plain")
    sols, sols_plain = Collector(cluster.bus, k.nav_solution()), Collector(cluster.bus, plain.nav_solution())
    cluster.service("ins")
    p = cluster.start("ins-plain", "zennav.services.ins", "--name", "ins-plain", "--nav-prefix", "plain")
    cluster.wait_alive(["ins-plain"], 30, p)
    out = tmp_path / "two.mcap"
    rec = cluster.zennav("record", "record", str(out), "--until-stream-end", bus_args=True)
    cluster.wait_alive(["record"], 30, rec)
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=60", "--speed", "0", "--outage", "20:10",
                          "--wait-for", "ins,ins-plain,record", wait=False)
    assert ing.wait(120) == 0, ing.text()
    assert "acknowledged by" in ing.text() and ing.text().count("ins-plain.") >= 1
    assert rec.wait(60) == 0, rec.text()
    ref = _replay(60.0, [(20.0, 10.0)])
    n = len(ref.t_ns)
    for c in (sols, sols_plain):
        c.wait(lambda c: len(c.msgs()) >= n, 30, "all solutions")
        assert max(_check_equal(c.msgs(), ref, tol=0.0).values()) == 0.0
    for key in (k.nav_solution(), plain.nav_solution()):
        assert sum(1 for _ in read_mcap(out, [re.escape(key) + "$"])) == n, key
    assert cluster.bus.rejected == {}


def test_ins_started_mid_stream_joins_late_and_aligns(cluster):
    """An ins started 25 s into a stream (as after a restart): it asks the ingest for the stream's start over the
    bus, joins at the first IMU sample it gets (counted late_join), aligns in motion from the GNSS fixes and
    follows the stream to its end; the ingest waits for its acknowledgement too."""
    k = cluster.keys
    late = M.Keys(k.vehicle, nav_prefix="late")
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    late_status = Collector(cluster.bus, late.nav_status(), channel="ring")
    cluster.service("ins")
    # --cache 0: nothing to recover the missed samples from (test_fault_tolerance: with the cache, the whole stream)
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=120", "--speed", "4", "--cache", "0", wait=False)
    status.wait(lambda c: any(m["t_ns"] - c.msgs()[0]["t_ns"] > 25e9 for m in c.msgs()), 60, "25 s of the stream")
    p = cluster.start("ins-late", "zennav.services.ins", "--name", "ins-late", "--nav-prefix", "late")
    st = late_status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")), None), 90,
                          "the late ins to finish the stream")
    assert ing.wait(60) == 0, ing.text()
    assert st["rejected"]["late_join"] == 1 and st["rejected"]["no_stream"] == 0, (st["rejected"], p.text())
    assert st["alignment"]["state"] == "aligned" and st["alignment"]["method"] == "in_motion"
    first = status.msgs()[-1]
    assert 0 < st["imu_count"] < first["imu_count"] == 24_000 and st["stream"]["src"] == first["stream"]["src"]
    assert "ins-late." in ing.text().split("end of stream acknowledged by")[1].splitlines()[0]


def test_ingest_does_not_wait_for_a_dead_ins(cluster):
    """The ingest waits for the end's acknowledgement of every ins that followed the stream as long as it lives;
    one that died mid-stream is given up --ack-timeout seconds later (the ingest still exits cleanly)."""
    import signal
    import time

    k = cluster.keys
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    ins = cluster.service("ins")
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=120", "--speed", "8", "--ack-timeout", "3",
                          wait=False)
    status.wait(lambda c: len(c.msgs()) > 3, 60, "the ins under way")
    ins.p.send_signal(signal.SIGKILL)
    t0 = time.monotonic()
    assert ing.wait(90) == 0, ing.text()
    assert "end of stream NOT acknowledged by ['ins." in ing.text(), ing.text()[-2000:]
    assert time.monotonic() - t0 < 60
