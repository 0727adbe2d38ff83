"""ingest service: a dataset (every loader of zennav.datasets, the built-in simulator ``sim:<kind>``) -> the
sensor keys, in one time-ordered sequence.

Wiring table
    publishes  <base>/sensor/stream      stream_start (dataset, sensor description, InitialState, counts,
                                         outages) / stream_end; the latest is served to late joiners
               <base>/sensor/imu/<id>    imu    (increments, as the dataset gives them: no conversion here), or
                                         imu_batch with --batch N: up to N consecutive samples per message
               <base>/sensor/gnss/<id>   gnss
               <base>/sensor/dvl/<id>    dvl    (a dataset with a DVL: beams + validity and/or DVL-frame velocity)
               <base>/sensor/depth/<id>  depth  (a dataset with a depth sensor)
    waits for  liveliness of --wait-for services (default: ins) and a subscriber on the IMU key (zenoh's
                                         matching status); with --speed 0 the stream pauses while one of them is
                                         down (--rejoin-timeout); restarted, it recovers what it missed from --cache
    serves     <base>/sensor/history     the messages of its last --cache samples by cseq range (History)
    subscribes <base>/nav/status, <base>/nav/*/status   to see every ins that follows the stream acknowledge
                                         its end before the session closes

The samples and their order are the in-process replay's (zennav.replay.sensor_events), the messages
zennav.stream.stream_messages: every one stamped with the sensor-channel sequence ``cseq``; stream_start
describes the sensors and the run, never filter settings (those are the ins's parameter file).

Pacing: --speed 1 is real time, --speed 10 ten times faster, --speed 0 (or max) as fast as the consumers
drain: the sensor keys are reliable with blocking congestion control and the consumers' queues are bounded,
so the publisher waits instead of losing samples. --batch N (as fast as possible only) sends up to N
consecutive IMU samples (never across a GNSS fix) as one imu_batch message: one zenoh message and one
validation per N samples, the same samples, cseqs and order (consumers expand it with zennav.messages.samples).
"""
from __future__ import annotations

import argparse
import sys
import threading
from collections import Counter
from dataclasses import replace

