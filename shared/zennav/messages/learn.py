"""Learning-loop messages (ARCHITECTURE.md section 3): ins -> learn/samples -> trainer -> learn/model/<name> ->
predictor; ins -> learn/query -> predictor -> learn/correction -> ins."""
from __future__ import annotations

import hashlib
import math

import numpy as np

from .codec import encode, floats, make, pyval
from .schema import FLOAT, FLOATS, INT, MAP, OPT, STR, define

PARAMSET_FORMAT = "zennav.paramset/2"  # zennav.learn.paramset.SCHEMA (not imported: no learn dependency here)
_PS_DTYPES = ("<f8", "<i8")  # little-endian float64, int64


def check_model_params(msg: dict) -> str:
    """Shapes of a model_params's arrays (types already checked): '' or 'code: detail'."""
    for an, am in msg["arrays"].items():
        if not (isinstance(am, dict) and isinstance(am.get("shape"), list) and isinstance(am.get("data"), list)
                and all(type(d) is int and d >= 0 for d in am["shape"])):
            return f"bad_shape: arrays.{an} needs shape and data"
        if math.prod(am["shape"]) != len(am["data"]):
            return f"bad_shape: arrays.{an} shape {am['shape']} vs {len(am['data'])} values"
        if not all(type(x) in (float, int) for x in am["data"]):
            return f"bad_type: arrays.{an} data not numbers"
    return ""


define("learn_sample", 1, "Training pair emitted while GNSS is valid: features and target (normalisation is the "
       "trainer's), variant names the target definition (zennav.nav.learning.TARGETS; target has OUTPUTS[variant] "
       "values). stream and index (optional, added compatibly): the src of the sensor stream the sample comes from "
       "and its ordinal among the sender's samples of its variant (the count published before it, restored with "
       "the ins's checkpoint), so that a receiver can drop a sample a restarted ins sends again.",
       features=FLOATS, target=FLOATS, variant=STR, stream=OPT(STR), index=OPT(INT))
define("learn_query", 1, "Prediction request of the ins while GNSS is lost (zennav.nav.learning.LearnQuery): "
       "t_ns the query time, target the variant, features as in learn_sample, dt_s the interval of a rate target "
       "[s]. The query is identified by its header (src, seq); the answer is one correction naming them. "
       "n_samples (optional, added compatibly): the number of learn_sample messages of this variant the sender "
       "published before the query; the answer should come from a model trained through exactly those "
       "(zennav.learn.learner).",
       target=STR, features=FLOATS, dt_s=FLOAT, n_samples=OPT(INT))
define("model_params", 1, "Versioned parameter set: name, version, kind, created_t_ns, normalisation "
       "{key: {shape, data[, dtype]}} (or {key: floats}), arrays {key: {shape, data[, dtype]}}, metrics, checksum. "
       "format (optional) names the parameter-set format; with format 'zennav.paramset/2' (model_params_msg / "
       "paramset_of) the message is zennav.learn.paramset's set with each array's bytes as a number list, and "
       "checksum is paramset.checksum of that set, verified end to end; otherwise params_checksum. signature "
       "(optional, added compatibly): the trainer's zennav.learn.signing signature of the checksum.",
       check=check_model_params, name=STR, version=INT, kind=STR, created_t_ns=INT, norm=MAP, arrays=MAP,
       metrics=MAP, checksum=STR, format=OPT(STR), signature=OPT(STR))
define("correction", 1, "Predicted INS error: kind (the learn_query target, or e.g. 'pos_ned' [m]), value, 1-sigma "
       "std, model name and version used; t_ns the time of the query answered; query_src/query_seq (optional) "
       "the header of the learn_query answered. refused (optional, added compatibly): the predictor's reason for "
       "not answering the query (no_model, off_domain, ...; value and std empty, model '', version -1).",
       kind=STR, value=FLOATS, std=FLOATS, model=STR, version=INT, query_src=OPT(STR), query_seq=OPT(INT),
       refused=OPT(STR))


def params_checksum(msg: dict) -> str:
    """sha256 over the canonical msgpack of (name, version, kind, norm, arrays): trainer and predictor agree on it."""
    canon = encode([msg.get("name"), msg.get("version"), msg.get("kind"), _sorted(msg.get("norm")),
                    _sorted(msg.get("arrays"))])
    return "sha256:" + hashlib.sha256(canon).hexdigest()


def _sorted(v):
    if isinstance(v, dict):
        return [[k, _sorted(v[k])] for k in sorted(v)]
    if isinstance(v, list):
        return [_sorted(x) for x in v]
    return v


