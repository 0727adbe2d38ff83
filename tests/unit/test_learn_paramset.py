"""Parameter sets: encoding, checksum, validation and its rejection reasons."""
import copy

import numpy as np
import pytest

from zennav.learn import anfis_numpy as an
from zennav.learn import paramset
from zennav.learn.paramset import REASONS, ParamSetRejected


def _parts(n_in=3, n_rules=4, n_out=2, seed=0):
    rng = np.random.default_rng(seed)
    arrays = an.cluster_rulebase(rng.normal(size=(100, n_in)), n_rules, seed=seed)
    arrays["consequents"] = rng.normal(size=(n_rules, n_in + 1, n_out))
    norm = dict(x_mean=rng.normal(size=n_in), x_std=rng.uniform(1, 2, n_in), x_min=np.full(n_in, -3.0),
                x_max=np.full(n_in, 3.0), y_mean=np.zeros(n_out), y_std=np.ones(n_out))
    return arrays, norm


def _msg(version=5, norm_changes=None, **changes):
    arrays, norm = _parts()
    arrays.update(changes)
    norm.update(norm_changes or {})
    metrics = {"val_rmse": np.array([0.1, 0.2]), "epochs": np.int64(7)}  # numpy values become plain
    return paramset.build("drift", version, arrays, norm, metrics, created_t_ns=123)


def _reason(msg, **kw):
    with pytest.raises(ParamSetRejected) as e:
        paramset.validate(msg, **kw)
    assert e.value.reason in REASONS and e.value.detail
    return e.value.reason


def test_round_trip_over_msgpack():
    arrays, norm = _parts()
    msg = paramset.build("drift", 2, arrays, norm, {"val_rmse": [0.5, 0.25]}, created_t_ns=99)
    ps = paramset.validate(paramset.decode(paramset.encode(msg)), live_version=1, n_in=3, n_out=2, name="drift")
    assert (ps.name, ps.version, ps.created_t_ns, ps.n_in, ps.n_out) == ("drift", 2, 99, 3, 2)
    assert ps.checksum == msg["checksum"] == paramset.checksum(msg) and ps.checksum.startswith("sha256:")
    for k in an.ARRAY_NAMES:
        np.testing.assert_array_equal(ps.arrays[k], arrays[k])
        assert not ps.arrays[k].flags.writeable
    assert ps.arrays["rules"].dtype == np.int64
    x = np.random.default_rng(1).normal(size=(5, 3))
    np.testing.assert_array_equal(an.predict(ps.arrays, ps.norm, x), an.predict(arrays, norm, x))
    assert dict(ps.metrics) == {"val_rmse": [0.5, 0.25]}


def test_checksum_is_canonical():
    a, b = _msg(), _msg()
    b_reordered = {k: b[k] for k in reversed(list(b))}
    b_reordered["arrays"] = {k: b["arrays"][k] for k in reversed(list(b["arrays"]))}
    assert paramset.checksum(a) == paramset.checksum(b_reordered)
    assert paramset.checksum(_msg(version=6)) != paramset.checksum(a)


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    """(Signer, Verifier) of a new pair, and a Verifier of another pair."""
    from zennav.learn.signing import Signer, Verifier, generate

    priv, pub = generate(tmp_path_factory.mktemp("keys"))
    _, other = generate(tmp_path_factory.mktemp("other"))
    return Signer.from_file(priv), Verifier.from_file(pub), Verifier.from_file(other)


def test_rejections_have_distinct_reasons(keys):
    signer, verifier, _ = keys
    good = _msg(version=5)
    paramset.validate(good, live_version=4)
    sig = signer.sign(good["checksum"])
    paramset.validate(good, live_version=4, verifier=verifier, signature=sig, max_version_step=1)

    tampered = copy.deepcopy(good)
    data = bytearray(tampered["arrays"]["c"]["data"])
    data[3] ^= 0x01
    tampered["arrays"]["c"]["data"] = bytes(data)

    cons = np.zeros((4, 4, 2))
    cons[1, 2, 0] = np.nan
    wrong_shape = _msg(consequents=np.zeros((4, 3, 2)))  # n_in + 1 rows expected

    reasons = {
        "checksum": _reason(tampered),
        "non_finite": _reason(_msg(consequents=cons)),
        "shape": _reason(wrong_shape),
        "stale_version": _reason(good, live_version=5),
        "schema": _reason({k: v for k, v in good.items() if k != "norm"}),
        "decode": _reason_decode(b"\xc1 not msgpack"),
        "invalid_value": _reason(_msg(a=-np.ones((3, 4)))),
        "unsigned": _reason(good, verifier=verifier),
        "bad_signature": _reason(good, verifier=verifier, signature=signer.sign(_msg(version=6)["checksum"])),
        "version_ahead": _reason(good, live_version=3, max_version_step=1),
    }
    assert reasons == {k: k for k in reasons}
    assert set(reasons) == set(REASONS)
    assert _reason(good, live_version=9) == "stale_version"
    assert _reason(good, n_in=4) == "shape"
    assert _reason(good, name="other") == "schema"
    assert _reason(_msg(rules=np.full((4, 3), 7))) == "invalid_value"
    assert _reason(_msg(norm_changes={"x_min": np.full(3, 4.0)})) == "invalid_value"  # x_min > x_max


def test_signature_binds_the_key_and_the_content(keys, tmp_path):
    """Only the trusted key's signature of this very set verifies; a forged or reused one is bad_signature, with
    a reason that says which; a set signed by an untrusted key names that key."""
    from zennav.learn.signing import Signer, Verifier

    signer, verifier, other = keys
    good = _msg(version=5)
    sig = signer.sign(good["checksum"])
    assert verifier.check(good["checksum"], sig) == ""
    assert "trusted key" in other.check(good["checksum"], sig)
    head, kid, hexsig = sig.split(":")
    flipped = f"{head}:{kid}:{hexsig[:-2]}{int(hexsig[-2:], 16) ^ 1:02x}"
    assert verifier.check(good["checksum"], flipped) == "signature does not verify"
    assert "not an ed25519" in verifier.check(good["checksum"], "hmac:00:00")
    assert verifier.check(good["checksum"], f"{head}:{kid}:zz") == "signature is not hex"
    # a key file that is not a key, or the wrong half: one line, ValueError
    bad = tmp_path / "bad.pem"
    bad.write_text("not a key")
    for load, path in ((Signer.from_file, bad), (Verifier.from_file, bad), (Signer.from_file, tmp_path / "none")):
        with pytest.raises(ValueError) as e:
            load(path)
        assert "\n" not in str(e.value)


def _reason_decode(payload):
    with pytest.raises(ParamSetRejected) as e:
        paramset.decode(payload)
    return e.value.reason


def test_schema_details():
    good = _msg()
    bad_dtype = copy.deepcopy(good)
    bad_dtype["arrays"]["rules"] = paramset._encode_array(np.zeros((4, 3)))  # float rules
    bad_len = copy.deepcopy(good)
    bad_len["norm"]["x_std"]["data"] = bad_len["norm"]["x_std"]["data"][:-8]
    bad_version = dict(good, version=True)
    others = (dict(good, schema="other/9"), dict(good, extra=1), {**good, 5: 1})
    for msg in (bad_dtype, bad_len, bad_version, *others):
        assert _reason(msg) == "schema"  # checked before the checksum
    assert _reason_decode(b"\x93\x01\x02\x03") == "decode"  # a msgpack list, not a map
