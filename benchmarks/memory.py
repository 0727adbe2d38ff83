#!/usr/bin/env python
"""Memory benchmark (a script, not a test): the resident memory of the edge set's processes and of a replay.

1. The edge set, each service its own process on loopback (peer-to-peer): zennav-ingest (sim:car, --duration s
   of 200 Hz, GNSS withheld 20 s every 120 s, as fast as the ins drains), zennav-ins --learning, zennav-predictor,
   zennav-trainer (signing off, CPU), zennav-attitude. Max RSS of every service process (wait4's ru_maxrss after
   it exits: exact), of the processes they start (the trainer's fit worker: VmHWM from /proc, read every 0.2 s
   until it exits), and whether torch is mapped into the ins or the predictor (it must never be). --compiled: a
   second ins beside it, learning off, with ``zennav-ins --compiled`` (numba's block loop), on the same stream
   (``--batch``: IMU samples per message; ``--solution-batch``: its solutions in nav_solution_batch messages, as
   many as its recovery cache keeps).
2. ``zennav replay sim:car -o duration_s=1800`` (30 min at 200 Hz, --replay-duration): max RSS of the command.
Targets (issue 17): ins <= 200 MB, predictor <= 120 MB, replay of 30 min at 200 Hz <= 1 GB.

    .venv/bin/python benchmarks/memory.py [--duration 600] [--replay-duration 1800] [--compiled [--solution-batch]]
        [--batch 1] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bus_throughput import OUTAGES, PY, Procs, free_port

TARGETS_MB = {"ins": 200, "predictor": 120, "replay": 1000}
MB = 1e6


def descendants(pid: int) -> list[int]:
    """Every process below pid (from /proc's parent links)."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                ppid = int(Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(d))
    out, todo = [], list(children.get(pid, []))
    while todo:
        p = todo.pop()
        out.append(p)
        todo += children.get(p, [])
    return out


def status_kb(pid: int, field: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def maps_torch(pid: int) -> bool:
    try:
        return "torch" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


class Watch:
    """Every 0.2 s: the peak RSS (VmHWM) of the processes the services started, and torch in ins/predictor."""

    def __init__(self, procs: Procs):
        self.procs, self.stop = procs, threading.Event()
        self.children: dict[str, int] = {}  # "service (child pid)" -> max VmHWM [kB]
        self.torch: dict[str, bool] = {}
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        while not self.stop.wait(0.2):
            for name, p in zip(self.procs.names, self.procs.procs):
                if name in ("ins", "predictor"):
                    self.torch[name] = self.torch.get(name, False) or maps_torch(p.pid)
                for c in descendants(p.pid):
                    k = f"{name} (child {c})"
                    self.children[k] = max(self.children.get(k, 0), status_kb(c, "VmHWM"))


def edge_set(duration: float, compiled: bool = False, batch: int = 1, solution_batch: bool = False) -> dict:
    from zennav.bus import Bus

    procs = Procs()
    ep = f"tcp/127.0.0.1:{free_port()}"
    bus_args = ["--connect", ep]
    bus = Bus("bench", mode="peer", listen=[ep], connect=[])
    done = threading.Event()

    def on_status(key, msg, recv_ns) -> None:
        if msg["stream"].get("done"):
            done.set()

    bus.subscribe(bus.keys.nav_status(), on_status, channel="ring")
    watch = Watch(procs)
    try:
        procs.start([PY, "-m", "zennav.services.predictor", "--allow-unsigned", *bus_args], "predictor")
        procs.start([PY, "-m", "zennav.services.trainer", "--unsigned", "--device", "cpu", "--torch-threads", "1",
                     *bus_args], "trainer")
        procs.start([PY, "-m", "zennav.services.attitude", *bus_args], "attitude")
        procs.start([PY, "-m", "zennav.services.ins", "--learning", *bus_args], "ins")
        wait = ["ins", "predictor", "trainer", "attitude"]
        if compiled:
            procs.start([PY, "-m", "zennav.services.ins", "--compiled", "--nav-prefix", "compiled", "--name",
                         "ins-compiled", *(["--solution-batch"] if solution_batch else []), *bus_args], "ins-compiled")
            wait.append("ins-compiled")
        if not bus.wait_alive(wait, 120):
            tails = " | ".join(procs.log_tail(n, 400) for n in procs.names)
            raise RuntimeError(f"the edge set did not come up: {tails}")
        procs.start([PY, "-m", "zennav.services.ingest", "sim:car", "-o", f"duration_s={duration}", "--speed", "0",
                     "--batch", str(batch), "--outage-every", OUTAGES, "--wait-for", ",".join(wait[:1] + wait[3:]),
                     *bus_args], "ingest")
        if not done.wait(duration * 3 + 300):
            raise RuntimeError("stream did not finish: " + procs.log_tail("ingest") + procs.log_tail("ins"))
        time.sleep(2.0)  # the trainer's last fit, the predictor's last answers
    finally:
        bus.close()
        watch.stop.set()
        watch.thread.join()
        rss = procs.stop()
    return {"max_rss_bytes": rss, "children_max_rss_bytes": {k: v * 1024 for k, v in watch.children.items() if v},
            "torch_mapped": watch.torch}


def replay(duration: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="zennav-mem-") as tmp:
        t0 = time.monotonic()
        p = subprocess.Popen([str(Path(PY).parent / "zennav"), "replay", "sim:car", "-o", f"duration_s={duration}",
                              "-q", "--out", tmp], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        err = p.stderr.read() if p.stderr else b""
        _, status, ru = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        if p.returncode:
            raise RuntimeError(err.decode()[-2000:])
        return {"max_rss_bytes": ru.ru_maxrss * 1024, "wall_s": round(time.monotonic() - t0, 1)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds streamed to the edge set")
    ap.add_argument("--replay-duration", type=float, default=1800.0, help="simulated seconds replayed (0: skip)")
    ap.add_argument("--compiled", action="store_true", help="also an ins --compiled (learning off) on the stream")
    ap.add_argument("--solution-batch", action="store_true", help="the ins --compiled with --solution-batch")
    ap.add_argument("--batch", type=int, default=1, help="IMU samples per ingest message (zennav-ingest --batch)")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args()
    res = {"edge_set": edge_set(args.duration, args.compiled, args.batch, args.solution_batch)}
    e = res["edge_set"]
    compiled = (", ins --compiled" + (" --solution-batch" if args.solution_batch else "")) if args.compiled else ""
    print(f"edge set, {args.duration:g} s of 200 Hz streamed, batch {args.batch} (ins --learning, predictor, trainer, "
          f"attitude, ingest{compiled}):")
    for name, b in e["max_rss_bytes"].items():
        t = TARGETS_MB.get(name)
        goal = f" (target <= {t} MB: {'met' if b / MB <= t else 'NOT met'})" if t else ""
        torch = f"; torch mapped: {e['torch_mapped'][name]}" if name in e["torch_mapped"] else ""
        print(f"  {name:<10} max RSS {b / MB:7.1f} MB{goal}{torch}")
    for name, b in e["children_max_rss_bytes"].items():
        print(f"  {name:<10} max RSS {b / MB:7.1f} MB (a process the service started)")
    if args.replay_duration > 0:
        r = res["replay"] = replay(args.replay_duration)
        t = TARGETS_MB["replay"]
        print(f"zennav replay sim:car, {args.replay_duration:g} s at 200 Hz: max RSS {r['max_rss_bytes'] / MB:.1f} MB "
              f"(target <= {t} MB: {'met' if r['max_rss_bytes'] / MB <= t else 'NOT met'}; {r['wall_s']} s)")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