def array_map(a) -> dict:
    """numpy array -> {"shape": [...], "data": [float64...]} for model_params.arrays."""
    a = np.asarray(a, dtype=np.float64)
    return {"shape": list(a.shape), "data": a.ravel().tolist()}


def map_array(m: dict) -> np.ndarray:
    return np.asarray(m["data"], dtype=np.float64).reshape(m["shape"])


def learn_sample_msg(sample, stream: str | None = None, index: int | None = None) -> dict:
    """zennav.nav.learning.LearnSample -> learn_sample message (stream: the sensor stream's src; index: the
    sample's ordinal among its variant's samples from this sender)."""
    return make("learn_sample", sample.t_ns, features=floats(sample.features), target=floats(sample.value),
                variant=str(sample.target), stream=stream, index=None if index is None else int(index))


def learn_query_msg(query, n_samples: int | None = None) -> dict:
    """zennav.nav.learning.LearnQuery -> learn_query message; n_samples: samples of its variant sent before it."""
    return make("learn_query", query.t_ns, target=str(query.target), features=floats(query.features),
                dt_s=float(query.dt_s), n_samples=None if n_samples is None else int(n_samples))


def correction_msg(query: dict, value, std, model: str, version: int) -> dict:
    """The answer to a (published, so src/seq-stamped) learn_query message."""
    return make("correction", query["t_ns"], kind=query["target"], value=floats(value), std=floats(std),
                model=str(model), version=int(version), query_src=query["src"], query_seq=int(query["seq"]))


def refusal_msg(query: dict, reason: str) -> dict:
    """The predictor's refusal of a (published) learn_query message: a correction without a value."""
    return make("correction", query["t_ns"], kind=query["target"], value=[], std=[], model="", version=-1,
                query_src=query["src"], query_seq=int(query["seq"]), refused=str(reason))


def model_params_msg(ps: dict, signature: str | None = None) -> dict:
    """A parameter set of zennav.learn.paramset (build()) -> model_params message: the same fields, each array's
    little-endian bytes as a number list (float64 -> float, int64 -> int: exact), the set's own checksum, its
    signature (zennav.learn.signing) when given.
    paramset_of() is the inverse, byte for byte, so the predictor verifies the trainer's checksum."""
    def wire(enc: dict) -> dict:
        if enc["dtype"] not in _PS_DTYPES:
            raise ValueError(f"unsupported dtype {enc['dtype']!r}")
        return {"dtype": enc["dtype"], "shape": [int(d) for d in enc["shape"]],
                "data": np.frombuffer(enc["data"], dtype=np.dtype(enc["dtype"])).tolist()}

    return make("model_params", ps["created_t_ns"], name=ps["name"], version=int(ps["version"]), kind=ps["kind"],
                created_t_ns=int(ps["created_t_ns"]), norm={k: wire(v) for k, v in ps["norm"].items()},
                arrays={k: wire(v) for k, v in ps["arrays"].items()}, metrics=pyval(dict(ps["metrics"])),
                checksum=ps["checksum"], format=PARAMSET_FORMAT if ps.get("schema") == PARAMSET_FORMAT
                else str(ps.get("schema")), **({} if signature is None else {"signature": str(signature)}))


def paramset_of(msg: dict) -> dict:
    """model_params message -> the zennav.learn.paramset message it carries (for paramset.validate, which then
    checks schema, checksum, shapes, finiteness and version). An array map that is not convertible is passed on
    as it is, so that validate rejects it with reason 'schema'; a float in an int64 array likewise."""
    def raw(m):
        if not (isinstance(m, dict) and {"dtype", "shape", "data"} <= set(m) and isinstance(m["data"], list)):
            return m
        if m["dtype"] not in _PS_DTYPES or (m["dtype"] == "<i8" and not all(type(x) is int for x in m["data"])):
            return m
        try:
            data = np.asarray(m["data"], dtype=np.dtype(m["dtype"])).tobytes()
        except (TypeError, ValueError, OverflowError):
            return m
        return {"dtype": m["dtype"], "shape": m["shape"], "data": data}

    return {"schema": msg.get("format"), "kind": msg["kind"], "name": msg["name"], "version": msg["version"],
            "created_t_ns": msg["created_t_ns"], "norm": {k: raw(v) for k, v in msg["norm"].items()},
            "arrays": {k: raw(v) for k, v in msg["arrays"].items()}, "metrics": msg["metrics"],
            "checksum": msg["checksum"]}