from zennav.datasets.errors import DataError
from zennav.messages import AID_STREAMS
from zennav.nodes.ingest import History, make_hold, outage_arg, stream, wait_for_consumers, wait_for_end
from zennav.replay import parse_outage, parse_outage_every, sensor_events
from zennav.service import EndAcks, ServiceRunner, add_bus_args, exit_process
from zennav.stream import stream_messages


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-ingest", description=__doc__.split("\n\n")[0])
    p.add_argument("source", nargs="?", default="sim:car", help="dataset spec (default sim:car)")
    p.add_argument("-o", "--option", action="append", default=[], help="loader option key=value (repeatable)")
    p.add_argument("--speed", default="1", help="pacing: 1 real time, N times faster, 0 or 'max' as fast as possible")
    p.add_argument("--batch", type=int, default=1,
                   help="with --speed 0: up to N consecutive IMU samples per imu_batch message (default 1: imu)")
    p.add_argument("--outage", action="append", default=[], metavar="START:DURATION",
                   type=outage_arg(parse_outage),
                   help="withhold GNSS for DURATION s starting START s after the initial time (repeatable)")
    p.add_argument("--outage-every", default=None, metavar="PERIOD:DURATION[:FIRST]",
                   type=outage_arg(parse_outage_every),
                   help="withhold GNSS for DURATION s every PERIOD s, the first at FIRST (default PERIOD-DURATION)")
    p.add_argument("--heading-unknown", action="store_true",
                   help="start without the dataset's initial yaw: the ins aligns (`zennav replay --heading-unknown`)")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--gnss-id", default="0")
    p.add_argument("--dvl-id", default="0")
    p.add_argument("--depth-id", default="0")
    p.add_argument("--wait-for", default="ins", help="comma-separated services to wait for (liveliness); '' none")
    p.add_argument("--wait-timeout", type=float, default=60.0)
    p.add_argument("--exit-on-end", action=argparse.BooleanOptionalAction, default=True,
                   help="exit after the stream (once the awaited consumers acknowledge its end), else stay up")
    p.add_argument("--ack-timeout", type=float, default=60.0,
                   help="[s] to wait for the end's acknowledgement while no ins that follows the stream is alive "
                        "(a live one, however slow, is waited for)")
    p.add_argument("--linger", type=float, default=1.0,
                   help="seconds to stay connected after the end when no ins acknowledgement is awaited")
    p.add_argument("--start-delay", type=float, default=0.0, help="seconds to wait before streaming")
    p.add_argument("--gnss-receiver", default=None, metavar="LINK",
                   help="GNSS from a live NMEA/UBX receiver instead of the dataset's: serial:PORT[:BAUD], "
                        "tcp:HOST:PORT or file:PATH (zennav.receivers; the IMU still comes from the dataset)")
    p.add_argument("--gnss-latency", type=float, default=0.5,
                   help="[s] how long an IMU sample waits for the receiver's fixes up to its time")
    p.add_argument("--gnss-silence", type=float, default=2.0, help="[s] receiver silence that is counted and logged")
    p.add_argument("--cache", type=int, default=20000,
                   help="sensor samples (cseqs) kept for consumers that recover what they missed: served by cseq "
                        "range (sensor/history), and per key by zenoh's advanced publisher (a --lockstep ins; the "
                        "IMU key's in messages of --batch samples); 0: none")
    p.add_argument("--max-lead", type=int, default=10000,
                   help="with --speed 0: stay at most this many messages ahead of the slowest ins following the "
                        "stream (its nav status), so that what a crashed ins had queued is still in the --cache; "
                        "0: no limit")
    p.add_argument("--rejoin-timeout", type=float, default=30.0,
                   help="with --speed 0: [s] to pause the stream while an awaited service is down (restarting), "
                        "then stream on without it")
    p.add_argument("--stop-timeout", type=float, default=3.0,
                   help="[s] after SIGTERM/SIGINT to wait for a publish blocked by a stalled consumer, then exit "
                        "without draining")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("ingest", args)
    log = run.log
    k = run.keys
    speed = 0.0 if str(args.speed).lower() in ("0", "max", "inf") else float(args.speed)
    if args.batch < 1 or (args.batch > 1 and speed > 0):
        raise SystemExit("--batch N needs N >= 1, and N > 1 only with --speed 0 (paced samples go one by one)")
    stats = {"imu": 0, "gnss": 0, "cseq": 0, "paused_s": 0}
    run.counters = lambda: dict(stats)
    acks = EndAcks(run.bus)  # every ins following the stream, and its acknowledgement of the end

    def publisher(key: str, per: int = 1):  # its cache: the messages (of `per` samples) of the last --cache samples
        return run.bus.cached_publisher(key, -(-args.cache // per)) if args.cache > 0 else run.bus.publisher(key)

    pubs = {"stream": publisher(k.stream()), "imu": publisher(k.imu(args.imu_id), args.batch),
            "gnss": publisher(k.gnss(args.gnss_id))}
    aid_keys = {"dvl": k.dvl(args.dvl_id), "depth": k.depth(args.depth_id)}  # declared when the dataset has them
    run.ready("starting", f"loading {args.source}")
    result: list[int] = []

    def work() -> None:
        result.append(_run(run, args, speed, acks, pubs, lambda kind: publisher(aid_keys[kind]), stats))

    worker = threading.Thread(target=work, name="ingest", daemon=True)
    worker.start()
    # the main thread only waits: a publish blocked by a stalled consumer cannot delay the reaction to SIGTERM
    while worker.is_alive() and not run.wait(0.2):
        pass
    worker.join(args.stop_timeout if run.stopping else None)
    if worker.is_alive():
        log.error("stopped while a publish was blocked by a stalled consumer: exiting without draining")
        exit_process(1)
    run.close()
    exit_process(result[0] if result else 1)  # not through the interpreter's finalization (exit_process)


def _run(run, args, speed: float, acks: EndAcks, pubs: dict, aid_publisher, stats: dict) -> int:
    """Load, wait for the consumers, stream, wait for the end's acknowledgement; the exit code. pubs: the stream,
    imu and gnss publishers; aid_publisher(kind): a publisher of an aid stream's key (zennav.messages.AID_STREAMS)."""
    log = run.log
    try:
        from zennav.datasets.registry import load_dataset, parse_loader_options

        ds = load_dataset(args.source, **parse_loader_options(args.option))
        if args.heading_unknown:  # travels to the ins in stream_start's InitialState
            ds.initial = replace(ds.initial, heading_known=False)
        windows, events = sensor_events(ds, args.outage, args.outage_every)
        receiver = None
        if args.gnss_receiver:  # the dataset's GNSS replaced by a live receiver's (zennav.receivers.live)
            from zennav.receivers.live import live_messages
            from zennav.receivers.receiver import GnssReceiver

            receiver = GnssReceiver(args.gnss_receiver, int(ds.initial.t_ns), silence_s=args.gnss_silence,
                                    log=log).start()
            run.counters = lambda: {**stats, **{f"receiver_{k}": v for k, v in receiver.counts.items()}}
        n = Counter(events.counts())
        aids = [a for a in AID_STREAMS if getattr(ds, a) is not None]
        if aids and receiver is not None:
            raise ValueError(f"--gnss-receiver streams IMU and GNSS only: {ds.name} has {', '.join(aids)}")
        for kind in aids:
            pubs[kind] = aid_publisher(kind)
            stats[kind] = 0
        log.info("%s: %d IMU samples, %d GNSS fixes%s, %d outage windows; speed %s", ds.name, n["imu"], n["gnss"],
                 "".join(f", {n[a]} {a} samples" for a in aids), len(windows), "max" if speed == 0 else speed)
        waits = [s for s in args.wait_for.split(",") if s]
        if not wait_for_consumers(run, waits, (pubs["imu"], pubs["stream"]), args.wait_timeout):
            return 2
        if args.start_delay:
            run.wait(args.start_delay)
        if run.stopping:
            return 0
        run.set_state("running", f"streaming {ds.name}")
        hold = make_hold(run, waits, args.rejoin_timeout, args.max_lead, stats) if speed == 0 and waits else None
        msgs = (stream_messages(ds, windows, events, args.batch) if receiver is None else
                live_messages(ds, windows, events, receiver, speed, args.gnss_latency, lambda: run.stopping))
        last_cseq = stream(run, msgs, int(ds.initial.t_ns), speed if receiver is None else 0.0, pubs, stats, hold,
                           History(run.bus, run.keys.sensor_history(), args.cache) if args.cache > 0 else None)
        if receiver is not None:
            receiver.stop()
            log.info("receiver %s: %s", args.gnss_receiver, receiver.counts)
        if last_cseq is None:
            return 0
        done = ", ".join(f"{stats[kind]} {kind.upper() if kind in ('imu', 'gnss') else kind}"
                         for kind in ("imu", "gnss", *aids))
        log.info("stream done: %s, last cseq %d", done, last_cseq)
        run.set_state("done", f"streamed {ds.name}: {done}")
        wait_for_end(run, acks, "ins" in waits, last_cseq, args.ack_timeout, args.linger, args.exit_on_end)
        return 0
    except (DataError, OSError, ValueError) as e:  # bad input: one line, no traceback
        log.error("cannot stream %s: %s", args.source, e)
        run.set_state("error", str(e))
        return 2
    except Exception as e:
        log.exception("ingest failed: %s", e)
        run.set_state("error", str(e))
        return 1


if __name__ == "__main__":
    sys.exit(main())
