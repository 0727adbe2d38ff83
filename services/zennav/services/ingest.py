"""ingest service: a dataset (every loader of zennav.datasets, the built-in simulator ``sim:<kind>``, or a
zennav ``.npz`` dataset file) -> the sensor keys, in one time-ordered sequence.

Wiring table
    publishes  <base>/sensor/stream      stream_start (dataset, NavConfig, InitialState, counts) / stream_end
               <base>/sensor/imu/<id>    imu    (increments, as the dataset gives them: no conversion here), or
                                         imu_batch with --batch N: up to N consecutive samples per message
               <base>/sensor/gnss/<id>   gnss
    waits for  liveliness of --wait-for services (default: ins) and a subscriber on the IMU key
    subscribes <base>/nav/status         to see consumers acknowledge stream_end (--exit-on-end)

Selection and order reproduce zennav.replay.run_replay exactly: IMU samples after the initial-state time up
to config.end_t_ns; GNSS fixes after the initial time, outside the outage windows, not after the last IMU
sample; merged by time, a fix before the IMU sample at or after its time; every sensor message carries the
shared sensor-channel sequence ``cseq`` (see zennav.messages).

Pacing: --speed 1 is real time, --speed 10 ten times faster, --speed 0 (or max) as fast as the consumers
drain: the sensor keys are reliable with blocking congestion control and the consumers' queues are bounded,
so the publisher waits instead of losing samples. --batch N (as fast as possible only) sends up to N
consecutive IMU samples (never across a GNSS fix) as one imu_batch message: one zenoh message and one
validation per N samples, the same samples, cseqs and order (consumers expand it with zennav.messages.samples).
"""
from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from dataclasses import replace

import numpy as np

from zennav import messages as M
from zennav.service import ServiceRunner, add_bus_args


# ------------------------------------------------------------------ dataset sources
def save_npz(ds, path) -> None:
    """Write a Dataset to a zennav .npz file (arrays + config/initial as JSON; no pickle)."""
    from zennav.messages import dataclass_to_map

    g = ds.gnss
    arrays = dict(imu_t_ns=ds.imu.t_ns, imu_dtheta=ds.imu.dtheta, imu_dvel=ds.imu.dvel,
                  gnss_t_ns=g.t_ns, gnss_llh=g.llh, gnss_std_ned=g.std_ned, gnss_fix=g.fix, gnss_num_sats=g.num_sats)
    if g.v_n is not None:
        arrays.update(gnss_v_n=g.v_n, gnss_std_v_n=g.std_v_n)
    meta = dict(name=ds.name, config=dataclass_to_map(ds.config), initial=dataclass_to_map(ds.initial))
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)


def load_npz(path):
    from zennav.nav.types import Dataset, GnssData, ImuData, InitialState, NavConfig

    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        imu = ImuData(z["imu_t_ns"], z["imu_dtheta"], z["imu_dvel"])
        has_v = "gnss_v_n" in z
        gnss = GnssData(z["gnss_t_ns"], z["gnss_llh"], z["gnss_std_ned"], z["gnss_v_n"] if has_v else None,
                        z["gnss_std_v_n"] if has_v else None, z["gnss_fix"], z["gnss_num_sats"])
    return Dataset(meta["name"], imu, gnss, M.map_to_dataclass(NavConfig, meta["config"]),
                   M.map_to_dataclass(InitialState, meta["initial"]))


def _parse_options(items) -> dict:
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        for conv in (int, float):
            try:
                v = conv(v)
                break
            except ValueError:
                pass
        else:
            v = {"true": True, "false": False, "none": None}.get(v.lower(), v)
        out[k] = v
    return out


def load_source(spec: str, options: dict | None = None):
    """'npz:<path>' or anything zennav.datasets.registry.load_dataset accepts (recordings, KF-GINS YAML,
    dataset folders, sim:<kind>)."""
    if spec.startswith("npz:"):
        return load_npz(spec[4:])
    from zennav.datasets.registry import load_dataset

    return load_dataset(spec, **(options or {}))


