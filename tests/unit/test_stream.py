"""The sensor stream (zennav.stream, zennav.replay.sensor_events): one selection for the ingest and the in-process
replay, the ingest's outage syntax equal to replay's, and the one follower of the ins and the attitude service:
source ownership, duplicate starts, and the late-join policy (ask for the start, join at the first IMU sample;
the ins then aligns in motion)."""
from __future__ import annotations

import logging
import time

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


def test_merger_refused_candidate_leaves_its_slot_open_and_gaps_are_bounded():
    """A candidate the consumer's rule refuses does not take its cseq: the genuine one arriving after it is
    released; far-ahead cseqs are dropped unless a run of consecutive ones shows the stream jumped; a hole is
    skipped as a counted gap after timeout_s (expire) even when nothing else arrives."""
    out: list = []
    m = M.SequenceMerger(1, accept=lambda c, item: "forged" if item == "bad" else "", timeout_s=0.05)
    m.push(1, "bad", out.append)  # in order but refused: nothing released, the slot stays open
    m.push(1, "one", out.append)
    m.push(3, "bad", out.append)  # held for cseq 3, then its genuine twin arrives
    m.push(3, "three", out.append)
    m.push(2, "two", out.append)
    assert out == ["one", "two", "three"] and m.counts["forged"] == 2 and m.counts["duplicate"] == 0
    m.push(4 + (1 << 16), "far", out.append)  # one message far ahead: dropped
    assert m.counts["far_ahead"] == 1 and m.next == 4
    m.push(6, "six", out.append)  # 4 and 5 lost
    assert out[-1] == "three"
    time.sleep(0.1)
    m.expire(out.append)
    assert out[-1] == "six" and m.counts["gap"] == 2 and m.held == 0
    jump = 100 + (1 << 16)
    for c in range(jump, jump + 8):  # a run of consecutive far-ahead cseqs: the stream jumped
        m.push(c, c, out.append)
    assert out[-8:] == list(range(jump, jump + 8)) and m.counts["resync"] == 1 and m.counts["far_ahead"] == 1


def test_follower_time_chain_refuses_forged_samples_and_takeovers():
    """The follower's rule: a sample of the live source whose interval does not start where the last one ended
    is refused (time_jump / time_backwards) without costing the genuine sample of its cseq; another source's
    stream_start is refused while the live stream is heard from (takeover_refused) and taken after
    takeover_after_s of silence."""
    ds = load_dataset("sim:car", duration_s=5.0)
    a, b = _msgs(ds, src="ingest.a"), _msgs(ds, src="ingest.b")
    s = _Sink()
    s.f.takeover_after_s = 0.2
    for key, m in a[:100]:
        s.f.on_message(key, m)
    key, nxt = a[100]
    s.f.on_message(key, dict(nxt, t_ns=nxt["t_ns"] + 10**9))  # the next cseq, 1 s ahead: refused
    s.f.on_message(key, dict(a[50][1], t_ns=a[50][1]["t_ns"] + 10**9))  # a used cseq: duplicate
    s.f.on_message(*b[0])  # a takeover while a is live: refused
    for key, m in a[100:]:
        s.f.on_message(key, m)
    merge = s.f.merger.counts
    assert s.f.done and len(s.samples) == len(a) - 2 and merge["time_jump"] == 1 and merge["duplicate"] == 1
    assert s.f.counts["takeover_refused"] == 1 and s.f.src == "ingest.a"
    s2 = _Sink()
    s2.f.takeover_after_s = 0.2
    for key, m in a[:100]:
        s2.f.on_message(key, m)
    time.sleep(0.3)  # a falls silent mid-stream: b may take over
    s2.f.on_message(*b[0])
    assert s2.f.src == "ingest.b" and s2.f.counts["takeover_refused"] == 0


def test_ins_resumed_from_a_checkpoint_continues_as_the_replay(tmp_path):
    """An ins that checkpoints every 5 s of data, killed after 20 s (its object dropped), and a new one started
    with the same checkpoint file that gets the stream from before the checkpoint again (as from the ingest's
    cache): the new one resumes at the checkpoint and its solutions are the replay's, bit for bit."""
    ds = load_dataset("sim:car", duration_s=40.0)
    first = _resumed(ds, _msgs(ds, outages=[(25.0, 8.0)]), tmp_path, 3000)
    assert first.checkpoint.written == 3


