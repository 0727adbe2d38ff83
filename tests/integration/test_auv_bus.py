"""The AUV over the bus (issue 14 item 7): ingest -> ins of the simulated AUV (IMU, GNSS at the surface, DVL
beams, depth) as real processes over Zenoh on loopback, recorded and replayed, against the in-process replay."""
from __future__ import annotations

import math
import re

import msgpack
import numpy as np
from zennav_harness import Cluster, Collector, wait_until

from zennav import messages as M

SPEC, DURATION_S = "sim:auv", 150.0  # 120 s at the surface (GNSS), then the dive (DVL and depth only)


def _bad_dvl(key: str) -> dict[str, bytes]:
    """One malformed payload per reason the ins's validator must count on a dvl key."""
    good = M.make("dvl", 1, cseq=5, beams=[0.5, 0.4, -0.5, -0.4], beam_valid=[True] * 4)
    good.update(src="intruder", seq=0, pub_ns=0)
    assert M.validate_map(good, key) == ""
    bad = {"bad_shape": {**good, "beams": [0.5, 0.4, -0.5]}, "not_finite": {**good, "beams": [math.nan] * 4},
           "bad_type": {**good, "beam_valid": [1, 1, 1, 1]},
           "missing_field": {k: v for k, v in good.items() if k not in ("beams", "beam_valid")},
           "wrong_schema": {**good, "schema": "depth", "depth_m": 3.0}}
    out = {code: msgpack.packb(m) for code, m in bad.items()}
    out["decode_error"] = b"\xc1\x00dvl"
    return out


def test_auv_stream_over_zenoh_equals_replay_records_and_replays(tmp_path):
    """A short dive of the simulated AUV streamed as fast as the ins drains: every DVL and depth sample reaches
    the engine (the ins's counts equal the ingest's), the solution and the DVL/depth status records equal the
    in-process replay bit for bit, malformed dvl payloads are rejected and counted by reason (the ins runs on);
    the recording carries the dvl and depth keys and, replayed into the ins, gives the same solution."""
    from zennav.datasets.registry import load_dataset
    from zennav.recording import read_mcap
    from zennav.replay import run_replay

    cluster = Cluster(tmp_path, vehicle="auv")
    failed = True
    try:
        k = cluster.keys
        sols = Collector(cluster.bus, k.nav_solution())
        aids = Collector(cluster.bus, k.nav_aid())
        status = Collector(cluster.bus, k.nav_status(), channel="ring")
        starts = Collector(cluster.bus, k.stream())
        cluster.service("ins", "--profile", "auv")
        out = tmp_path / "auv.mcap"
        rec = cluster.zennav("record", "record", str(out), "--until-stream-end", bus_args=True)
        cluster.wait_alive(["record"], 30, rec)
        pub = cluster.bus.publisher(k.dvl(), latest=False)
        bad = _bad_dvl(k.dvl())
        for payload in bad.values():
            pub.put_raw(payload)
        ing = cluster.service("ingest", SPEC, "-o", f"duration_s={DURATION_S}", "--speed", "0",
                              "--wait-for", "ins,record", wait=False)
        ds = load_dataset(SPEC, duration_s=DURATION_S)
        ref = run_replay(ds)
        st = status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")
                                         and m["stream"]["src"].startswith("ingest")), None), 120,
                         "ins to finish the stream")
        assert ing.wait(60) == 0, ing.text()
        assert rec.wait(60) == 0, rec.text()
        counts = next(iter(starts.msgs("stream_start")))["counts"]
        assert counts["dvl"] > 100 and counts["depth"] > 100
        assert st["aid_counts"] == {"dvl": counts["dvl"], "depth": counts["depth"]}
        assert st["imu_count"] == counts["imu"] == len(ref.t_ns) and st["gnss_count"] == counts["gnss"]
        assert st["stream"].get("gap", 0) == 0 and st["stream"].get("duplicate", 0) == 0
        assert {c: st["rejected"].get(c) for c in bad} == dict.fromkeys(bad, 1), st["rejected"]
        sols.wait(lambda c: len(c.msgs()) >= len(ref.t_ns), 30, "all solutions")
        msgs = sols.msgs()
        assert np.array_equal([m["t_ns"] for m in msgs], ref.t_ns)
        for f, r in (("llh", ref.llh), ("v_n", ref.v_n), ("q_nb", ref.q_nb), ("std_pos_ned", ref.std_pos_ned)):
            assert np.array_equal(np.array([m[f] for m in msgs]), r), f
        underwater = ("dvl", "depth")
        want = sorted((r.source, r.t_ns, r.fused, r.reason) for r in ref.reports)
        wait_until(lambda: len(aids.msgs()) >= len(want), 30, "all aid records")
        got = sorted((m["source"], m["t_ns"], m["fused"], m["reason"]) for m in aids.msgs())
        assert got == want
        fused = {s: sum(1 for r in got if r[0] == s and r[2]) for s in underwater}
        assert fused["dvl"] > 0.9 * counts["dvl"] * (DURATION_S - 120.0) / DURATION_S and fused["depth"] > 100
        # the recording carries the new keys; replayed into the same ins it gives the same solution
        recorded = {key: sum(1 for _ in read_mcap(out, [re.escape(key) + "$"])) for key in (k.dvl(), k.depth())}
        assert recorded == {k.dvl(): counts["dvl"], k.depth(): counts["depth"]}
        sols2 = Collector(cluster.bus, k.nav_solution())
        rep = cluster.zennav("replay", "bus-replay", str(out), "--speed", "0", bus_args=True)
        assert rep.wait(120) == 0, rep.text()
        st2 = status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")
                                          and m["stream"]["src"].startswith("replay")), None), 60,
                          "ins done with the replayed stream")
        assert st2["aid_counts"] == st["aid_counts"]
        sols2.wait(lambda c: len(c.msgs()) >= len(ref.t_ns), 30, "replayed solutions")
        assert np.array_equal(np.array([m["llh"] for m in sols2.msgs()]), ref.llh)
        failed = False
    finally:
        cluster.close(failed)