def sensor_events(ds, outages=(), outage_every=None):
    """(windows, events): events are ("gnss", k) / ("imu", k) in the order the replay feeds the core."""
    from zennav.replay import outage_windows

    t_imu = ds.imu.t_ns
    t0 = int(ds.initial.t_ns)
    k0 = int(np.searchsorted(t_imu, t0, side="right"))
    t_last = int(t_imu[-1] if ds.config.end_t_ns is None else min(t_imu[-1], ds.config.end_t_ns))
    k1 = int(np.searchsorted(t_imu, t_last, side="right"))
    windows = outage_windows(t0, t_last, list(outages), outage_every)
    t_g = ds.gnss.t_ns
    keep = t_g > t0
    if k1 > k0:
        keep &= t_g <= t_imu[k1 - 1]
    else:
        keep[:] = False
    for a, b in windows:
        keep &= ~((t_g >= a) & (t_g < b))
    fixes = np.flatnonzero(keep)
    # merge: a fix goes before the first IMU sample at or after its time
    pos = np.searchsorted(t_imu[k0:k1], t_g[fixes], side="left")
    events = []
    j = 0
    nf = len(fixes)
    for i, k in enumerate(range(k0, k1)):
        while j < nf and pos[j] <= i:
            events.append(("gnss", int(fixes[j])))
            j += 1
        events.append(("imu", k))
    return windows, events


# ------------------------------------------------------------------ service
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-ingest", description=__doc__.split("\n\n")[0])
    p.add_argument("source", nargs="?", default="sim:car", help="dataset spec (default sim:car), or npz:<path>")
    p.add_argument("-o", "--option", action="append", default=[], help="loader option key=value (repeatable)")
    p.add_argument("--speed", default="1", help="pacing: 1 real time, N times faster, 0 or 'max' as fast as possible")
    p.add_argument("--batch", type=int, default=1,
                   help="with --speed 0: up to N consecutive IMU samples per imu_batch message (default 1: imu)")
    p.add_argument("--outage", action="append", default=[], metavar="START:DURATION",
                   help="withhold GNSS for DURATION s starting START s after the initial time (repeatable)")
    p.add_argument("--outage-every", default=None, metavar="PERIOD:DURATION:FIRST", help="periodic outages [s]")
    p.add_argument("--heading-unknown", action="store_true",
                   help="start without the dataset's initial yaw: the ins aligns (as `zennav replay --heading-unknown`)")
    p.add_argument("--adaptive-r", action=argparse.BooleanOptionalAction, default=None,
                   help="innovation-based adaptive GNSS measurement noise (seed 001) on/off; default: the dataset's")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--gnss-id", default="0")
    p.add_argument("--wait-for", default="ins", help="comma-separated services to wait for (liveliness); '' none")
    p.add_argument("--wait-timeout", type=float, default=60.0)
    p.add_argument("--exit-on-end", action=argparse.BooleanOptionalAction, default=True,
                   help="exit after the stream (once the awaited consumers acknowledge its end), else stay up")
    p.add_argument("--ack-timeout", type=float, default=60.0)
    p.add_argument("--linger", type=float, default=1.0,
                   help="seconds to stay connected after the end when no ins acknowledgement is awaited")
    p.add_argument("--start-delay", type=float, default=0.0, help="seconds to wait before streaming")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("ingest", args)
    log = run.log
    k = run.keys
    speed = 0.0 if str(args.speed).lower() in ("0", "max", "inf") else float(args.speed)
    if args.batch < 1 or (args.batch > 1 and speed > 0):
        raise SystemExit("--batch N needs N >= 1, and N > 1 only with --speed 0 (paced samples go one by one)")
    stats = {"imu": 0, "gnss": 0, "cseq": 0}
    run.counters = lambda: dict(stats)
    acks: dict[str, int] = {}
    ack_cv = threading.Condition()

    def on_status(key, msg, recv_ns):
        st = msg.get("stream") or {}
        if st.get("src") == run.bus.src and st.get("done"):
            with ack_cv:
                acks[msg["src"]] = int(st.get("last_cseq", -1))
                ack_cv.notify_all()

    run.bus.subscribe(k.nav_status(), on_status, channel="ring")
    p_stream = run.bus.publisher(k.stream())
    p_imu = run.bus.publisher(k.imu(args.imu_id))
    p_gnss = run.bus.publisher(k.gnss(args.gnss_id))
    run.ready("starting", f"loading {args.source}")
    try:
        ds = load_source(args.source, _parse_options(args.option))
        if args.heading_unknown:  # travels to the ins in stream_start's InitialState
            ds.initial = replace(ds.initial, heading_known=False)
        if args.adaptive_r is not None:  # travels in stream_start's NavConfig
            ds.config = ds.config.with_(adaptive_r=args.adaptive_r)
        outages = [tuple(float(x) for x in o.split(":")) for o in args.outage]
        every = tuple(float(x) for x in args.outage_every.split(":")) if args.outage_every else None
        windows, events = sensor_events(ds, outages, every)
        n_imu = sum(1 for e in events if e[0] == "imu")
        n_gnss = len(events) - n_imu
        log.info("%s: %d IMU samples, %d GNSS fixes, %d outage windows; speed %s", ds.name, n_imu, n_gnss,
                 len(windows), "max" if speed == 0 else speed)
        waits = [s for s in args.wait_for.split(",") if s]
        if waits:
            run.set_state("starting", f"waiting for {','.join(waits)}")
            if not run.bus.wait_alive(waits, args.wait_timeout):
                log.error("gave up waiting for %s (alive: %s)", waits, sorted(run.bus.alive()))
                run.set_state("error", f"{waits} not alive")
                return 2
            deadline = time.monotonic() + args.wait_timeout
            while not (p_imu.matching and p_stream.matching) and time.monotonic() < deadline and not run.stopping:
                time.sleep(0.01)
        if args.start_delay:
            run.wait(args.start_delay)
        if run.stopping:
            return 0
        run.set_state("running", f"streaming {ds.name}")
        last_cseq = _stream(run, ds, events, windows, speed, p_stream, p_imu, p_gnss, stats, args.batch)
        if last_cseq is None:
            return 0
        log.info("stream done: %d IMU, %d GNSS, last cseq %d", stats["imu"], stats["gnss"], last_cseq)
        run.set_state("done", f"streamed {ds.name}: {stats['imu']} IMU, {stats['gnss']} GNSS")
        if waits and "ins" in waits:
            # closing the session drops what is still queued: keep it open until the ins has consumed the end
            with ack_cv:
                ok = ack_cv.wait_for(lambda: any(v == last_cseq for v in acks.values()) or run.stopping,
                                     args.ack_timeout)
            log.info("end of stream %s by ins", "acknowledged" if ok and acks else "NOT acknowledged")
        elif args.exit_on_end:
            run.wait(args.linger)  # no acknowledgement to wait for: give the queues time to drain
        if not args.exit_on_end:
            run.wait()
        return 0
    except KeyboardInterrupt:
        return 0
    except Exception as e:
        log.exception("ingest failed: %s", e)
        run.set_state("error", str(e))
        return 1
    finally:
        run.close()


