#!/usr/bin/env python
"""Transport benchmark (a script, not a test): separate processes over Zenoh on loopback.

1. Throughput: the simulated drive (default 600 s of 200 Hz IMU = 120,000 samples, GNSS withheld 20 s every
   120 s) published by ingest as fast as the consumer drains (reliable, blocking congestion control: zero loss
   is checked, not assumed). Consumers:
   - "bus":   a stand-in that receives, decodes, validates and merges (zennav.stream.StreamFollower: cseq order,
              imu_batch expanded, the time chain checked) and hands each sample to a no-op: the transport ceiling;
   - "ins":   zennav-ins (the navigation engine per sample, one solution published per sample);
   - "ins-compiled": zennav-ins --compiled, batched only (each imu_batch through the engine's block loop compiled
              by numba; the same solutions);
   - "ins-batch": zennav-ins --compiled --solution-batch, batched only (the same solutions, those of each stretch
              the block loop runs at once in one nav_solution_batch message);
   - "learn": zennav-ins --learning with zennav-trainer and zennav-predictor running (samples and queries
              published, answers fused);
   - "learn-compiled": the same with zennav-ins --learning --compiled, batched only (the block loop from one
              learning event to the next: a fix, a query; numba's resident memory, benchmarks/memory.py).
   Each with one IMU sample per message and with ``zennav-ingest --batch N`` (--batch, default 50: up to N
   consecutive samples per imu_batch message, the same samples, order and solutions).
   Rate = IMU samples consumed / wall time between the consumer's first message and the stream's end; beside it
   the consumer's CPU time per sample over the same span (its process, all threads: the engine, the decoding and
   zenoh's own threads), the figure a loaded machine distorts least.
2. Latency: IMU paced at 200 Hz (real time), one sample per message; latency = wall clock at nav/solution
   receive (this process) minus the IMU message's publish time (ingest), percentiles over every sample; split at
   the solution's publish time (its pub_ns) into the ins hop (ingest publish -> ins solution publish: transport,
   wake-ups, the engine) and the solution hop (ins publish -> receive here). Beside it the transport's floor on
   the same two hops with no zennav code: this process publishes raw bytes the size of an IMU message on the
   IMU key at 200 Hz, an echo process (plain zenoh subscriber, a worker thread as the services have) publishes
   them back on the solution key with the solution's QoS, and the round trip is timed here.
3. Stage costs (in this process, no transport): microseconds per IMU sample of decode+validate, merge, the ins's
   whole per-message path (engine included) and the solution message (packed as the ins packs it,
   zennav.messages.SolutionPacker), unbatched and batched:
   where the time goes.
Peer-to-peer (peers on loopback, gossip) by default; --router also through a router (`zennav router`, everyone
a client). Every case runs --repeat times (fresh processes each time); the rate printed is the median, with
the range; the latency percentiles are over the samples of all repetitions. The last lines set the medians
beside issue 17's targets.

    .venv/bin/python benchmarks/bus_throughput.py [--duration 600] [--latency-duration 30] [--repeat 3]
        [--batch 50] [--router] [--no-learn] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

PY = sys.executable
BIN = Path(PY).parent
OUTAGES = "120:20"  # --outage-every of every throughput case: the learning loop queries while GNSS is withheld
TARGETS = {"bus": 50_000, "ins": 50_000, "learn": 20_000}  # [IMU/s] issue 17 (batched messages allowed)
LATENCY_TARGET_MS = {"p50": 0.5, "p99": 2.0}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Procs:
    """Service processes of one case; their stderr goes to files in a temporary folder (a pipe nobody reads
    would block a talkative process). stop() reaps them with wait4 and returns each one's max RSS."""

    def __init__(self, env: dict | None = None):
        self.procs: list[subprocess.Popen] = []
        self.names: list[str] = []
        self.dir = tempfile.TemporaryDirectory(prefix="zennav-bench-")
        self.env = dict(os.environ, ZENNAV_LOG="WARNING", ZENNAV_STATE_DIR=self.dir.name, **(env or {}))

    def start(self, argv: list[str], name: str) -> subprocess.Popen:
        err = open(Path(self.dir.name) / f"{name}.log", "wb")
        p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True, env=self.env)
        err.close()
        self.procs.append(p)
        self.names.append(name)
        return p

    def log_tail(self, name: str, n: int = 2000) -> str:
        path = Path(self.dir.name) / f"{name}.log"
        return path.read_text(errors="replace")[-n:] if path.exists() else ""

    def stop(self) -> dict[str, int]:
        """SIGTERM (SIGKILL after 10 s) every process, newest first; {name: max resident set size [bytes]}."""
        rss = {}
        for p in reversed(self.procs):
            if p.returncode is None:
                try:
                    os.killpg(p.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        for name, p in zip(reversed(self.names), reversed(self.procs)):
            if p.returncode is not None:  # reaped by Popen already: its rusage is gone
                continue
            deadline = time.monotonic() + 10
            while True:
                pid, status, ru = os.wait4(p.pid, os.WNOHANG)
                if pid or time.monotonic() > deadline:
                    break
                time.sleep(0.02)
            if not pid:
                p.kill()
                pid, status, ru = os.wait4(p.pid, 0)
            p.returncode = os.waitstatus_to_exitcode(status)
            rss[name] = ru.ru_maxrss * 1024
        self.procs, self.names = [], []
        self.dir.cleanup()
        return rss


def sink_main(argv) -> int:
    """Stand-in consumer for the 'bus' measurement: receives, decodes, validates and merges the stream as the ins
    does (zennav.stream.StreamFollower; an in-order imu_batch whole, as the ins takes it), hands each sample (or
    batch) to a no-op, and acknowledges the end like the ins so that ingest can exit."""
    from zennav import messages as M
    from zennav.service import ServiceRunner, add_bus_args
    from zennav.stream import StreamFollower

    p = add_bus_args(argparse.ArgumentParser())
    p.add_argument("--queue", type=int, default=1024)  # the ins's default
    args = p.parse_args(argv)
    run = ServiceRunner("ins", args)
    pub = run.bus.publisher(run.keys.nav_status())
    st: dict[str, Any] = {"imu": 0, "t0": None, "cpu0": 0.0}

    def on_sample(key, msg) -> None:
        if msg["schema"] == "imu":
            st["imu"] += 1

    def on_batch(key, msg) -> None:  # an in-order imu_batch, whole (as the ins takes it)
        st["imu"] += len(msg["t_ns_list"])

    def on_end(msg) -> None:
        wall, cpu = time.perf_counter() - st["t0"], time.process_time() - st["cpu0"]
        pub.put(M.make("nav_status", msg["t_ns"], gnss_state="valid", counters={}, rejected={}, imu_count=st["imu"],
                       gnss_count=0, model={}, stream={**follower.status(), "wall_s": wall, "cpu_s": cpu}))

    follower = StreamFollower(lambda start, join: None, on_sample, on_end, run.stream_start_of, run.log,
                              on_batch=on_batch)

    def on(key, msg, recv_ns) -> None:
        if st["t0"] is None:
            st["t0"], st["cpu0"] = time.perf_counter(), time.process_time()
        follower.on_message(key, msg)

    run.bus.recovering_subscribe(run.keys.sensors(), on, channel="fifo", capacity=args.queue, name="sensors")
    return run.serve()


INS_ARGS = {"ins": [], "ins-compiled": ["--compiled"], "ins-batch": ["--compiled", "--solution-batch"]}


def start_consumer(procs: Procs, kind: str, bus_args: list[str], bus, solution_every: int = 1) -> None:
    """The consumer processes of a case, alive on the bus when this returns."""
    wait = ["ins"]
    if kind == "bus":
        procs.start([PY, __file__, "--role", "sink", *bus_args], "sink")
    elif kind in INS_ARGS:
        procs.start([PY, "-m", "zennav.services.ins", "--solution-every", str(solution_every), *bus_args,
                     *INS_ARGS[kind]], "ins")
    else:  # the learning loop: development signing (unsigned sets), the trainer on the CPU
        procs.start([PY, "-m", "zennav.services.predictor", "--allow-unsigned", *bus_args], "predictor")
        procs.start([PY, "-m", "zennav.services.trainer", "--unsigned", "--device", "cpu", "--torch-threads", "1",
                     *bus_args], "trainer")
        procs.start([PY, "-m", "zennav.services.ins", "--learning", *bus_args,
                     *(["--compiled"] if kind == "learn-compiled" else [])], "ins")
        wait += ["predictor", "trainer"]
    if not bus.wait_alive(wait, 120):
        raise RuntimeError(f"{wait} did not come up: " + " | ".join(procs.log_tail(n, 500) for n in procs.names))


def run_case(kind: str, via_router: bool, duration: float, speed: str, want_latency: bool, batch: int = 1,
             solution_every: int = 1) -> dict:
    from zennav.bus import Bus

    procs = Procs()
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    if via_router:
        procs.start([str(BIN / "zennav"), "router", "--listen", ep], "router")
        bus_args = ["--mode", "client", "--connect", ep]
        bus = Bus("bench", mode="client", connect=[ep])
    else:
        bus_args = ["--connect", ep]
        bus = Bus("bench", mode="peer", listen=[ep], connect=[])
    lat: list[tuple[int, int, int]] = []  # [ns] IMU publish -> solution receive, -> solution publish, publish ->
    status: dict = {}
    done = threading.Event()

    def on_sol(key, msg, recv_ns):
        lat.append((recv_ns - msg["imu_pub_ns"], msg["pub_ns"] - msg["imu_pub_ns"], recv_ns - msg["pub_ns"]))

    def on_status(key, msg, recv_ns):
        if msg["stream"].get("done"):
            status.update(msg)
            done.set()

    if want_latency:
        bus.subscribe(bus.keys.nav_solution(), on_sol, channel="fifo", capacity=65536)
    bus.subscribe(bus.keys.nav_status(), on_status, channel="ring")
    try:
        start_consumer(procs, kind, bus_args, bus, solution_every)
        outage = [] if want_latency else ["--outage-every", OUTAGES]
        ing = procs.start([PY, "-m", "zennav.services.ingest", "sim:car", "-o", f"duration_s={duration}",
                           "--speed", speed, "--batch", str(batch), *outage, *bus_args], "ingest")
        if not done.wait(duration * 2 + 300):
            raise RuntimeError("stream did not finish: " + procs.log_tail("ingest") + procs.log_tail("ins"))
        ing.wait(60)
        st = status["stream"]
        n = status["imu_count"]
        out = {"consumer": kind, "via": "router" if via_router else "peer-to-peer", "batch": batch,
               "solution_every": solution_every, "imu_samples": n,
               "expected": int(duration * 200), "wall_s": round(st["wall_s"], 3),
               "rate_per_s": round(n / st["wall_s"]), "cpu_us_per_sample": round(st.get("cpu_s", 0.0) / n * 1e6, 2),
               "lost": int(duration * 200) - n,
               "gap": st.get("gap", 0), "duplicate": st.get("duplicate", 0)}
        if want_latency:
            t_end = time.monotonic() + 10
            while len(lat) < n and time.monotonic() < t_end:
                time.sleep(0.05)
            ms = np.array(lat) / 1e6
            out.update(solutions=len(ms), latency_ms_all=ms, latency_ms=percentiles(ms[:, 0]))
        return out
    finally:
        bus.close()
        procs.stop()


def percentiles(ms: np.ndarray) -> dict:
    out = {k: round(float(np.percentile(ms, q)), 3) for k, q in (("p50", 50), ("p90", 90), ("p99", 99))}
    out["max"] = round(float(ms.max()), 3)
    return out


def stage_costs(duration: float, batch: int) -> dict:
    """[us per IMU sample] of the ins's per-message path in this process (no transport), on the messages ingest
    would publish (encoded): decode+validate (zennav.messages.Validator), merge (StreamFollower to a no-op), the ins
    (InsNode.on_sensor: merge, engine, solution built; published to a no-op; batched: also with the compiled block
    loop, zennav-ins --compiled) and the solution message (packed as the ins service packs it,
    zennav.messages.SolutionPacker, from the engine's state).
    Best of 3 passes each (the machine is shared)."""
    import logging

    from zennav import messages as M
    from zennav.datasets.registry import load_dataset
    from zennav.nodes.ins import InsNode
    from zennav.replay import sensor_events
    from zennav.stream import StreamFollower, stream_messages

    ds = load_dataset("sim:car", duration_s=duration)
    windows, events = sensor_events(ds, [], None)
    keys = M.Keys("car")
    key = {"stream": keys.stream(), "imu": keys.imu(), "gnss": keys.gnss()}
    wire = []
    for i, (kind, msg) in enumerate(stream_messages(ds, windows, events, batch)):
        msg.update(src="ingest.bench", seq=i, pub_ns=time.time_ns())
        wire.append((key[kind], M.encode(msg)))
    n = len(ds.imu.t_ns)
    log = logging.getLogger("bench")

    def decoded() -> list:
        v = M.Validator()
        return [(k, v.check(k, p)[0]) for k, p in wire]

    def best(setup, body) -> float:
        times = []
        for _ in range(3):
            arg = setup()
            t0 = time.perf_counter()
            body(arg)
            times.append(time.perf_counter() - t0)
        return round(min(times) / n * 1e6, 2)

    def merge(msgs) -> None:
        f = StreamFollower(lambda start, join: None, lambda key, msg: None, lambda end: None,
                           on_batch=lambda key, msg: None)
        for k, m in msgs:
            f.on_message(k, m)

    def ins(node_msgs) -> None:
        node, msgs = node_msgs
        for k, m in msgs:
            node.on_sensor(k, m)

    def solution(nav) -> None:
        pack, s = M.SolutionPacker().pack, nav.state
        std = [*nav.std_pos_ned.tolist(), *nav.std_v_n.tolist(), *nav.std_att.tolist()]
        for i in range(n):
            pack(nav.t_ns, (s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3), std, nav.gyro_bias,
                 nav.accel_bias, nav.gnss_state, i, 0, "ins.bench", i, time.time_ns())

    def built_ins(block_loop=None) -> tuple:
        return InsNode(lambda kind, msg: None, log, block_loop=block_loop), decoded()

    def navigated():
        node, msgs = built_ins()
        ins((node, msgs))
        return node.nav

    out = {"batch": batch, "decode_validate": best(lambda: None, lambda _: decoded()),
           "merge": best(decoded, merge), "ins": best(built_ins, ins), "solution_msg": best(navigated, solution)}
    if batch > 1:
        from zennav.nav import kernels

        kernels.compiled()  # loaded (compiled once per machine) outside the timing
        out["ins_compiled"] = best(lambda: built_ins("compiled"), ins)
    return out


def throughput(kinds: list[str], routes: list[bool], duration: float, batch: int, repeat: int,
               solution_every: int) -> list[dict]:
    """Every kind with one sample per message and with batch (ins-compiled, ins-batch: batched only); the ins also
    publishing one solution in solution_every (when > 1, batched)."""
    cases = [(kind, b, 1) for kind in kinds for b in sorted({1, batch})
             if not kind.endswith(("-compiled", "-batch")) or b > 1]
    for kind in ("ins", "ins-compiled"):
        if kind in kinds and solution_every > 1 and batch > 1:
            cases.insert(cases.index((kind, batch, 1)) + 1, (kind, batch, solution_every))
    results = []
    for via_router in routes:
        for kind, b, every in cases:
            runs = [run_case(kind, via_router, duration, "0", want_latency=False, batch=b, solution_every=every)
                    for _ in range(repeat)]
            rates = sorted(r["rate_per_s"] for r in runs)
            cpu = statistics.median(r["cpu_us_per_sample"] for r in runs)
            r = {"test": "throughput", **runs[0], "rate_per_s": int(statistics.median(rates)), "rates": rates,
                 "cpu_us_per_sample": cpu,
                 "lost": sum(x["lost"] for x in runs), "gap": sum(x["gap"] for x in runs),
                 "duplicate": sum(x["duplicate"] for x in runs)}
            del r["wall_s"], r["imu_samples"]
            results.append(r)
            sols = f" (1 solution in {every})" if every > 1 else ""
            print(f"throughput {r['via']:<13} ingest -> {kind:<12} batch {b:>3}{sols}: median {r['rate_per_s']:>7} "
                  f"IMU/s over {len(runs)} runs (range {rates[0]}-{rates[-1]}; consumer CPU {cpu:.1f} us/sample; "
                  f"{runs[0]['expected']} samples each, "
                  f"lost {r['lost']}, gaps {r['gap']}, duplicates {r['duplicate']})", flush=True)
    return results


ECHO_IN, ECHO_OUT = "zennav/@v1/bench/sensor/imu/echo", "zennav/@v1/bench/nav/solution"


def echo_main(argv) -> int:
    """The transport floor's echo: every payload on ECHO_IN published back unchanged on ECHO_OUT (plain zenoh,
    the IMU's and the solution's QoS through zennav.bus, no decoding), until SIGTERM."""
    from zennav.bus import Bus
    from zennav.stopsignals import on_stop_signals

    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    args = p.parse_args(argv)
    bus = Bus("echo", mode="peer", connect=[args.connect], listen=["tcp/127.0.0.1:0"])
    out = bus.publisher(ECHO_OUT, latest=False)
    bus.subscribe(ECHO_IN, lambda key, payload, recv_ns: out.put_raw(payload), validate=False, channel="fifo")
    stop = threading.Event()
    on_stop_signals(lambda signum: stop.set())
    stop.wait()
    bus.close()
    return 0


def transport_floor(duration: float, size: int = 154) -> np.ndarray:
    """[ms] round trips bench -> echo -> bench at 200 Hz of raw payloads of size bytes (an IMU message's, with
    its header)."""
    from zennav.bus import Bus

    procs = Procs()
    ep = f"tcp/127.0.0.1:{free_port()}"
    bus = Bus("bench", mode="peer", listen=[ep], connect=[])
    rtt: list[int] = []
    sub = bus.subscribe(ECHO_OUT, lambda key, payload, recv_ns: rtt.append(
        recv_ns - int.from_bytes(payload[:8], "little")), validate=False, channel="fifo")
    try:
        procs.start([PY, __file__, "--role", "echo", "--connect", ep], "echo")
        pub = bus.publisher(ECHO_IN, latest=False)
        t_end = time.monotonic() + 30
        while not pub.matching and time.monotonic() < t_end:
            time.sleep(0.05)
        time.sleep(1.0)  # the echo's publisher reaches this subscriber
        pad = bytes(max(0, size - 8))
        t_next = time.monotonic()
        for _ in range(int(duration * 200)):
            pub.put_raw(time.time_ns().to_bytes(8, "little") + pad)
            t_next += 0.005
            time.sleep(max(0.0, t_next - time.monotonic()))
        time.sleep(0.5)
        return np.array(rtt) / 1e6
    finally:
        sub.close()
        bus.close()
        procs.stop()


def latency(routes: list[bool], duration: float, repeat: int, consumers: list[str]) -> list[dict]:
    results = []
    floor = np.concatenate([transport_floor(duration) for _ in range(repeat)])
    fm = percentiles(floor)
    results.append({"test": "transport_floor_200hz", "runs": repeat, "round_trips": len(floor), "latency_ms": fm})
    print(f"floor      peer-to-peer  zenoh alone, the same two hops at 200 Hz (154 B raw, echo process): p50 "
          f"{fm['p50']:.3f} ms, p90 {fm['p90']:.3f} ms, p99 {fm['p99']:.3f} ms, max {fm['max']:.3f} ms "
          f"({len(floor)} round trips, {int(duration * 200) * repeat} sent)", flush=True)
    for via_router, kind in ((v, k) for v in routes for k in consumers):
        runs = [run_case(kind, via_router, duration, "1", want_latency=True) for _ in range(repeat)]
        ms = np.concatenate([x.pop("latency_ms_all") for x in runs])
        lm, ins_hop, sol_hop = (percentiles(ms[:, i]) for i in range(3))
        r = {"test": "latency_200hz", "consumer": kind, "via": runs[0]["via"], "runs": len(runs), "solutions": len(ms),
             "lost": sum(x["lost"] for x in runs), "latency_ms": lm,
             "p50_per_run": [x["latency_ms"]["p50"] for x in runs],
             "p99_per_run": [x["latency_ms"]["p99"] for x in runs], "ins_hop_ms": ins_hop, "solution_hop_ms": sol_hop}
        results.append(r)
        print(f"latency    {r['via']:<13} {kind}: IMU publish -> solution receive at 200 Hz: p50 {lm['p50']:.3f} ms, "
              f"p90 {lm['p90']:.3f} ms, p99 {lm['p99']:.3f} ms, max {lm['max']:.3f} ms "
              f"({r['solutions']} solutions over {len(runs)} runs, lost {r['lost']}; per run p50 "
              f"{r['p50_per_run']}, p99 {r['p99_per_run']}; ins hop p50 {ins_hop['p50']:.3f} ms, p99 "
              f"{ins_hop['p99']:.3f} ms; solution hop p50 {sol_hop['p50']:.3f} ms, p99 {sol_hop['p99']:.3f} ms)",
              flush=True)
    return results


def summary(results: list[dict]) -> None:
    """The medians beside issue 17's targets (peer-to-peer, the best batch size measured)."""
    print("\nissue 17 targets (peer-to-peer; medians):")
    for kind, target in TARGETS.items():
        rows = [r for r in results if r["test"] == "throughput"
                and r["consumer"] in (kind, f"{kind}-compiled", f"{kind}-batch")
                and r["via"] == "peer-to-peer" and r["solution_every"] == 1]  # a solution per sample
        if rows:
            best = max(rows, key=lambda r: r["rate_per_s"])
            clean = all(r["lost"] == r["gap"] == r["duplicate"] == 0 for r in rows)
            side = ", ".join(f"{r['consumer']} batch {r['batch']}: {r['rate_per_s']}" for r in rows)
            print(f"  {kind:<6} >= {target:>6} IMU/s: {best['rate_per_s']:>7} ({best['consumer']}, "
                  f"batch {best['batch']}) "
                  f"({'met' if best['rate_per_s'] >= target else 'NOT met'}; {side}; "
                  f"{'nothing' if clean else 'SAMPLES'} lost or duplicated)")
    for r in results:
        if r["test"] == "transport_floor_200hz":
            print(f"  the transport's floor on those two hops (zenoh alone): p50 {r['latency_ms']['p50']:.3f} ms, "
                  f"p99 {r['latency_ms']['p99']:.3f} ms")
        if r["test"] == "latency_200hz" and r["via"] == "peer-to-peer":
            lm = r["latency_ms"]
            print(f"  latency at 200 Hz, one sample per message ({r['consumer']}): " + ", ".join(
                f"{q} {lm[q]:.3f} ms (<= {t} ms: {'met' if lm[q] <= t else 'NOT met'})"
                for q, t in LATENCY_TARGET_MS.items()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--role", default="bench", choices=("bench", "sink", "echo"))
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds for throughput (200 Hz)")
    ap.add_argument("--latency-duration", type=float, default=30.0, help="real-time seconds for latency")
    ap.add_argument("--batch", type=int, default=50,
                    help="also every consumer with IMU sent in imu_batch messages of this many samples (1: not)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case (median rate, pooled latency)")
    ap.add_argument("--solution-every", type=int, default=10,
                    help="also the ins (batched) publishing one solution in this many samples (1: not)")
    ap.add_argument("--router", action="store_true", help="also every case through a router")
    ap.add_argument("--no-learn", action="store_true", help="skip the learning-loop case")
    ap.add_argument("--no-compiled", action="store_true", help="skip the zennav-ins --compiled case")
    ap.add_argument("--consumers", default=None, help="comma-separated consumers to run (default: all not skipped)")
    ap.add_argument("--latency-consumers", default="ins",
                    help="comma-separated consumers of the latency case: ins, ins-compiled (one sample per message)")
    ap.add_argument("--only", default=None, choices=("throughput", "latency", "stages"), help="run one part")
    ap.add_argument("--json", default=None, help="also write the results here")
    args, rest = ap.parse_known_args()
    if args.role == "sink":
        return sink_main(rest)
    if args.role == "echo":
        return echo_main(rest)
    results: list[dict] = []
    routes = [False, True] if args.router else [False]
    if args.only in (None, "stages"):
        for b in sorted({1, args.batch}):
            c = stage_costs(min(args.duration, 120.0), b)
            results.append({"test": "stages_us_per_sample", **c})
            print(f"stages (us per IMU sample, in-process, batch {b:>3}): decode+validate {c['decode_validate']}, "
                  f"merge {c['merge']}, ins whole path {c['ins']} (engine included)"
                  + (f", with --compiled {c['ins_compiled']}" if "ins_compiled" in c else "")
                  + f", solution packed {c['solution_msg']}", flush=True)
    if args.only in (None, "throughput"):
        kinds = ["bus", "ins"] + ([] if args.no_compiled or args.batch <= 1 else ["ins-compiled", "ins-batch"]) + \
            ([] if args.no_learn else ["learn"] + ([] if args.no_compiled or args.batch <= 1 else ["learn-compiled"]))
        kinds = [k for k in kinds if args.consumers is None or k in args.consumers.split(",")]
        results += throughput(kinds, routes, args.duration, args.batch, args.repeat, args.solution_every)
    if args.only in (None, "latency"):
        results += latency(routes, args.latency_duration, args.repeat, args.latency_consumers.split(","))
    summary(results)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
