"""Transport basics over real Zenoh between processes: round trip, router, monitor up/down, late joiners."""
from __future__ import annotations

import json
import math
import time

import numpy as np
from zennav_harness import Collector, free_port, json_lines, wait_until

from zennav import messages as M

ECHO = str(__import__("pathlib").Path(__file__).with_name("echo_node.py"))


def _aid(i: int) -> dict:
    return M.make("aid_report", 1_000 + i, source="ping", observation=[float(i), math.pi, -1e-300],
                  innovation=[0.1 * i], innovation_var=[1.0], test_ratio=None if i % 2 else 0.5, fused=True,
                  reason="")


def _round_trip(cluster, bus_args, n=2000):
    k = cluster.keys
    got = Collector(cluster.bus, k.nav_aid("pong"))
    echo = cluster.start("echo", ECHO, "--in", k.nav_aid("ping"), "--out", k.nav_aid("pong"), *bus_args,
                         bus_args=False)
    cluster.wait_alive(["echo"], 30, echo)
    pub = cluster.bus.publisher(k.nav_aid("ping"))
    wait_until(lambda: pub.matching, 10, "echo subscriber to match")
    sent = [_aid(i) for i in range(n)]
    t_send = {}
    for i, m in enumerate(sent):
        t_send[i] = time.time_ns()
        pub.put(m)
    got.wait(lambda c: len(c.msgs()) >= n, 30, f"{n} echoed messages")
    msgs = got.msgs()
    assert len(msgs) == n
    assert [m["t_ns"] for m in msgs] == [1_000 + i for i in range(n)], "order or content changed"
    for a, b in zip(sent, msgs):  # bit-exact floats, None preserved
        assert a["observation"] == b["observation"] and a["test_ratio"] == b["test_ratio"]
    assert [m["seq"] for m in msgs] == list(range(n)), "echo publisher sequence has gaps"
    # latency of one round trip, paced (one in flight)
    rtts = []
    for i in range(200):
        before = len(got.msgs())
        t0 = time.perf_counter_ns()
        pub.put(_aid(n + i))
        got.wait(lambda c, before=before: len(c.msgs()) > before, 5, "paced echo")
        rtts.append((time.perf_counter_ns() - t0) / 1e6)
    print(f"\nround trip over {'router' if '--mode' in bus_args else 'peer'}: p50 {np.median(rtts):.3f} ms, "
          f"p99 {np.percentile(rtts, 99):.3f} ms")
    assert cluster.bus.rejected == {}


def test_pubsub_round_trip_between_processes_peer(cluster):
    _round_trip(cluster, ["--connect", cluster.endpoint])


def test_pubsub_round_trip_through_router(cluster):
    """Router process (`zennav router`), the echo node as its client, the test as its client too."""
    from zennav.bus import Bus

    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    cluster.zennav("router", "router", "--listen", ep)
    cluster.bus.close()
    cluster.bus = Bus("tester", cluster.vehicle, mode="client", connect=[ep])
    cluster.wait_alive(["router"], 30)
    _round_trip(cluster, ["--mode", "client", "--connect", ep])
    assert cluster.bus.routers(), "the test session should be connected to the router"


def test_monitor_reports_killed_service_down_then_up_and_stream_resumes(cluster):
    k = cluster.keys
    cluster.service("attitude")
    mon = cluster.service("monitor", "--json", "--interval", "0.25")
    cluster.service("ingest", "sim:car", "-o", "duration_s=120", "--speed", "1", "--wait-for", "attitude",
                    "--exit-on-end", wait=False)
    att_key = k.attitude()

    def snap_where(pred):
        lines = json_lines(mon)
        return next((s for s in reversed(lines) if pred(s)), None)

    def up_and_streaming(s):
        svc = s["services"].get("attitude", {})
        return svc.get("alive") and s["keys"].get(att_key, {}).get("rate_hz", 0) > 100

    s1 = wait_until(lambda: snap_where(up_and_streaming), 40, "monitor: attitude up and streaming")
    count1 = s1["keys"][att_key]["count"]
    att = next(p for p in cluster.procs if p.name == "attitude")
    att.kill()
    wait_until(lambda: snap_where(lambda s: s["services"].get("attitude", {}).get("alive") is False), 20,
               "monitor: attitude down")
    cluster.service("attitude")
    s2 = wait_until(lambda: snap_where(lambda s: up_and_streaming(s) and s["keys"][att_key]["count"] > count1 + 200),
                    40, "monitor: attitude back up and its stream resumed")
    assert s2["services"]["attitude"]["state"] == "running"
    assert s2["services"]["ingest"]["alive"]


def test_late_joiner_gets_latest_model_and_status(cluster):
    """A model publisher and the ins run first; a monitor process started afterwards gets the latest model
    version, the ins status and the services' status from the queryables."""
    k = cluster.keys
    cluster.service("ins")
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=10", "--speed", "0", wait=False)
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    status.wait(lambda c: any(m["stream"].get("done") for m in c.msgs()), 60, "ins stream done")
    assert ing.wait(30) == 0
    pub = cluster.bus.publisher(k.learn_model("anfis"))
    for v in (1, 2, 3):
        m = M.make("model_params", time.time_ns(), name="anfis", version=v, kind="anfis", created_t_ns=v,
                   norm={"in_mean": [0.0]}, arrays={"w": M.array_map(np.arange(6.0).reshape(2, 3) * v)},
                   metrics={"rmse": 1.0 / v}, checksum="")
        m["checksum"] = M.params_checksum(m)
        pub.put(m)
    late = cluster.start("late", "zennav.services.monitor", "--once", "--json", "--duration", "0.5")
    assert late.wait(60) == 0, late.text()
    snap = json.loads(late.text()[late.text().index("{"):late.text().rindex("}") + 1])
    assert snap["models"]["anfis"]["version"] == 3
    assert snap["nav"]["stream"]["done"] is True and snap["nav"]["imu_count"] == 2000
    assert snap["services"]["ins"]["alive"] and snap["services"]["ins"]["state"] == "running"
