"""monitor service / `zennav monitor`: live health of one vehicle's key space (core: zennav.nodes.monitor).

Wiring table
    subscribes <base>/**                 every sample (ring channel: a slow monitor never slows the pipeline)
               liveliness <base>/@alive/*  which services are up
    queries    svc/*/status, nav/status, attitude, learn/model/*   latest values at start (late joiner)
    publishes  svc/<name>/status         its own heartbeat (when run as a service)

Health per service (zennav.nodes.monitor: down, error, degraded with the reason, running) is judged here from
liveliness, status age (--stale) and whether a service's work counter moves while its input flows (--stall).

Drops are seen from the monitor: if the monitor itself falls behind by more than its ring capacity, the
samples it skipped count as drops too.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

from zennav.nodes.monitor import MonitorState, format_table
from zennav.service import ArgumentParser, ServiceRunner, add_bus_args


def _query_latest(run, state: MonitorState, selectors) -> None:
    """Late joiner: the latest values served by the publishers' queryables, fed like live samples."""
    for sel in selectors:
        try:
            for key, payload in run.bus.get(sel, timeout=1.0):
                state.on_sample(key, payload, time.time_ns())
        except Exception as e:
            run.log.debug("query %s failed: %s", sel, e)


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog="zennav-monitor", description="zennav monitor: live health of the key space")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--once", action="store_true", help="observe for --duration seconds, print once and exit")
    p.add_argument("--duration", type=float, default=2.0, help="observation time with --once [s]")
    p.add_argument("--interval", type=float, default=1.0, help="refresh period [s]")
    p.add_argument("--stall", type=float, default=10.0, help="a live service whose input flows this long [s] while "
                   "its work counter stands still is shown degraded")
    p.add_argument("--stale", type=float, default=5.0, help="a live service without a status this long [s] is "
                   "shown degraded")
    p.add_argument("--ring", type=int, default=65536, help="receive ring capacity")
    p.add_argument("--prometheus", type=int, default=None, metavar="PORT",
                   help="expose the snapshot as Prometheus metrics on http://--prometheus-addr:PORT/metrics")
    p.add_argument("--prometheus-addr", default="127.0.0.1", help="address of the metrics endpoint")
    p.add_argument("--announce", action=argparse.BooleanOptionalAction, default=None,
                   help="declare a liveliness token (default: yes when running continuously, no with --once)")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    announce = (not args.once) if args.announce is None else args.announce
    if args.once and args.name is None:
        args.name = f"monitor-{os.getpid()}"
    run = ServiceRunner("monitor", args)
    k = run.keys
    state = MonitorState(k, stall_s=args.stall, stale_s=args.stale)
    run.bus.subscribe(k.all(), state.on_sample, validate=False, channel="ring", capacity=args.ring, name="all")
    run.bus.watch_alive(state.on_alive)
    _query_latest(run, state, (k.svc_status(), k.nav_status(), k.attitude(), k.learn_model()))
    run.counters = lambda: {"keys": len(state.per_key)}
    exporter = None
    if args.prometheus is not None:  # zennav.prometheus: the latest snapshot at /metrics
        from zennav.prometheus import serve

        exporter = serve(args.prometheus, args.prometheus_addr)
    try:
        if announce:
            run.ready("running", "watching " + k.all())
        if args.once:
            run.wait(args.duration)
            # a peer found by gossip after the first queries went out: ask again for what is still missing
            # (only where nothing came, so no sample is seen twice)
            missing = [sel for sel, have in ((k.nav_status(), state.nav.get("t_ns")), (k.attitude(), state.attitude),
                                             (k.learn_model(), state.models)) if not have]
            missing += [k.svc_status(s) for s, up in sorted(state.alive.items()) if up and s not in state.services]
            _query_latest(run, state, missing)
            snap = state.snapshot()
            snap["window_s"] = args.duration
            print(json.dumps(snap, indent=1) if args.json else format_table(snap), flush=True)
            return 0
        state.snapshot()
        while not run.wait(args.interval):
            snap = state.snapshot()
            if exporter is not None:
                exporter.update(snap)
            if args.json:
                print(json.dumps(snap), flush=True)
            else:
                out = format_table(snap)
                if sys.stdout.isatty():
                    out = "\x1b[2J\x1b[H" + out
                print(out, flush=True)
        return 0
    finally:
        run.close()


if __name__ == "__main__":
    sys.exit(main())
