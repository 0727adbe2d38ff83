"""The process tools over real Zenoh: launch (supervision, restart, clean stop), record to MCAP and replay."""
from __future__ import annotations

import os
import re
import signal

import numpy as np
import yaml
from zennav_harness import Collector, free_port, wait_until

from zennav.bus import Bus


def test_launch_waits_prefixes_restarts_and_stops_cleanly(cluster, tmp_path):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    spec = {"name": "t", "vehicle": cluster.vehicle, "rendezvous": ep, "mode": "peer", "up_timeout_s": 60,
            "stop_timeout_s": 10, "services": [
                {"name": "router", "command": ["zennav", "router", "--listen", "{rendezvous}"],
                 "restart": "on-failure"},
                {"name": "ins", "command": ["zennav-ins"], "restart": "on-failure", "after": ["router"]},
                {"name": "attitude", "command": ["{python}", "-m", "zennav.services.attitude"],
                 "restart": "on-failure", "after": ["router"]},
                {"name": "trainer", "command": ["zennav-trainer"], "restart": "no", "after": ["router"]}]}
    f = tmp_path / "set.yaml"
    f.write_text(yaml.safe_dump(spec))
    watcher = Bus("watcher", cluster.vehicle, connect=[ep], listen=["tcp/127.0.0.1:0"], token=False)
    try:
        launch = cluster.zennav("launch", "launch", str(f))
        wait_until(lambda: "all 4 services up" in launch.text(), 60, "launch: all up")
        assert watcher.wait_alive(["router", "ins", "attitude", "trainer"], 20)
        log = launch.text()
        assert re.search(r"^\[ins\s*\] .*ins up", log, re.M), log
        wait_until(lambda: re.search(r"^\[trainer\s*\] .*trainer up \(running", launch.text(), re.M), 20,
                   "launch: the trainer's 'up' line")
        pid = int(re.search(r"started attitude \(pid (\d+)\)", log).group(1))
        os.kill(pid, signal.SIGKILL)
        wait_until(lambda: "attitude DIED (signal SIGKILL)" in launch.text(), 20, "launch: attitude died")
        wait_until(lambda: "restarting attitude (1/5)" in launch.text(), 20, "launch: restart")
        wait_until(lambda: len(re.findall(r"started attitude \(pid (\d+)\)", launch.text())) == 2, 20, "restart")
        pid2 = int(re.findall(r"started attitude \(pid (\d+)\)", launch.text())[-1])
        assert pid2 != pid
        # the restarted attitude announces itself again
        wait_until(lambda: re.search(r"^\[attitude\s*\] .*attitude up", launch.text().split(f"pid {pid2}")[1], re.M),
                   30, "restarted attitude up")
        assert watcher.wait_alive(["attitude"], 20)
        pids = [int(p) for p in re.findall(r"started \w+ \(pid (\d+)\)", launch.text())]
        launch.p.send_signal(signal.SIGINT)
        assert launch.wait(30) == 0
        out = launch.text()
        assert "stopped (ok)" in out
        assert watcher.wait_alive(["router", "ins", "attitude", "trainer"], 20, alive=False)
        for p in pids:  # every child is gone (reaped by the launcher)
            assert not os.path.exists(f"/proc/{p}") or "zombie" in open(f"/proc/{p}/status").read().lower()
    finally:
        watcher.close()


def test_record_mcap_and_replay_reproduce_solution(cluster, tmp_path):
    from mcap.reader import make_reader

    from zennav.recording import read_mcap

    k = cluster.keys
    out = tmp_path / "run.mcap"
    cluster.service("ins")
    rec = cluster.zennav("record", "record", str(out), "--until-stream-end", bus_args=True)
    cluster.wait_alive(["record"], 30, rec)
    ing = cluster.service("ingest", "sim:car", "-o", "duration_s=60", "--speed", "0", "--outage", "20:10",
                          "--wait-for", "ins,record", wait=False)
    assert ing.wait(120) == 0, ing.text()
    assert rec.wait(60) == 0, rec.text()
    # the file: one channel per key, JSON schemas (Foxglove reads json + jsonschema)
    with open(out, "rb") as fh:
        summ = make_reader(fh).get_summary()
    topics = {c.topic for c in summ.channels.values()}
    assert {k.imu(), k.gnss(), k.stream(), k.nav_solution(), k.nav_status()} <= topics
    assert {s.encoding for s in summ.schemas.values()} == {"jsonschema"}
    assert {c.message_encoding for c in summ.channels.values()} == {"json"}
    recorded = [m for key, m, _, _ in read_mcap(out, [re.escape(k.nav_solution()) + "$"])]
    assert len(recorded) == 12000
    # publish the recorded sensor keys back (as fast as possible) into the same ins: a new stream
    sols = Collector(cluster.bus, k.nav_solution())
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    rep = cluster.zennav("replay", "bus-replay", str(out), "--speed", "0", bus_args=True)
    assert rep.wait(120) == 0, rep.text()
    status.wait(lambda c: any(m["stream"].get("done") and m["stream"]["src"].startswith("replay")
                              for m in c.msgs()), 60, "ins done with the replayed stream")
    sols.wait(lambda c: len(c.msgs()) >= 12000, 30, "replayed solutions")
    got = sols.msgs()
    assert len(got) == 12000
    fields = ("t_ns", "llh", "v_n", "q_nb", "euler", "std_pos_ned", "gnss_state", "imu_cseq")
    assert all(all(a[f] == b[f] for f in fields) for a, b in zip(recorded, got)), "replay differs"
    t = np.array([m["t_ns"] for m in got])
    assert np.all(np.diff(t) > 0)


def test_trainer_set_joins_an_edge_router_as_a_client(cluster):
    """deploy/trainer.yaml on "another host": `zennav launch deploy/trainer.yaml --rendezvous <edge router>` starts
    the trainer as a zenoh client of that router (the launch file has no address of its own); the edge side (here
    the test's session behind a `zennav router`) sees it alive; Ctrl-C stops it cleanly."""
    from zennav.params import DEPLOY_DIR

    port = free_port()
    router = cluster.zennav("router", "router", "--listen", f"tcp/127.0.0.1:{port}", "--connect", cluster.endpoint,
                            "--vehicle", cluster.vehicle)
    cluster.wait_alive(["router"], 30, router)
    launch = cluster.zennav("launch", "launch", str(DEPLOY_DIR / "trainer.yaml"), "--rendezvous",
                            f"tcp/127.0.0.1:{port}", "--vehicle", cluster.vehicle)
    wait_until(lambda: "all 1 services up" in launch.text(), 90, "launch: the trainer up")
    cluster.wait_alive(["trainer"], 20, launch)
    m = re.search(r"started trainer \(pid (\d+)\): \S*zennav-trainer --signing-key (\S+) --state-dir (\S+)$",
                  launch.text(), re.M)
    assert m, launch.text()
    assert m.group(2) == f"{cluster.env['ZENNAV_KEYS']}/paramset-signing.pem"  # {keys}, {state}: ZENNAV_KEYS, ...
    assert m.group(3) == f"{cluster.env['ZENNAV_STATE_DIR']}/trainer"
    env = open(f"/proc/{m.group(1)}/environ", "rb").read().split(b"\0")
    assert b"ZENNAV_MODE=client" in env and f"ZENNAV_CONNECT=tcp/127.0.0.1:{port}".encode() in env
    launch.p.send_signal(signal.SIGINT)
    assert launch.wait(30) == 0 and "stopped (ok)" in launch.text()
    cluster.wait_alive(["trainer"], 20, launch, alive=False)
