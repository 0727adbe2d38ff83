"""The secure bus without a network: `zennav certs` credentials, the secure configs open_config builds, the
access-control table of deploy/secure/router.json5 evaluated per identity and key, the launch files' secure
variant."""
from __future__ import annotations

import json
import stat
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from zennav.bus import open_config
from zennav.certs import IDENTITIES, make_certs

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def creds(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("creds")
    make_certs(d, hosts=["10.0.0.2", "edge.local"])
    return d


def test_certs_are_signed_by_the_ca_with_the_identity_as_common_name(creds):
    ca = x509.load_pem_x509_certificate((creds / "ca.pem").read_bytes())
    dictionary = dict(line.split(":", 1) for line in (creds / "usrpwd.txt").read_text().splitlines())
    assert set(dictionary) == set(IDENTITIES)
    for ident in IDENTITIES:
        cert = x509.load_pem_x509_certificate((creds / f"{ident}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == ident
        assert cert.issuer == ca.subject
        ca.public_key().verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))
        assert dictionary[ident] == (creds / f"{ident}.secret").read_text() and len(dictionary[ident]) >= 32
        for private in (f"{ident}.key", f"{ident}.secret"):
            assert stat.S_IMODE((creds / private).stat().st_mode) == 0o600
    san = x509.load_pem_x509_certificate((creds / "router.pem").read_bytes()).extensions.get_extension_for_class(
        x509.SubjectAlternativeName).value
    assert {"localhost", "edge.local", "router"} <= set(san.get_values_for_type(x509.DNSName))
    assert {str(a) for a in san.get_values_for_type(x509.IPAddress)} == {"127.0.0.1", "10.0.0.2"}


def test_secure_configs_carry_the_identity_credentials(creds):
    client = open_config(None, connect="tls/10.0.0.2:7447", identity="ins", secure_dir=creds)
    assert json.loads(client.get_json("mode")) == "client"
    assert json.loads(client.get_json("connect/endpoints")) == ["tls/10.0.0.2:7447"]
    tls = json.loads(client.get_json("transport/link/tls"))
    assert tls["enable_mtls"] is True and tls["connect_certificate"] == str(creds / "ins.pem")
    assert tls["root_ca_certificate"] == str(creds / "ca.pem")
    assert json.loads(client.get_json("transport/auth/usrpwd/user")) == "ins"
    assert json.loads(client.get_json("transport/auth/usrpwd/password")) == (creds / "ins.secret").read_text()
    router = open_config("router", listen="tls/127.0.0.1:7447", identity="anything", secure_dir=creds)
    assert json.loads(router.get_json("transport/link/tls/listen_certificate")) == str(creds / "router.pem")
    assert json.loads(router.get_json("transport/auth/usrpwd/dictionary_file")) == str(creds / "usrpwd.txt")
    acl = json.loads(router.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"


@pytest.mark.parametrize("kwargs, match", [
    ({"mode": "peer"}, "peers open direct links"),
    ({"connect": "tcp/127.0.0.1:7447"}, "tls/ only"),
    ({"mode": "router", "listen": "tcp/0.0.0.0:7447"}, "tls/ only"),
    ({"identity": "intruder"}, "no credentials for identity 'intruder'"),
])
def test_secure_bus_refuses_what_would_bypass_the_router(creds, kwargs, match):
    with pytest.raises(ValueError, match=match):
        open_config(kwargs.get("mode"), connect=kwargs.get("connect"), listen=kwargs.get("listen"),
                    identity=kwargs.get("identity", "ins"), secure_dir=creds)


def _allowed(acl: dict, identity: str, message: str, flow: str, key: str) -> bool:
    """The router's decision for a message of ``identity`` on a concrete key: allowed by some rule of a policy
    whose subjects name the identity (as certificate common name and user name), else the default."""
    subjects = {s["id"] for s in acl["subjects"]
                if identity in s.get("cert_common_names", []) and identity in s.get("usernames", [])}
    rules = {r["id"]: r for r in acl["rules"]}
    for pol in acl["policies"]:
        if not subjects & set(pol["subjects"]):
            continue
        for r in (rules[i] for i in pol["rules"]):
            if message in r["messages"] and flow in r["flows"] and any(
                    zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in r["key_exprs"]):
                assert r["permission"] == "allow"
                return True
    return acl["default_permission"] == "allow"


def test_access_control_table(creds):
    """Who may put (and serve) which key, and who receives it, per deploy/secure/router.json5."""
    acl = json.loads(open_config("router", listen="tls/127.0.0.1:7447", secure_dir=creds).get_json("access_control"))
    base = "zennav/@v1/car/"
    owner = {"sensor/imu/0": "ingest", "sensor/gnss/0": "ingest", "sensor/stream": "ingest",
             "nav/solution": "ins", "nav/plain/solution": "ins", "nav/aid/gnss_pos": "ins", "nav/status": "ins",
             "attitude": "attitude", "learn/samples": "ins", "learn/query": "ins", "learn/model/elman": "trainer",
             "learn/correction": "predictor", "svc/ins-plain/status": "ins", "svc/trainer/status": "trainer",
             "@alive/ins-plain": None, "@alive/predictor": None}
    readers = {"sensor/imu/0": {"ins", "attitude"}, "learn/model/elman": {"predictor", "trainer"},
               "learn/correction": {"ins"}, "learn/samples": {"trainer"}, "nav/solution": {"attitude", "ingest",
                                                                                         "predictor"}}
    idents = [i for i in IDENTITIES if i != "router"]
    for rel, who in owner.items():
        for ident in idents:
            put = _allowed(acl, ident, "put", "ingress", base + rel)
            assert put == (ident == who), (ident, rel)
            assert _allowed(acl, ident, "reply", "ingress", base + rel) == (ident == who), (ident, rel)
    for rel, who in readers.items():
        observers = {"monitor", "record", "launch"}
        assert {i for i in idents if _allowed(acl, i, "put", "egress", base + rel)} == who | observers, rel
    for ident in idents:  # liveliness: each service its own token (the launcher has none), everyone sees all
        assert _allowed(acl, ident, "liveliness_token", "ingress", f"{base}@alive/{ident}") == (ident != "launch")
        assert not _allowed(acl, ident, "liveliness_token", "ingress", f"{base}@alive/router")
        assert _allowed(acl, ident, "liveliness_token", "egress", f"{base}@alive/router")
    assert not _allowed(acl, "nobody", "declare_subscriber", "ingress", base + "sensor/imu/0")
    # the ingest's history (zennav.nodes.ingest.History): the ins and the attitude query it, only the ingest serves
    history, readers_of_history = base + "sensor/history", {"ins", "attitude", "monitor", "record", "launch"}
    assert {i for i in idents if _allowed(acl, i, "query", "ingress", history)} == readers_of_history
    assert {i for i in idents if _allowed(acl, i, "query", "egress", history)} == {"ingest"}
    assert {i for i in idents if _allowed(acl, i, "reply", "ingress", history)} == {"ingest"}
    assert {i for i in idents if _allowed(acl, i, "declare_queryable", "ingress", history)} == {"ingest"}
    assert {i for i in idents if _allowed(acl, i, "reply", "egress", history)} == readers_of_history


def test_launch_secure_variant(creds):
    from zennav.launch import Launcher, load_launch, secure_variant

    spec = secure_variant(load_launch(REPO / "deploy" / "demo.yaml"), creds)
    assert spec.rendezvous == "tls/127.0.0.1:7447" and spec.mode == "client" and spec.secure_dir == str(creds)
    launcher = Launcher(spec)
    env = {s.name: launcher._env(s) for s in spec.services}
    assert env["ins-plain"]["ZENNAV_IDENTITY"] == "ins" and env["ingest"]["ZENNAV_IDENTITY"] == "ingest"
    assert {e["ZENNAV_SECURE_DIR"] for e in env.values()} == {str(creds)}
    assert {e["ZENNAV_MODE"] for e in env.values()} == {"client"}
    assert all(s.identity in IDENTITIES for s in spec.services)
    with pytest.raises(ValueError, match="holds no credentials"):
        secure_variant(spec, creds / "nowhere")
