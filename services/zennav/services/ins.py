"""ins service: the navigation engine (zennav.nav.navigator.Navigator) on the bus.

Wiring table
    subscribes <base>/sensor/**          the sensor stream, through zennav.stream.StreamFollower (one stream,
                                         cseq order, late join): stream_start -> Navigator(the stream's sensor
                                         description + the --params filter settings, its initial state);
                                         imu -> on_imu; gnss -> on_gnss; stream_end -> final status
               <base>/attitude           --attitude-alignment: at-rest roll/pitch in coarse alignment
               <base>/learn/correction   --learning: the predictor's answers, fused (zennav.learn.link)
    publishes  <nav>/solution            one per IMU sample (every --solution-every-th)
               <nav>/aid/<source>        every aid source's status record (gnss_pos, gnss_vel, learned ...)
               <nav>/status              engine status, stream progress, drops: every second of data time, on
                                         GNSS or alignment state changes, at the stream end (its acknowledgement)
               <base>/learn/samples      --learning: the engine's training samples (GNSS good, converged)
               <base>/learn/query        --learning: the engine's prediction requests (GNSS lost)
    <nav> is <base>/nav, or <base>/nav/<prefix> with --nav-prefix (a second ins beside the first on one stream).

Filter settings come from the parameter file (--params, default deploy/ins.yaml, zennav.params), never from the
stream; followed from its start, the solution is the in-process replay's (zennav replay, same file) bit for bit.
A late joiner starts in coarse alignment at its first sample (zennav.stream). Learning (--learning; off by
default): the engine emits samples and queries (NavConfig.learning), LearningLink publishes them and fuses the
answers; answers arrive asynchronously, so a learning run is bit-reproducible only with --lockstep.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace

from zennav import messages as M
from zennav.learn.link import LearningLink
from zennav.params import ParamError, load_filter_params, nav_config
from zennav.service import ServiceRunner, add_bus_args
from zennav.stream import StreamFollower


class InsNode:
    """The transport-free ins (testable without zenoh): feed it validated sensor messages with
    ``on_sensor(key, msg)``; it calls ``publish(kind, msg)`` with kind solution/aid/status. filter_params: SI
    settings of a parameter file (zennav.params.load_filter_params; {}: NavConfig's defaults); imu_key /
    gnss_key: the sensors it navigates with (None: any)."""

    def __init__(self, publish, log, filter_params: dict | None = None, solution_every: int = 1,
                 status_period_ns: int = 1_000_000_000, on_state=None, bus_rejected=None,
                 learning: LearningLink | None = None, fetch_start=None, imu_key=None, gnss_key=None):
        self.publish, self.log = publish, log
        self.filter_params = dict(filter_params or {})
        self.learn = learning  # None: learning off (the default; the engine runs exactly as in the replay)
        self.bus_rejected = bus_rejected or dict
        self.on_state = on_state or (lambda detail: None)
        self.solution_every = max(1, int(solution_every))
        self.status_period_ns = status_period_ns
        self.keys = {"imu": imu_key, "gnss": gnss_key}
        self.follower = StreamFollower(self._start, self._sample, self._end, fetch_start, log)
        self.on_sensor = self.follower.on_message
        self.nav = None
        self.imu_count = self.gnss_count = self.sol_count = self.corrections = self.attitude_taken = 0
        self.wall_s, self._wall0, self._next_status_t, self._states = 0.0, 0.0, 0, (None, None)

    def _start(self, start: dict, join: dict | None) -> None:
        from zennav.nav.navigator import Navigator
        from zennav.nav.types import InitialState

        config = nav_config(start["config"], self.filter_params)
        initial = M.map_to_dataclass(InitialState, start["initial"])
        if join is not None:  # late join: an ins switched on in motion, at the first sample's start time
            initial = replace(initial, t_ns=join["t_ns"] - join["dt_ns"], heading_known=False)
        if self.learn is not None:
            config = config.with_(learning=True)
            self.learn.reset()
        self.nav = Navigator(config, initial)
        self.imu_count = self.gnss_count = self.sol_count = 0
        self._next_status_t = int(initial.t_ns) + self.status_period_ns
        self._states = (self.nav.gnss_state, self.nav.align_state)
        self._wall0, self.wall_s = time.perf_counter(), 0.0
        self.log.info("stream %s from %s%s: %s IMU, %s GNSS expected", start["dataset"], start["src"],
                      " (joined late)" if join else "", start["counts"].get("imu"), start["counts"].get("gnss"))
        self.on_state(f"navigating stream {start['dataset']} from {start['src']}")

    def _sample(self, key: str, msg: dict) -> None:
        schema, nav = msg["schema"], self.nav
        if self.keys[schema] not in (None, key):
            return
        if schema == "gnss":
            self.gnss_count += 1
            nav.on_gnss(M.gnss_fix(msg))
            self._reports()
            return
        self.imu_count += 1
        ok = nav.on_imu(msg["t_ns"], msg["dtheta"], msg["dvel"])  # False: rejected by the engine (counted)
        self._reports()
        if self.learn is not None:
            self.learn.after_imu(nav)
        if ok:
            self.sol_count += 1
            if self.sol_count % self.solution_every == 0:
                self.publish("solution", M.nav_solution_msg_of(nav, msg["cseq"], msg["pub_ns"]))
        states = (nav.gnss_state, nav.align_state)
        if states != self._states or msg["t_ns"] >= self._next_status_t:
            self._states = states
            while self._next_status_t <= msg["t_ns"]:
                self._next_status_t += self.status_period_ns
            self.publish("status", self.status_msg())

    def _end(self, msg: dict) -> None:
        self.wall_s = time.perf_counter() - self._wall0
        c = msg["counts"]
        complete = (c.get("imu", 0), c.get("gnss", 0)) == (self.imu_count, self.gnss_count)
        (self.log.info if complete or self.follower.counts["late_join"] else self.log.error)(
            "end of stream %s: consumed %d/%d IMU, %d/%d GNSS in %.2f s; merger %s", self.follower.dataset,
            self.imu_count, c.get("imu", 0), self.gnss_count, c.get("gnss", 0), self.wall_s,
            self.follower.status())
        self.publish("status", self.status_msg())
        self.on_state(f"stream {self.follower.dataset} done: {self.imu_count} IMU, {self.gnss_count} GNSS, "
                      f"{self.sol_count} solutions")

    def on_attitude(self, msg: dict, tilt_std_rad: float) -> bool:
        """attitude message -> roll/pitch for coarse alignment (Navigator.on_attitude), only while the heading is
        unknown, the vehicle stands still (GNSS speed below align_still_speed_mps) and the accelerometer is not
        rejected (weight 1): under sustained acceleration the accelerometer tilt is off by about atan(a/g).
        Returns whether taken. The arrival time is not part of the sensor sequence: not bit-reproducible."""
        nav = self.nav
        if nav is None or nav.align_state != "coarse" or msg["weight"] < 1.0 \
                or math.hypot(nav.state.vn, nav.state.ve) > nav.config.align_still_speed_mps:
            return False
        taken = bool(nav.on_attitude(msg["t_ns"], msg["euler"][0], msg["euler"][1], tilt_std_rad))
        self.attitude_taken += taken
        return taken

    def _reports(self) -> None:
        for rep in self.nav.pop_reports():
            self.publish("aid", M.aid_report_msg(rep))

    def on_correction(self, key: str, msg: dict) -> None:
        """A learn/correction message (the answer to one of our queries): fused with --learning, else ignored."""
        self.corrections += 1
        if self.learn is None or self.nav is None:
            if self.corrections == 1:
                self.log.warning("learn/correction received but ignored: %s", "learning is off (start the ins "
                                 "with --learning)" if self.learn is None else "no stream yet")
            return
        self.learn.on_correction(self.nav, msg)
        self._reports()

    def status_msg(self) -> dict:
        nav = self.nav
        return M.nav_status_msg(
            nav.t_ns if nav is not None else 0, nav.status() if nav is not None else None,
            {**self.follower.status(), "solutions": self.sol_count, "wall_s": self.wall_s},
            {**self.bus_rejected(), **self.follower.counts}, self.imu_count, self.gnss_count,
            {"corrections_received": self.corrections,
             **(self.learn.status() if self.learn is not None else {"learning": False, "corrections_fused": 0})})

    def counters(self) -> dict:
        return {"imu": self.imu_count, "gnss": self.gnss_count, "solutions": self.sol_count,
                **{f"drop_{a}": b for a, b in self.follower.counts.items()},
                **({f"learn_{a}": b for a, b in dict(self.learn.counts).items()} if self.learn is not None else {})}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-ins", description="zennav ins service: GNSS/INS navigation engine")
    p.add_argument("--params", default=None, help="filter parameter file, human units (default deploy/ins.yaml)")
    p.add_argument("--nav-prefix", default="", help="publish on <base>/nav/<prefix>/... (a second ins)")
    p.add_argument("--imu-id", default="0")
    p.add_argument("--gnss-id", default="0")
    p.add_argument("--solution-every", type=int, default=1, help="publish every N-th solution")
    p.add_argument("--queue", type=int, default=8192, help="sensor queue capacity (back-pressure beyond)")
    p.add_argument("--learning", action="store_true",
                   help="learning loop: publish learn/samples and learn/query, fuse learn/correction (off: the "
                        "core runs exactly as the in-process replay)")
    p.add_argument("--learn-targets", default="body_velocity",
                   help="comma-separated target variants to publish samples and queries for (position, velocity, "
                        "drift, body_velocity; zennav.nav.learning)")
    p.add_argument("--correction-max-age", type=float, default=1.0,
                   help="fuse an answer only if its query is at most this old [s of data time]")
    p.add_argument("--lockstep", action="store_true",
                   help="wait for the answer to each learn/query before the next sensor sample (a replay of a "
                        "recording, with the predictor's --lockstep: the in-process replay's learned corrections, "
                        "bit for bit; not for live vehicles)")
    p.add_argument("--lockstep-timeout", type=float, default=300.0,
                   help="longest wait [s] for the answers to one sample's queries (counted: lockstep_timeouts)")
    p.add_argument("--attitude-alignment", action="store_true",
                   help="take roll/pitch from the attitude service during coarse alignment (heading unknown)")
    p.add_argument("--attitude-tilt-std", type=float, default=1.0,
                   help="1-sigma [deg] credited to the attitude service's at-rest roll/pitch for coarse alignment")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("ins", args)
    try:
        filter_params, out = load_filter_params(args.params), M.Keys(run.keys.vehicle, args.nav_prefix)
    except (ParamError, ValueError) as e:
        return run.fail(f"bad ins parameters: {e}")
    import zennav.nav.navigator  # noqa: F401  (import the core, scipy included, before announcing)
    k, bus = run.keys, run.bus
    pubs = {"solution": bus.publisher(out.nav_solution()), "status": bus.publisher(out.nav_status())}

    def publish(kind: str, msg: dict) -> None:
        (bus.publisher(out.nav_aid(msg["source"])) if kind == "aid" else pubs[kind]).put(msg)

    learn = None
    if args.learning:
        from zennav.nav.learning import TARGETS

        targets = [t.strip() for t in args.learn_targets.split(",") if t.strip()]
        if not targets or not set(targets) <= set(TARGETS):
            raise SystemExit(f"--learn-targets: choose from {TARGETS}")
        pubs["sample"] = bus.publisher(k.learn_samples())
        pubs["query"] = bus.publisher(k.learn_query())
        # lockstep: the sensor callback waits on a condition of the serial bus's callback lock, which the
        # correction callback needs (zennav.learn.link)
        learn = LearningLink(publish, run.log, targets, args.correction_max_age,
                             lockstep_timeout_s=args.lockstep_timeout if args.lockstep else 0.0, lock=bus._cb_lock)
    node = InsNode(publish, run.log, filter_params, args.solution_every, on_state=lambda d: setattr(run, "detail", d),
                   bus_rejected=bus.rejected_counts, learning=learn, fetch_start=run.stream_start_of,
                   imu_key=k.imu(args.imu_id), gnss_key=k.gnss(args.gnss_id))
    run.counters = node.counters
    bus.subscribe(k.sensors(), lambda key, msg, recv_ns: node.on_sensor(key, msg), channel="fifo",
                  capacity=args.queue, name="sensors")
    if args.attitude_alignment:
        tilt_std = math.radians(args.attitude_tilt_std)
        bus.subscribe(k.attitude(), lambda key, msg, recv_ns: node.on_attitude(msg, tilt_std), channel="ring",
                      capacity=16, name="attitude")
    bus.subscribe(k.learn_correction(), lambda key, msg, recv_ns: node.on_correction(key, msg), channel="fifo",
                  name="correction")
    return run.serve("running", f"waiting for a sensor stream; filters from {args.params or 'deploy/ins.yaml'}")


if __name__ == "__main__":
    sys.exit(main())
