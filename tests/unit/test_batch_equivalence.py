"""imu_batch on the wire: a stream sent with ``zennav-ingest --batch N`` reaches the ins's engine as the same
samples as the unbatched stream, sample for sample (encoded, validated, merged by the consumers' StreamFollower,
expanded): same keys, schemas, times, intervals, increments and cseqs, in the same order, nothing lost or
duplicated."""
from __future__ import annotations

import logging

import pytest

from zennav import messages as M
from zennav.datasets.registry import load_dataset
from zennav.replay import sensor_events
from zennav.stream import StreamFollower, stream_messages

K = M.Keys("car")
KEY = {"imu": K.imu(), "gnss": K.gnss(), "stream": K.stream()}
FIELDS = ("schema", "t_ns", "cseq", "dt_ns", "dtheta", "dvel", "llh", "std_ned", "v_n", "fix")


def _followed(ds, outages, batch: int) -> tuple[list, int, dict]:
    """(key, sample fields) handed on by a StreamFollower fed the encoded stream, messages on the wire, counts."""
    windows, events = sensor_events(ds, outages)
    validator = M.Validator()
    out: list = []
    ended: list = []
    f = StreamFollower(lambda start, join: None, lambda key, m: out.append((key, {k: m.get(k) for k in FIELDS})),
                       ended.append, log=logging.getLogger("test"))
    n_wire = 0
    for seq, (kind, m) in enumerate(stream_messages(ds, windows, events, batch)):
        m.update(src="ingest.a", seq=seq, pub_ns=0)
        msg, reason = validator.check(KEY[kind], M.encode(m))
        assert msg is not None, reason
        f.on_message(KEY[kind], msg)
        n_wire += 1
    assert len(ended) == 1 and f.done
    return out, n_wire, dict(f.merger.counts) if f.merger else {}


@pytest.mark.parametrize("batch", [7, 50])
def test_batched_stream_equals_the_unbatched_one_sample_for_sample(batch):
    ds = load_dataset("sim:car", duration_s=60.0)
    outages = [(20.0, 10.0)]
    ref, n_ref, counts_ref = _followed(ds, outages, 1)
    got, n_got, counts = _followed(ds, outages, batch)
    n_imu = sum(1 for _k, m in ref if m["schema"] == "imu")
    assert n_imu == 12_000  # 60 s at 200 Hz (the sample at the initial time starts the first interval)
    assert got == ref  # every sample, field for field (floats bit for bit), in order
    assert n_got < n_ref / 4  # batched: fewer messages on the wire (cut before every GNSS fix)
    for c in (counts, counts_ref):
        assert c.get("gap", 0) == c.get("duplicate", 0) == c.get("reordered", 0) == 0
