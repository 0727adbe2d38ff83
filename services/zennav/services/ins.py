"""ins service: the navigation engine (zennav.nav.navigator.Navigator) on the bus.

Wiring table
    subscribes <base>/sensor/**          the sensor stream, through zennav.stream.StreamFollower (one stream,
                                         cseq order, late join): stream_start -> Navigator(the stream's sensor
                                         description + the --params filter settings, its initial state);
                                         imu -> on_imu; gnss -> on_gnss; dvl, depth -> on_aid right after
                                         the IMU sample that reaches their time; stream_end -> final status
               <base>/attitude           --attitude-alignment: at-rest roll/pitch in coarse alignment
               <base>/learn/correction   --learning: the predictor's answers, fused (zennav.learn.link)
    publishes  <nav>/solution            one per IMU sample (every --solution-every-th; --solution-batch: those of
                                         a stretch of an imu_batch in one nav_solution_batch)
               <nav>/aid/<source>        every aid source's status record (gnss_pos, gnss_vel, dvl, depth, ...)
               <nav>/status              engine status, stream progress, drops: every second of data time, on
                                         GNSS or alignment state changes, at the stream end (its acknowledgement)
               <base>/learn/samples      --learning: the engine's training samples (GNSS good, converged)
               <base>/learn/query        --learning: the engine's prediction requests (GNSS lost)
    queries    <base>/sensor/history     what the stream waits for (missed while down, lost in transit), from the
                                         ingest's last messages (zennav.stream.Backfill; --lockstep: zenoh's
                                         advanced subscriber fetches the ingest's cache instead)
    With --checkpoint a restarted ins resumes the engine where it was (zennav.checkpoint); the solution and query
    publishers keep a cache for subscribers that recover what they missed (a router restart, a restarted
    predictor).
    <nav> is <base>/nav, or <base>/nav/<prefix> with --nav-prefix (a second ins beside the first on one stream).
    With --compiled the IMU samples of an imu_batch message run through the engine's block loop compiled by numba
    (zennav.nodes.ins; the same solutions; numba costs resident memory, benchmarks/memory.py).

The core is zennav.nodes.ins.InsNode. Filter settings come from the parameter file (--params, default
deploy/ins.yaml, zennav.params), never from the stream: followed from its start, the solution is the in-process
replay's (zennav replay reads the same file) bit for bit. Learning (--learning; off by default): answers arrive
asynchronously, so a learning run is bit-reproducible only with --lockstep (zennav.learn.link).
"""
from __future__ import annotations

import argparse
import math
import sys

from zennav import messages as M
from zennav.checkpoint import Checkpointer
from zennav.learn.link import LearningLink
from zennav.nodes.ingest import fetch_history
from zennav.nodes.ins import InsNode
from zennav.params import ParamError
from zennav.replay_cli import filter_settings
from zennav.service import ServiceRunner, add_bus_args
from zennav.stream import Backfill, start_ticker