def _resumed(ds, msgs, tmp_path, back: int, block_loop=None):
    """An ins checkpointing every 5 s of data, fed msgs up to 20 s of data, and a new one with the same checkpoint
    file fed the stream from ``back`` messages before that on (duplicates for the merge): asserts that the new one
    resumed and that its solutions are the replay's (outage 25..33 s), bit for bit. Returns the first ins."""
    from zennav.checkpoint import Checkpointer
    from zennav.nodes.ins import InsNode

    path = tmp_path / "ins.ckpt"
    first = InsNode(lambda kind, m: None, log, checkpoint=Checkpointer(path, 5.0), block_loop=block_loop)
    cut = next(i for i, (_k, m) in enumerate(msgs) if m["t_ns"] > ds.initial.t_ns + 20 * 10**9)
    for key, m in msgs[:cut]:
        first.on_sensor(key, m)
    sols: dict = {}
    second = InsNode(lambda kind, m: sols.__setitem__(m["t_ns"], m) if kind == "solution" else None, log,
                     checkpoint=Checkpointer(path, 5.0), block_loop=block_loop)
    for key, m in msgs[cut - back:]:
        second.on_sensor(key, m)
    assert second.recovery["resumed"] == 1 and second.follower.done
    ref = run_replay(ds, outages=[(25.0, 8.0)])
    t = sorted(sols)
    keep = ref.t_ns >= t[0]
    assert np.array_equal(t, ref.t_ns[keep]) and t[0] < msgs[cut][1]["t_ns"]
    assert np.array_equal(np.array([sols[x]["llh"] for x in t]), ref.llh[keep])
    return first


class _Loopback:
    """The bus as History and fetch_history use it (serve, get, keys, count_rejected), a query answered in this
    process: the transport is all it stands in for."""

    def __init__(self):
        self.keys, self.answers, self.rejected = K, {}, []

    def serve(self, key, answer):
        self.answers[key] = answer

    def get(self, key, timeout, payload=None, qos=None):
        assert qos == M.HISTORY_QOS  # blocking: a burst of replies must not be dropped
        out = self.answers[key](payload) if key in self.answers else None
        return [] if out is None else [(key, out)]

    def count_rejected(self, key, reason):
        self.rejected.append(reason)


def _restarted_ins(tmp_path, history_size: int, dead: int | None):
    """An ins checkpointing every 5 s of data, killed after 20 s of a 40 s stream; the ingest kept its last
    history_size messages; the restarted ins gets the live stream again only ``dead`` messages after the kill
    (None: never, the stream ended while it was down) and backfills the rest from the ingest's history
    (zennav.stream.Backfill). Returns (restarted ins, its solutions by time, the messages, the dataset)."""
    import threading

    from zennav.checkpoint import Checkpointer
    from zennav.nodes.ingest import History, fetch_history
    from zennav.nodes.ins import InsNode
    from zennav.stream import Backfill

    ds = load_dataset("sim:car", duration_s=40.0)
    msgs = _msgs(ds)
    bus = _Loopback()
    history = History(bus, K.sensor_history(), history_size)
    for key, m in msgs:
        history.add(key, m, M.encode(m))
    path = tmp_path / "ins.ckpt"
    first = InsNode(lambda kind, m: None, log, checkpoint=Checkpointer(path, 5.0))
    cut = next(i for i, (_k, m) in enumerate(msgs) if m["t_ns"] > ds.initial.t_ns + 20 * 10**9)
    for key, m in msgs[:cut]:
        first.on_sensor(key, m)
    sols: dict = {}
    second = InsNode(lambda kind, m: sols.__setitem__(m["t_ns"], m) if kind == "solution" else None, log,
                     checkpoint=Checkpointer(path, 5.0))
    backfill = Backfill(second.follower, lambda a, b: fetch_history(bus, K.sensor_history(), a, b), after_s=0.0)
    lock, never = threading.RLock(), lambda: False
    backfill.run(lock, never)  # restarted, before the stream goes on: the history's next samples, if it has them
    if dead is None:
        assert not bus.rejected
        return second, sols, msgs, ds
    for key, m in msgs[cut + dead:cut + dead + 100]:  # the live stream again: held behind the dead window
        second.on_sensor(key, m)
    backfill.run(lock, never)
    for key, m in msgs[cut + dead + 100:]:
        second.on_sensor(key, m)
    assert not bus.rejected
    return second, sols, msgs, ds


