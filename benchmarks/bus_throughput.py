#!/usr/bin/env python
"""Transport benchmark (a script, not a test): separate processes over Zenoh on loopback.

1. Throughput: the simulated drive (default 600 s of 200 Hz IMU = 120,000 samples) published by ingest as
   fast as the consumer drains (reliable, blocking congestion control: zero loss is checked, not assumed):
   - "ins":  ingest -> ins (the full navigation engine per sample, solutions published);
   - "bus":  ingest -> a stand-in consumer that only receives, decodes and validates (transport ceiling).
   Rate = IMU samples consumed / wall time between the consumer's first and last message.
   With --batch N (default 10) also ingest -> ins with `zennav-ingest --batch N`: up to N consecutive IMU samples
   per imu_batch message (the same samples, order and solutions; one zenoh message and one validation per batch).
2. Latency: IMU paced at 200 Hz (real time); latency = wall clock at nav/solution receive (this process)
   minus the IMU message's publish time (ingest), percentiles over every sample.
Both peer-to-peer (peers on loopback, gossip) and through a router (`zennav router`, everyone a client).

Every case runs --repeat times (fresh processes each time); the rate printed is the median, with the range; the
latency percentiles are over the samples of all repetitions.

    .venv/bin/python benchmarks/bus_throughput.py [--duration 600] [--latency-duration 30] [--repeat 3]
        [--batch 10] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

PY = sys.executable
BIN = Path(PY).parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Procs:
    def __init__(self):
        self.procs = []

    def start(self, argv, name):
        p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True,
                             env=dict(os.environ, ZENNAV_LOG="WARNING"))
        p.name = name
        self.procs.append(p)
        return p

    def stop(self):
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in reversed(self.procs):
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
        self.procs = []


def sink_main(argv) -> int:
    """Stand-in consumer for the 'bus' measurement: receives, decodes, validates; acknowledges the end like
    the ins does so ingest can exit."""
    from zennav import messages as M
    from zennav.service import ServiceRunner, add_bus_args

    p = add_bus_args(argparse.ArgumentParser())
    args = p.parse_args(argv)
    run = ServiceRunner("ins", args)
    pub = run.bus.publisher(run.keys.nav_status())
    st: dict[str, Any] = {"n": 0, "imu": 0, "t0": None, "src": None, "cseqs": set()}

    def on(key, msg, recv_ns):
        if st["t0"] is None:
            st["t0"] = time.perf_counter()
        st["n"] += 1
        if msg["schema"] == "imu":
            st["imu"] += 1
        elif msg["schema"] == "imu_batch":
            st["imu"] += len(msg["t_ns_list"])
        elif msg["schema"] == "stream_start":
            st["src"] = msg["src"]
        elif msg["schema"] == "stream_end":
            wall = time.perf_counter() - st["t0"]
            pub.put(M.make("nav_status", msg["t_ns"], gnss_state="valid", counters={}, rejected={},
                           imu_count=st["imu"], gnss_count=0, model={},
                           stream={"src": msg["src"], "done": True, "last_cseq": msg["last_cseq"], "wall_s": wall,
                                   "expected_imu": msg["counts"]["imu"], "received": st["n"]}))

    run.bus.subscribe(run.keys.sensors(), on, channel="fifo", capacity=8192)
    return run.serve()


def run_case(kind: str, via_router: bool, duration: float, speed: str, want_latency: bool, batch: int = 1) -> dict:
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
    lat = []
    status = {}
    done = threading.Event()

    def on_sol(key, msg, recv_ns):
        lat.append(recv_ns - msg["imu_pub_ns"])

    def on_status(key, msg, recv_ns):
        if msg["stream"].get("done"):
            status.update(msg)
            done.set()

    if want_latency:
        bus.subscribe(bus.keys.nav_solution(), on_sol, channel="fifo", capacity=65536)
    bus.subscribe(bus.keys.nav_status(), on_status, channel="ring")
    try:
        if kind == "ins":
            procs.start([PY, "-m", "zennav.services.ins", *bus_args], "ins")
        else:
            procs.start([PY, __file__, "--role", "sink", *bus_args], "sink")
        if not bus.wait_alive(["ins"], 60):
            raise RuntimeError("consumer did not come up")
        ing = procs.start([PY, "-m", "zennav.services.ingest", "sim:car", "-o", f"duration_s={duration}",
                           "--speed", speed, "--batch", str(batch), *bus_args], "ingest")
        if not done.wait(duration * 2 + 120):
            raise RuntimeError("stream did not finish: " + ing.stderr.read().decode()[-2000:] if ing.poll() else "")
        ing.wait(60)
        st = status["stream"]
        n = status["imu_count"]
        out = {"consumer": kind, "via": "router" if via_router else "peer-to-peer", "batch": batch, "imu_samples": n,
               "expected": int(duration * 200), "wall_s": round(st["wall_s"], 3),
               "rate_per_s": round(n / st["wall_s"]), "lost": int(duration * 200) - n,
               "gap": st.get("gap", 0), "duplicate": st.get("duplicate", 0)}
        if want_latency:
            t_end = time.monotonic() + 10
            while len(lat) < n and time.monotonic() < t_end:
                time.sleep(0.05)
            ms = np.array(lat) / 1e6
            out.update(solutions=len(ms), latency_ms_all=ms, latency_ms={"p50": round(float(np.percentile(ms, 50)), 3),
                                                      "p90": round(float(np.percentile(ms, 90)), 3),
                                                      "p99": round(float(np.percentile(ms, 99)), 3),
                                                      "max": round(float(ms.max()), 3)})
        return out
    finally:
        bus.close()
        procs.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--role", default="bench", choices=("bench", "sink"))
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds for throughput (200 Hz)")
    ap.add_argument("--latency-duration", type=float, default=30.0, help="real-time seconds for latency")
    ap.add_argument("--batch", type=int, default=10,
                    help="also measure ingest -> ins with IMU sent in imu_batch messages of this many samples (1: not)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case (median rate, pooled latency)")
    ap.add_argument("--json", default=None, help="also write the results here")
    args, rest = ap.parse_known_args()
    if args.role == "sink":
        return sink_main(rest)
    results = []
    cases = [("bus", 1), ("ins", 1)] + ([("ins", args.batch)] if args.batch > 1 else [])
    for via_router in (False, True):
        for kind, batch in cases:
            runs = [run_case(kind, via_router, args.duration, "0", want_latency=False, batch=batch)
                    for _ in range(args.repeat)]
            rates = sorted(r["rate_per_s"] for r in runs)
            r = {"test": "throughput", **runs[0], "rate_per_s": int(np.median(rates)), "rates": rates,
                 "lost": sum(x["lost"] for x in runs), "gap": sum(x["gap"] for x in runs),
                 "duplicate": sum(x["duplicate"] for x in runs)}
            del r["wall_s"], r["imu_samples"]
            results.append(r)
            what = kind if batch == 1 else f"{kind} (--batch {batch})"
            print(f"throughput {r['via']:<13} ingest -> {what:<3}: median {r['rate_per_s']:>7} IMU/s over "
                  f"{len(runs)} runs (range {rates[0]}-{rates[-1]}; {runs[0]['expected']} samples each, "
                  f"lost {r['lost']}, gaps {r['gap']}, duplicates {r['duplicate']})", flush=True)
    for via_router in (False, True):
        runs = [run_case("ins", via_router, args.latency_duration, "1", want_latency=True) for _ in range(args.repeat)]
        ms = np.concatenate([x.pop("latency_ms_all") for x in runs])
        lm = {k: round(float(np.percentile(ms, q)), 3) for k, q in (("p50", 50), ("p90", 90), ("p99", 99))}
        lm["max"] = round(float(ms.max()), 3)
        r = {"test": "latency_200hz", "via": runs[0]["via"], "runs": len(runs), "solutions": int(ms.size),
             "lost": sum(x["lost"] for x in runs), "latency_ms": lm,
             "p50_per_run": [x["latency_ms"]["p50"] for x in runs]}
        results.append(r)
        print(f"latency    {r['via']:<13} IMU publish -> solution receive at 200 Hz: p50 {lm['p50']:.3f} ms, "
              f"p90 {lm['p90']:.3f} ms, p99 {lm['p99']:.3f} ms, max {lm['max']:.3f} ms "
              f"({r['solutions']} solutions over {len(runs)} runs, lost {r['lost']})", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
