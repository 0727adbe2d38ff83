"""The sensor stream (zennav.stream, zennav.replay.sensor_events): one selection for the ingest and the in-process
replay, the ingest's outage syntax equal to replay's, and the one follower of the ins and the attitude service:
source ownership, duplicate starts, and the late-join policy (ask for the start, join at the first IMU sample;
the ins then aligns in motion)."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from zennav import messages as M
from zennav.datasets.registry import load_dataset
from zennav.replay import run_replay, sensor_events
from zennav.stream import StreamFollower, stream_messages

K = M.Keys("car")
log = logging.getLogger("test")
KEY = {"imu": K.imu(), "gnss": K.gnss(), "stream": K.stream()}


def _msgs(ds, outages=(), src="ingest.a", batch=1):
    windows, events = sensor_events(ds, outages)
    return [(KEY[kind], {**m, "src": src, "seq": 0, "pub_ns": 0})
            for kind, m in stream_messages(ds, windows, events, batch)]


def test_ingest_takes_the_outage_forms_replay_takes():
    """zennav-ingest --outage-every 90:30 (replay's form; the first outage at PERIOD - DURATION = 60 s) used to
    raise ValueError; both now parse with zennav.replay's parsers and give the same windows."""
    from zennav.services.ingest import build_parser

    p = build_parser()
    a = p.parse_args(["sim:car", "--outage-every", "90:30", "--outage", "10:5"])
    assert a.outage_every == (90.0, 30.0, 60.0) and a.outage == [(10.0, 5.0)]
    assert p.parse_args(["--outage-every", "90:30:120"]).outage_every == (90.0, 30.0, 120.0)
    for bad in (["--outage-every", "90"], ["--outage-every", "30:90"], ["--outage", "a:b"], ["--outage", "5:0"]):
        with pytest.raises(SystemExit):
            p.parse_args(bad)
    ds = load_dataset("sim:car", duration_s=300.0)
    windows, _ = sensor_events(ds, a.outage, a.outage_every)
    s = [((w0 - ds.initial.t_ns) / 1e9, (w1 - ds.initial.t_ns) / 1e9) for w0, w1 in windows]
    assert s == [(10.0, 15.0), (60.0, 90.0), (150.0, 180.0), (240.0, 270.0)]


def test_one_selection_feeds_the_replay_and_the_stream():
    """The stream's samples are exactly the replay's: same IMU samples (one solution each), no withheld fix, the
    counts in stream_start and stream_end, consecutive cseqs."""
    ds = load_dataset("sim:car", duration_s=60.0)
    res = run_replay(ds, outages=[(20.0, 10.0)])
    msgs = [m for _, m in _msgs(ds, [(20.0, 10.0)])]
    imu = [m for m in msgs if m["schema"] == "imu"]
    gnss = [m for m in msgs if m["schema"] == "gnss"]
    assert [m["t_ns"] for m in imu] == res.t_ns.tolist()
    (w0, w1), = res.windows
    assert gnss and not any(w0 <= m["t_ns"] < w1 for m in gnss) and all(m["t_ns"] <= imu[-1]["t_ns"] for m in gnss)
    assert msgs[0]["counts"] == msgs[-1]["counts"] == {"imu": len(imu), "gnss": len(gnss)}
    assert [m["cseq"] for m in msgs] == list(range(len(msgs))) and msgs[-1]["last_cseq"] == len(msgs) - 1


class _Sink:
    def __init__(self):
        self.starts, self.samples, self.ends = [], [], []
        self.f = StreamFollower(lambda s, j: self.starts.append((s, j)), lambda k, m: self.samples.append(m),
                                self.ends.append, None, log)


def test_follower_owns_one_source_and_counts_drops():
    ds = load_dataset("sim:car", duration_s=5.0)
    a, b = _msgs(ds, src="ingest.a"), _msgs(ds, src="ingest.b")
    s = _Sink()
    for key, m in a[:100]:
        s.f.on_message(key, m)
    s.f.on_message(*a[0])  # the same start again
    for key, m in b[1:11]:  # another ingest's samples while a's stream is live
        s.f.on_message(key, m)
    assert s.f.counts["duplicate_start"] == 1 and s.f.counts["foreign_source"] == 10 and len(s.starts) == 1
    for key, m in a[100:]:
        s.f.on_message(key, m)
    assert s.f.done and len(s.ends) == 1 and len(s.samples) == len(a) - 2
    s.f.on_message(*b[0])  # a new stream replaces the finished one
    assert s.f.src == "ingest.b" and not s.f.done and len(s.starts) == 2 and s.starts[1][1] is None


def test_follower_without_a_start_drops_and_asks_again_later():
    """No start to be had (no ingest answers): samples are dropped as no_stream and the start is asked for again
    only after retry_every more of them; once it is there, the follower joins."""
    ds = load_dataset("sim:car", duration_s=5.0)
    msgs = _msgs(ds)
    asked, answer = [], [None]
    s = _Sink()
    s.f.fetch_start = lambda src: asked.append(src) or answer[0]
    s.f.retry_every = 50
    for key, m in msgs[200:260]:
        s.f.on_message(key, m)
    assert len(asked) == 2 and s.f.counts["no_stream"] == 60 and not s.starts  # at the 1st and the 51st
    answer[0] = msgs[0][1]
    for key, m in msgs[260:]:
        s.f.on_message(key, m)
    assert len(asked) == 3 and s.f.counts["late_join"] == 1 and s.f.done
    start, join = s.starts[0]
    assert start is msgs[0][1] and join["cseq"] == s.samples[0]["cseq"] > 260 - 50


def test_start_missed_but_nothing_else_is_a_normal_start():
    """The start message lost (or overtaken) but the first sample received is the one right after it: the ins
    follows the stream from its start, the solution is the replay's bit for bit."""
    from zennav.nodes.ins import InsNode

    ds = load_dataset("sim:car", duration_s=30.0)
    msgs = _msgs(ds, batch=4)
    sols = []
    node = InsNode(lambda kind, m: sols.append(m) if kind == "solution" else None, log,
                   fetch_start=lambda src: msgs[0][1])
    for key, m in msgs[1:]:
        node.on_sensor(key, m)
    assert node.follower.counts["late_join"] == 0 and node.follower.done
    ref = run_replay(ds)
    assert np.array_equal(np.array([m["llh"] for m in sols]), ref.llh)


def test_ins_joining_late_aligns_in_motion_and_navigates():
    """An ins started 60 s into the simulated drive (the car moving): it asks for the stream's start, starts in
    coarse alignment at its first sample (heading unknown; the start's position and attitude are a minute old),
    takes position and velocity from the next fixes, aligns in motion and then navigates within metres of the
    truth, also through a 20 s outage (measured: 1.5 m at most, 0.13 m at the end)."""
    from zennav.nav import earth
    from zennav.nodes.ins import InsNode

    ds = load_dataset("sim:car", duration_s=180.0)
    msgs = _msgs(ds, outages=[(140.0, 20.0)])
    t_join = ds.initial.t_ns + 60 * 10**9
    first = next(i for i, (_k, m) in enumerate(msgs) if m["schema"] == "imu" and m["t_ns"] > t_join)
    out: dict[str, list] = {"solution": [], "status": [], "aid": []}
    node = InsNode(lambda kind, m: out[kind].append(m), log, fetch_start=lambda src: msgs[0][1])
    for key, m in msgs[first:]:
        node.on_sensor(key, m)
    assert node.follower.counts["late_join"] == 1 and node.follower.done
    assert out["solution"][0]["t_ns"] == msgs[first][1]["t_ns"]
    al = out["status"][-1]["alignment"]
    assert al["state"] == "aligned" and al["method"] == "in_motion"
    join_t = msgs[first][1]["t_ns"] - msgs[first][1]["dt_ns"]
    assert al["times_ns"]["coarse"] == join_t < al["times_ns"]["fine"] <= al["times_ns"]["aligned"]
    aligned_t = al["times_ns"]["aligned"]
    assert aligned_t - join_t < 60 * 10**9
    truth = ds.truth
    t = np.array([m["t_ns"] for m in out["solution"]])
    llh = np.array([m["llh"] for m in out["solution"]])
    idx = np.searchsorted(truth.t_ns, t)
    err = np.array([np.linalg.norm(earth.llh_to_ned(llh[i], truth.llh[j])[:2]) for i, j in enumerate(idx)])
    after = t > aligned_t + 5 * 10**9
    print(f"\nlate join: aligned {(aligned_t - msgs[first][1]['t_ns']) / 1e9:.1f} s after joining; horizontal "
          f"error after: max {err[after].max():.2f} m, end {err[-1]:.2f} m")
    assert err[after].max() < 5.0 and err[-1] < 1.0