def test_history_keeps_the_messages_of_its_last_size_samples():
    """The ingest's history counts samples (cseqs), not messages: with imu_batch messages of 50 samples and a fix
    between them, a history of 120 keeps the messages that reach into the last 120 cseqs, whatever the batching
    (before, it kept 120 messages: 50 times the samples with batches of 50)."""
    import msgpack

    from zennav.nodes.ingest import History

    history = History(_Loopback(), K.sensor_history(), 120)
    cseq = 0
    for i in range(6):  # batch i: cseqs 51 i .. 51 i + 49, fix i: 51 i + 50
        history.add("imu", {"schema": "imu_batch", "cseq": cseq, "t_ns_list": list(range(50))}, b"b%d" % i)
        history.add("gnss", {"schema": "gnss", "cseq": cseq + 50}, b"g%d" % i)
        cseq += 51
    kept = [payload for _key, payload in msgpack.unpackb(history.answer(msgpack.packb([0, cseq])))]
    assert kept == [b"b3", b"g3", b"b4", b"g4", b"b5", b"g5"]  # 305 - 120 = 185 < 202, the last cseq of batch 3
    assert [p for _k, p in msgpack.unpackb(history.answer(msgpack.packb([200, 210])))] == [b"b3", b"g3", b"b4"]


def test_restarted_ins_backfills_the_dead_window_from_the_ingest_history(tmp_path):
    """The restarted ins resumes from its checkpoint with the history's samples, fills the 3000 messages it never
    got live from it, outside its live queue, and navigates every sample: the replay's solution, bit for bit."""
    second, sols, msgs, ds = _restarted_ins(tmp_path, 20000, 3000)
    st = second.follower.status()
    assert second.recovery["resumed"] == 1 and st["done"] and not st.get("gap") and not st.get("backfill_empty")
    assert st["backfilled"] >= 3000 and second.imu_count == msgs[-1][1]["counts"]["imu"]
    ref = run_replay(ds)
    t = sorted(sols)
    keep = ref.t_ns >= t[0]
    assert np.array_equal(t, ref.t_ns[keep])
    assert np.array_equal(np.array([sols[x]["llh"] for x in t]), ref.llh[keep])


def test_restarted_after_the_stream_ended_reaches_its_end_from_the_history(tmp_path):
    """The stream ended while the ins was down (a drained ingest faster than its notice of the kill): nothing live
    comes again, yet the restarted ins goes on through the ingest's history chunk by chunk to its stream_end
    (before, it stopped after the first chunk and waited for ever) and navigates every sample as the replay."""
    second, sols, msgs, ds = _restarted_ins(tmp_path, 20000, None)
    st = second.follower.status()
    assert second.recovery["resumed"] == 1 and st["done"] and not st.get("gap") and not st.get("duplicate"), st
    assert second.imu_count == msgs[-1][1]["counts"]["imu"]
    ref = run_replay(ds)
    t = sorted(sols)
    keep = ref.t_ns >= t[0]
    assert np.array_equal(t, ref.t_ns[keep])
    assert np.array_equal(np.array([sols[x]["llh"] for x in t]), ref.llh[keep])


def test_what_the_ingest_no_longer_has_is_a_counted_gap(tmp_path):
    """The ingest kept only its last 2000 messages: the restarted ins counts the cseqs it can no longer have
    (backfill_empty) and skips them as a gap, backfills the rest and reaches the stream's end."""
    second, _, _, _ = _restarted_ins(tmp_path, 2000, 3000)
    st = second.follower.status()
    assert st["done"] and st["backfill_empty"] > 0 and st["gap"] == st["backfill_empty"], st
    assert st["backfilled"] > 0 and second.recovery["realigned"] == 1


def test_block_loop_publishes_the_step_wise_solutions_and_resumes(tmp_path, block_samples):
    """imu_batch messages of 50 samples through the ins's block loop (as Python: the compiled loop's code): every
    solution (with its velocity and attitude 1-sigma across covariance propagations) and aid report equals the
    step-wise ins's, across a GNSS outage, and as many checkpoints are written; the block loop did run most samples;
    a new block-loop ins resumed from its checkpoint navigates on as the replay, bit for bit."""
    from zennav.checkpoint import Checkpointer
    from zennav.nodes.ins import InsNode

    ds = load_dataset("sim:car", duration_s=40.0)
    msgs = _msgs(ds, outages=[(25.0, 8.0)], batch=50)
    out: dict = {None: [], "python": []}
    nodes = {b: InsNode(lambda kind, m, b=b: out[b].append((kind, m)), log, block_loop=b,
                        checkpoint=Checkpointer(tmp_path / f"{b}.ckpt", 5.0)) for b in out}
    for key, m in msgs:
        for node in nodes.values():
            node.on_sensor(key, m)
    step, block = out[None], out["python"]
    sols = [m for kind, m in step if kind == "solution"]
    assert len(sols) == nodes[None].imu_count == msgs[0][1]["counts"]["imu"] and block_samples[0] > 0.8 * len(sols)
    assert [m for kind, m in block if kind == "solution"] == sols
    assert [m for kind, m in block if kind == "aid"] == [m for kind, m in step if kind == "aid"]
    assert nodes["python"].checkpoint.written == nodes[None].checkpoint.written >= 7

    _resumed(ds, msgs, tmp_path, 60, "python")


