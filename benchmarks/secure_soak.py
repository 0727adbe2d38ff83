#!/usr/bin/env python
"""Soak of the demo's process set (deploy/demo.yaml: router, ins with learning in lockstep, ins-plain, attitude,
predictor, trainer, monitor, record, ingest) streaming the simulated drive at full speed, first in the plain
configuration (peers on loopback), then in the secure one (`zennav launch ... --secure DIR`: every service a
client of the router over mutual TLS with user/password and the router's access control), in the same run.

Each variant is `zennav launch <set> --until record` (what the product runs); the figures come from the
recorder's MCAP (zennav.recording.read_mcap; its log time is the sample time, so the clock here is each message's
pub_ns, the publisher's wall clock):
- IMU published: the ingest's stream_end counts; per ins (nav/, nav/plain/): solutions recorded, duplicate
  solutions (a sample time twice), lost = IMU published - distinct solutions, and the ins's own merger counts
  (gap, duplicate) from its last nav/status;
- throughput: IMU samples / (last solution published - stream_start published), wall clock [samples/s].

    .venv/bin/python benchmarks/secure_soak.py [--drive-s 3000] [--out out/secure_soak] [--variants plain,secure]

--drive-s is the simulated drive's length (200 Hz IMU); pick it so that one variant streams for the soak time
wanted (the script prints each variant's streaming seconds).
"""
from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import yaml

from zennav.certs import make_certs
from zennav.learn.signing import PRIVATE_NAME, PUBLIC_NAME
from zennav.learn.signing import generate as generate_keys
from zennav.recording import read_mcap

PY = sys.executable
ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _set_file(out: Path, name: str, drive_s: float) -> Path:
    """deploy/demo.yaml with the drive's length, a free port, the recording under out/ and, as `zennav demo` gives
    them, a parameter-set signing pair (out/keys/: the trainer signs, the predictor verifies) and the trainer's
    version state (out/<name>-state/)."""
    keys = out / "keys"
    if not (keys / PRIVATE_NAME).exists():
        generate_keys(keys)
    env = {"trainer": {"ZENNAV_SIGNING_KEY": str(keys / PRIVATE_NAME), "ZENNAV_STATE_DIR": str(out / f"{name}-state")},
           "predictor": {"ZENNAV_VERIFY_KEY": str(keys / PUBLIC_NAME)}}
    spec = yaml.safe_load((ROOT / "deploy" / "demo.yaml").read_text())
    spec["rendezvous"] = f"tcp/127.0.0.1:{_free_port()}"
    spec["up_timeout_s"] = 180
    for s in spec["services"]:
        cmd = s["command"]
        if s["name"] == "ingest":
            cmd[cmd.index("-o") + 1] = f"duration_s={drive_s}"
            cmd += ["--wait-timeout", "180"]
        if s["name"] == "record":
            cmd[-1] = str(out / f"{name}.mcap")
        if s["name"] in env:
            s["env"] = {**s.get("env", {}), **env[s["name"]]}
    path = out / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def _figures(mcap: Path) -> dict:
    t_start = None
    end: dict = {}
    sol_t: dict[str, Counter] = {}
    sol_last: dict[str, int] = {}
    status: dict[str, dict] = {}
    for key, msg, _payload, _log_ns in read_mcap(mcap, [r"/sensor/stream$", r"/nav/(.+/)?(solution|status)$"]):
        rel = key.split("/", 3)[3]
        if rel == "sensor/stream" and msg and msg.get("schema") == "stream_start":
            t_start = msg["pub_ns"]  # published just before the first IMU sample
        elif rel == "sensor/stream" and msg and msg.get("schema") == "stream_end":
            end = msg
        elif rel.startswith("nav/") and rel.endswith("/solution") or rel == "nav/solution":
            sol_t.setdefault(rel, Counter())[msg["t_ns"]] += 1
            sol_last[rel] = max(sol_last.get(rel, 0), msg["pub_ns"])
        elif rel.startswith("nav/") and rel.endswith("status") and msg:
            status[rel] = msg.get("stream", {})
    imu = int(end.get("counts", {}).get("imu", -1))
    out: dict = {"imu_published": imu, "ins": {}}
    for rel, c in sorted(sol_t.items()):
        st = status.get(rel[:-len("solution")] + "status", {})
        seconds = (sol_last[rel] - t_start) / 1e9 if t_start else float("nan")
        out["ins"][rel] = {"solutions": sum(c.values()), "distinct": len(c), "lost": imu - len(c),
                           "duplicate_solutions": sum(v - 1 for v in c.values() if v > 1),
                           "merger_gap": st.get("gap", 0), "merger_duplicate": st.get("duplicate", 0),
                           "stream_s": round(seconds, 1), "throughput_per_s": round(imu / seconds, 1)}
    return out


def run_variant(name: str, out: Path, drive_s: float, creds: Path | None, limit_s: float) -> dict:
    set_file = _set_file(out, name, drive_s)
    cmd = [str(Path(PY).parent / "zennav"), "launch", str(set_file), "--until", "record"]
    if creds is not None:
        cmd += ["--secure", str(creds)]
    log = out / f"{name}.log"
    t0 = time.monotonic()
    with log.open("w") as f:
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT)
        try:
            rc = proc.wait(limit_s)
        except subprocess.TimeoutExpired:  # stop the set (the launcher stops its services, the recorder closes)
            proc.send_signal(signal.SIGTERM)
            rc = proc.wait(120)
            rc = rc or -signal.SIGTERM
    res = {"variant": name, "rc": rc, "wall_s": round(time.monotonic() - t0, 1), "log": str(log)}
    mcap = out / f"{name}.mcap"
    if mcap.exists():
        res.update(_figures(mcap))
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--drive-s", type=float, default=3000.0, help="simulated drive length [s of data]")
    p.add_argument("--out", type=Path, default=ROOT / "out" / "secure_soak")
    p.add_argument("--variants", default="plain,secure")
    p.add_argument("--limit-s", type=float, default=3600.0,
                   help="stop a variant after this long [s] (its figures then count what was not navigated)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    creds = args.out / "creds"
    if not (creds / "ca.pem").exists():
        make_certs(creds)
    results = []
    for name in args.variants.split(","):
        r = run_variant(name, args.out, args.drive_s, creds if name == "secure" else None, args.limit_s)
        results.append(r)
        print(json.dumps(r), flush=True)
    print(f"\ndrive {args.drive_s:.0f} s = {results[0].get('imu_published')} IMU samples, full speed")
    print(f"{'variant':<8} {'ins':<20} {'solutions':>10} {'lost':>6} {'dup':>5} {'gap':>5} {'stream s':>9} "
          f"{'samples/s':>10}")
    for r in results:
        for rel, f in r.get("ins", {}).items():
            print(f"{r['variant']:<8} {rel:<20} {f['solutions']:>10} {f['lost']:>6} "
                  f"{f['duplicate_solutions'] + f['merger_duplicate']:>5} {f['merger_gap']:>5} {f['stream_s']:>9} "
                  f"{f['throughput_per_s']:>10}")
        if r["rc"] != 0 or not r.get("ins"):
            print(f"{r['variant']:<8} FAILED (rc {r['rc']}, see {r['log']})")
    return 0 if all(r["rc"] == 0 and r.get("ins") for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