LOCKSTEP_QUEUE = 1 << 24  # sensor messages buffered with --lockstep (a replay's whole stream)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-ins", description="zennav ins service: GNSS/INS navigation engine")
    p.add_argument("--params", default=None, help="filter parameter file, human units (default deploy/ins.yaml)")
    p.add_argument("--profile", default=None,
                   help="a vehicle profile of the parameter file (car, auv, ...; none) that sets the vehicle "
                        "constraints, as `zennav replay --profile` (default: the file's own switches)")
    p.add_argument("--nav-prefix", default="", help="publish on <base>/nav/<prefix>/... (a second ins)")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--gnss-id", default="0")
    p.add_argument("--dvl-id", default="0")
    p.add_argument("--depth-id", default="0")
    p.add_argument("--solution-every", type=int, default=1, help="publish every N-th solution")
    p.add_argument("--queue", type=int, default=1024,
                   help="sensor queue capacity in messages (back-pressure beyond; every queued message holds zenoh's "
                        "receive buffer: 8192 cost about 100 MB more resident memory than 1024, benchmarks/memory.py; "
                        "a restarted ins's backfill does not go through it)")
    p.add_argument("--learning", action="store_true",
                   help="learning loop: publish learn/samples and learn/query, fuse learn/correction (off: the "
                        "core runs exactly as the in-process replay)")
    p.add_argument("--learn-targets", default="body_velocity",
                   help="comma-separated target variants to publish samples and queries for (position, velocity, "
                        "drift, body_velocity, dvl_beam; zennav.nav.learning)")
    p.add_argument("--lockstep", action="store_true",
                   help="wait for the answer to each learn/query before the next sensor sample (a replay of a "
                        "recording, with the predictor's --lockstep: the in-process replay's learned corrections, "
                        "bit for bit; not for live vehicles)")
    p.add_argument("--lockstep-timeout", type=float, default=300.0,
                   help="longest wait [s] for the answers to one sample's queries (counted: lockstep_timeouts)")
    p.add_argument("--compiled", action="store_true",
                   help="run the IMU samples of each imu_batch message through the engine's block loop compiled by "
                        "numba (the same solutions; the engine's CPU per sample about 15x less, the whole ins's about "
                        "2.7x with a solution per sample, benchmarks/bus_throughput.py; numba and the kernels add "
                        "about 115 MB resident memory, benchmarks/memory.py; compiled once per machine, loaded in "
                        "about a second; with --learning the loop runs from one learning event to the next: a fix, "
                        "a query; the drift target's shadow INSs take every sample step-wise)")
    p.add_argument("--solution-batch", type=int, nargs="?", const=50, default=0, metavar="N",
                   help="with --compiled: the solutions of each stretch of an imu_batch the block loop runs at once "
                        "in nav_solution_batch messages of at most N (default 50) (the same solutions; zennav.bus "
                        "subscribers receive them one by one); the recovery cache then keeps --recovery-cache / N "
                        "messages, at most --recovery-cache solutions")
    p.add_argument("--attitude-alignment", action="store_true",
                   help="take roll/pitch from the attitude service during coarse alignment (heading unknown)")
    p.add_argument("--attitude-tilt-std", type=float, default=1.0,
                   help="1-sigma [deg] credited to the attitude service's at-rest roll/pitch for coarse alignment")
    p.add_argument("--checkpoint", default=None, metavar="FILE",
                   help="checkpoint the engine's whole state to FILE (atomically) and resume from it after a "
                        "restart (zennav.checkpoint; default: none)")
    p.add_argument("--checkpoint-every", type=float, default=10.0, help="[s of data] between checkpoints")
    p.add_argument("--takeover-after", type=float, default=10.0,
                   help="[s] another source's stream_start replaces the live stream only after this long without a "
                        "message of it (inf: only after its end); refused takeovers are counted takeover_refused")
    p.add_argument("--bridge-max", type=float, default=0.5,
                   help="[s] lost IMU samples up to this long are bridged (rates held); longer: re-align")
    p.add_argument("--recovery-cache", type=int, default=12000,
                   help="solutions (and queries) kept for subscribers that recover what they missed (router "
                        "restart); 0: plain publishers")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.solution_batch < 0 or (args.solution_batch and not args.compiled):
        raise SystemExit("zennav-ins: --solution-batch N needs N >= 0 and --compiled (the block loop's rows)")
    run = ServiceRunner("ins", args)
    try:
        filter_params = filter_settings("", args.params, args.profile, None)
        out = M.Keys(run.keys.vehicle, args.nav_prefix)
    except (ParamError, ValueError) as e:
        return run.fail(f"bad ins parameters: {e}")
    import zennav.nav.navigator  # noqa: F401  (import the core, scipy included, before announcing)

    if args.compiled:  # load (or compile, once per machine) the block loop before announcing
        from zennav.nav import kernels

        kernels.compiled()
    k, bus = run.keys, run.bus
    cache, rows_max = args.recovery_cache, args.solution_batch
    depth = -(-cache // rows_max) if rows_max else cache  # [messages] the solution cache: at most `cache` solutions
    pubs = {"solution": bus.cached_publisher(out.nav_solution(), depth) if cache > 0 else
            bus.publisher(out.nav_solution()), "status": bus.publisher(out.nav_status())}

    def publish(kind: str, msg: dict) -> None:
        (bus.publisher(out.nav_aid(msg["source"])) if kind == "aid" else pubs[kind]).put(msg)

    pack, put_packed = M.SolutionPacker().pack, pubs["solution"].put_packed

    def put_solution(nav, t_ns: int, row, std: list, cseq: int, pub_ns: int) -> None:  # packed straight to bytes
        put_packed(pack, t_ns, row, std, nav.gyro_bias, nav.accel_bias, nav.gnss_state, cseq, pub_ns)

    def put_batch(nav, t_ns, rows, std, cseq, pub_ns) -> None:  # rows_max a message at most
        for a in range(0, len(t_ns), rows_max):
            b = slice(a, a + rows_max)
            pubs["solution"].put(M.nav_solution_batch_msg(nav, t_ns[b], rows[b], std[b], cseq[b], pub_ns[b]))

    learn = None
    if args.learning:
        from zennav.nav.learning import TARGETS

        targets = [t.strip() for t in args.learn_targets.split(",") if t.strip()]
        if not targets or not set(targets) <= set(TARGETS):
            raise SystemExit(f"--learn-targets: choose from {TARGETS}")
        pubs["sample"] = bus.publisher(k.learn_samples())
        # cached: a restarted predictor fetches the queries it missed (a lockstep ins waits for their answers)
        pubs["query"] = bus.cached_publisher(k.learn_query(), 64) if cache > 0 else bus.publisher(k.learn_query())
        # lockstep: the sensor callback waits on a condition of the serial bus's callback lock, which the
        # correction callback needs (zennav.learn.link)
        from zennav.nav.types import NavConfig

        max_age_s = NavConfig().with_(**filter_params).learn_answer_max_age_s  # queries unanswered past it expire
        learn = LearningLink(publish, run.log, targets, max_age_s,
                             lockstep_timeout_s=args.lockstep_timeout if args.lockstep else 0.0,
                             lock=bus.callback_lock)
    node = InsNode(publish, run.log, filter_params, args.solution_every, on_state=lambda d: setattr(run, "detail", d),
                   bus_rejected=bus.rejected_counts, learning=learn, fetch_start=run.stream_start_of,
                   imu_key=k.imu(args.imu_id), gnss_key=k.gnss(args.gnss_id),
                   checkpoint=Checkpointer(args.checkpoint, args.checkpoint_every), bridge_max_s=args.bridge_max,
                   takeover_after_s=args.takeover_after,
                   aid_keys={"dvl": k.dvl(args.dvl_id), "depth": k.depth(args.depth_id)},
                   block_loop="compiled" if args.compiled else None, put_solution=put_solution,
                   put_batch=put_batch if args.solution_batch else None)
    run.counters = lambda: {**node.counters(), "missed": sum(bus.missed.values())}
    on_sensor = lambda key, msg, recv_ns: node.on_sensor(key, msg)  # noqa: E731
    backfill = None
    if args.lockstep:
        # the ins waits for answers (a fit can take minutes) while the ingest streams on; its samples queue here
        # without bound instead of holding the ingest's blocking push past zenoh's wait_before_close. A restarted
        # ins recovers what it missed from the publishers' caches (zenoh's history: a drained replay), not by a
        # backfill (zennav.stream.Backfill: not while a sample waits releasing the lock)
        bus.recovering_subscribe(k.sensors(), on_sensor, channel="fifo", capacity=LOCKSTEP_QUEUE, name="sensors")
    else:  # what it lacks (missed while down, lost in transit) is fetched from the ingest's history
        bus.subscribe(k.sensors(), on_sensor, channel="fifo", capacity=args.queue, name="sensors")
        backfill = Backfill(node.follower, lambda first, last: fetch_history(bus, k.sensor_history(), first, last))
    start_ticker(node.follower, bus.callback_lock, lambda: run.stopping, backfill=backfill)
    if args.attitude_alignment:
        tilt_std = math.radians(args.attitude_tilt_std)
        bus.subscribe(k.attitude(), lambda key, msg, recv_ns: node.on_attitude(msg, tilt_std), channel="ring",
                      capacity=16, name="attitude")
    bus.subscribe(k.learn_correction(), lambda key, msg, recv_ns: node.on_correction(key, msg), channel="fifo",
                  name="correction")
    return run.serve("running", f"waiting for a sensor stream; filters from {args.params or 'deploy/ins.yaml'}")


if __name__ == "__main__":
    sys.exit(main())