def test_whole_batches_and_sample_by_sample_give_the_same_stream():
    """The block-loop ins takes an in-order imu_batch whole (StreamFollower.on_batch); batches that arrive swapped,
    twice or after a held one go sample by sample: the solutions, the aid reports and the stream's counts
    (reordered, duplicate) equal the step-wise ins's, which takes every batch sample by sample."""
    from zennav.nodes.ins import InsNode

    ds = load_dataset("sim:car", duration_s=20.0)
    msgs = _msgs(ds, outages=[(12.0, 4.0)], batch=50)
    batches = [i for i, (_, m) in enumerate(msgs) if m["schema"] == "imu_batch"]
    a, b = batches[20], batches[40]
    msgs[a], msgs[a + 1] = msgs[a + 1], msgs[a]  # swapped in transit
    msgs.insert(b + 1, msgs[b])  # delivered twice
    out: dict = {None: [], "python": []}
    nodes = {k: InsNode(lambda kind, m, k=k: out[k].append((kind, m)), log, block_loop=k) for k in out}
    whole = [0]
    on_batch = nodes["python"].follower.on_batch
    assert on_batch is not None

    def counted(key, msg):
        whole[0] += 1
        on_batch(key, msg)

    nodes["python"].follower.on_batch = counted
    for key, m in msgs:
        for node in nodes.values():
            node.on_sensor(key, m)
    assert [m for kind, m in out["python"] if kind in ("solution", "aid")] == \
        [m for kind, m in out[None] if kind in ("solution", "aid")]
    st = nodes["python"].follower.status()
    assert st == nodes[None].follower.status() and st["done"]
    assert st["reordered"] == 100 and st["duplicate"] == 50  # the held batch and the one it waited for
    assert len(batches) - 3 <= whole[0] < len(batches)


@pytest.mark.parametrize("every", [1, 3])
def test_solution_batches_hold_the_step_wise_solutions(every):
    """The block-loop ins with put_batch (zennav-ins --solution-batch): each stretch the loop runs at once in one
    nav_solution_batch (valid on the bus after encoding); expanded (zennav.messages.solutions) and in order with the
    single solutions of the samples the step-wise engine takes, they are the step-wise ins's solutions (every
    solution_every-th), bit for bit, through a GNSS outage; most solutions travel in batches."""
    from zennav.nodes.ins import InsNode

    ds = load_dataset("sim:car", duration_s=20.0)
    msgs = _msgs(ds, outages=[(12.0, 4.0)], batch=50)
    head = ("src", "seq", "pub_ns")
    step: list = []
    got: list = []
    batches = [0, 0]  # messages, solutions in them

    def put_batch(nav, t, rows, std, cseq, pub):
        m = M.nav_solution_batch_msg(nav, t, rows, std, cseq, pub)
        m.update(src="ins.x", seq=batches[0], pub_ns=1)
        m = M.decode(M.encode(m))
        assert M.validate_map(m, "zennav/@v1/car/nav/solution") == ""
        rows_of = M.solutions(m)
        batches[0] += 1
        batches[1] += len(rows_of)
        got.extend({k: v for k, v in r.items() if k not in head} for r in rows_of)

    ref = InsNode(lambda kind, m: step.append(m) if kind == "solution" else None, log, solution_every=every)
    node = InsNode(lambda kind, m: got.append(m) if kind == "solution" else None, log, solution_every=every,
                   block_loop="python", put_batch=put_batch)
    for key, m in msgs:
        ref.on_sensor(key, m)
        node.on_sensor(key, m)
    assert len(step) == ref.imu_count // every and got == step
    assert batches[1] > 0.8 * len(step) and batches[0] < batches[1] / 5
