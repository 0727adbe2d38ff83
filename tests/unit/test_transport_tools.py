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
