"""Transport tools without a network: MCAP record/read exactness, launch files, zenoh configs in deploy/."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from zennav import messages as M

REPO = Path(__file__).resolve().parents[2]
K = M.Keys("car")


@pytest.mark.parametrize("encoding", ["json", "msgpack"])
def test_mcap_round_trip_is_exact(tmp_path, encoding):
    from zennav.recording import McapRecorder, json_schema, read_mcap

    rng = np.random.default_rng(3)
    rec = McapRecorder(tmp_path / "x.mcap", encoding)
    sent = []
    for i in range(200):
        m = M.imu_msg(1000 + i, rng.normal(size=3) * 1e-3, rng.normal(size=3), 5, i + 1)
        m.update(src="s", seq=i, pub_ns=10 + i)
        sent.append(m)
        rec.add(K.imu(), M.encode(m), 100 + i)
    rec.add(K.imu(), b"\xc1garbage", 400)
    rec.close()
    got = list(read_mcap(tmp_path / "x.mcap"))
    assert [g[1] for g in got if g[1] is not None and isinstance(g[1], dict)][:200] == sent
    from zennav.gpstime import gps_ns_to_unix_ns

    assert [g[3] for g in got][:200] == [gps_ns_to_unix_ns(1000 + i) for i in range(200)]  # log time: sample time
    assert rec.skipped == (1 if encoding == "json" else 0)
    s = json_schema(M.SCHEMAS["imu"])
    assert s["properties"]["dvel"]["minItems"] == 3 and "cseq" in s["required"]
    json.dumps(s)


def test_mcap_views_of_a_solution_batch_are_those_of_its_solutions(tmp_path):
    """A recorded nav_solution_batch is stored as it came, and its Foxglove views are its solutions', each at its
    own sample time: the same as recording the solutions one by one."""
    from mcap.reader import make_reader

    from zennav.recording import McapRecorder

    class Nav:
        gyro_bias, accel_bias, gnss_state = [0.0, 1e-6, 0.0], [0.01, 0.0, 0.0], "valid"

    n = 5
    rows = np.column_stack([np.full(n, 0.6), np.full(n, 2.1), np.arange(n) + 50.0, np.ones((n, 3)),
                            np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))])
    b = M.nav_solution_batch_msg(Nav, [10**18 + i for i in range(n)], rows, np.full((n, 9), 0.1), range(n),
                                 [0] * n)
    b.update(src="ins.1", seq=0, pub_ns=7)
    views = {}
    for name, msgs in (("batch", [b]), ("single", M.solutions(b))):
        rec = McapRecorder(tmp_path / f"{name}.mcap", "json")
        for m in msgs:
            rec.add(K.nav_solution(), M.encode(m), 0)
        rec.close()
        with open(tmp_path / f"{name}.mcap", "rb") as f:
            views[name] = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()
                           if c.topic != K.nav_solution()]
    assert len(views["batch"]) == 3 * n and views["batch"] == views["single"]


def test_launch_files_in_deploy_parse():
    """local.yaml and edge.yaml start with their router; the edge set has no trainer (it runs elsewhere) and its
    ins learns; trainer.yaml is the trainer alone, a client, its router's address a launch parameter (none in the
    file); every command is a zennav console script."""
    import sys

    from zennav.launch import load_launch

    bindir = Path(sys.executable).parent
    for name in ("local.yaml", "edge.yaml", "demo.yaml"):
        spec = load_launch(REPO / "deploy" / name)
        names = [s.name for s in spec.services]
        assert names[0] == "router" and "ins" in names and "ingest" in names
        assert all(s.restart in ("no", "on-failure", "always") for s in spec.services)
        for s in spec.services:
            assert s.command[0].startswith("zennav") and (bindir / s.command[0]).exists(), (name, s.command)
    edge = {s.name: s for s in load_launch(REPO / "deploy" / "edge.yaml").services}
    assert set(edge) == {"router", "ins", "attitude", "predictor", "monitor", "ingest"}
    assert "--learning" in edge["ins"].command
    with pytest.raises(ValueError, match="no rendezvous"):
        load_launch(REPO / "deploy" / "trainer.yaml")
    tr = load_launch(REPO / "deploy" / "trainer.yaml", {"rendezvous": "tcp/10.0.0.2:7447"})
    assert tr.mode == "client" and [s.command[0] for s in tr.services] == ["zennav-trainer"]
    # sets signed, versions kept across restarts; the predictors trust the public half
    assert {"--signing-key", "--state-dir"} <= set(tr.services[0].command)
    for name in ("local.yaml", "edge.yaml"):
        pred = next(s for s in load_launch(REPO / "deploy" / name).services if s.name == "predictor")
        assert "--verify-key" in pred.command and "--allow-unsigned" not in pred.command
    assert tr.rendezvous == "tcp/10.0.0.2:7447"


def test_zenoh_configs_in_deploy():
    from zennav.bus import open_config

    peer = open_config("peer")
    assert json.loads(peer.get_json("scouting/multicast/enabled")) is False
    assert json.loads(peer.get_json("mode")) == "peer"
    assert json.loads(peer.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    client = open_config("client", connect="tcp/10.0.0.2:7447")
    assert json.loads(client.get_json("connect/endpoints")) == ["tcp/10.0.0.2:7447"]
    router = open_config("router", listen="tcp/127.0.0.1:9999", connect="")
    assert json.loads(router.get_json("mode")) == "router"
    assert json.loads(router.get_json("listen/endpoints")) == ["tcp/127.0.0.1:9999"]
    assert json.loads(router.get_json("scouting/multicast/enabled")) is False


def test_only_bus_imports_zenoh():
    offenders = []
    for p in list((REPO / "shared" / "zennav").rglob("*.py")) + list((REPO / "services" / "zennav").rglob("*.py")):
        if p.name == "bus.py" and p.parent.name == "zennav":
            continue
        text = p.read_text()
        if "import zenoh" in text or "from zenoh" in text:
            offenders.append(str(p.relative_to(REPO)))
    assert offenders == []