def _stream(run, ds, events, windows, speed, p_stream, p_imu, p_gnss, stats, batch: int = 1) -> int | None:
    imu, gnss = ds.imu, ds.gnss
    t_imu = imu.t_ns
    cseq = 0
    n_imu = sum(1 for e in events if e[0] == "imu")
    start = M.make("stream_start", int(ds.initial.t_ns), cseq=cseq, dataset=ds.name,
                   config=M.dataclass_to_map(ds.config), initial=M.dataclass_to_map(ds.initial),
                   counts={"imu": n_imu, "gnss": len(events) - n_imu},
                   outages=[[int(a), int(b)] for a, b in windows])
    p_stream.put(start)
    t_list = t_imu.tolist()
    dth = imu.dtheta.tolist()
    dv = imu.dvel.tolist()
    t0_data = int(ds.initial.t_ns)
    wall0 = time.perf_counter()
    prev_t = t0_data
    put_imu, put_gnss = p_imu.put, p_gnss.put
    make = M.make
    held: list[int] = []  # --batch: indices of the IMU samples not yet sent

    def flush() -> None:
        nonlocal prev_t
        if not held:
            return
        ts = [t_list[i] for i in held]
        dts = [b - a for a, b in zip([prev_t] + ts[:-1], ts)]
        put_imu(M.imu_batch_msg(ts, dts, [dth[i] for i in held], [dv[i] for i in held], cseq - len(held) + 1))
        prev_t = ts[-1]
        stats["imu"] += len(held)
        held.clear()

    for n, (kind, idx) in enumerate(events):
        if run.stopping:
            return None
        cseq += 1
        if kind == "imu":
            if batch > 1:
                held.append(idx)
                if len(held) == batch:
                    flush()
                stats["cseq"] = cseq
                continue
            t = t_list[idx]
            if speed > 0:
                due = wall0 + (t - t0_data) / 1e9 / speed
                delay = due - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            put_imu(make("imu", t, cseq=cseq, dt_ns=t - prev_t, dtheta=dth[idx], dvel=dv[idx]))
            prev_t = t
            stats["imu"] += 1
        else:
            if held:  # the samples before this fix go first, in their own batch (cseq order = publish order)
                cseq -= 1
                flush()
                cseq += 1
            put_gnss(M.gnss_msg(gnss.fix_at(idx), cseq))
            stats["gnss"] += 1
        stats["cseq"] = cseq
    flush()
    cseq += 1
    p_stream.put(M.make("stream_end", prev_t, cseq=cseq, counts={"imu": stats["imu"], "gnss": stats["gnss"]},
                        last_cseq=cseq))
    return cseq


if __name__ == "__main__":
    sys.exit(main())
