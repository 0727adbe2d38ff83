"""ins service: the navigation engine (zennav.nav.navigator.Navigator) on the bus.

Wiring table
    subscribes <base>/sensor/**          stream_start -> new Navigator(config, initial); imu (and each sample
                                         of an imu_batch) -> on_imu;
                                         gnss -> on_gnss; stream_end -> final status (acknowledges the end)
               <base>/learn/correction   the predictor's answer to one of our learn/query messages: fused
                                         as a pseudo-measurement (Navigator.on_correction; --learning only)
    publishes  <base>/nav/solution       one per IMU sample (every --solution-every-th)
               <base>/nav/aid/<source>   every aiding report (gnss_pos, gnss_vel, ..., learned_drift)
               <base>/nav/status         GNSS state, core counters, rejections, stream progress
                                         (every second of data time, on GNSS state changes, at stream end)
               <base>/learn/samples      --learning: the core's training samples (GNSS good, converged)
               <base>/learn/query        --learning: the core's prediction requests (GNSS lost)

Learning (--learning; off by default, and then the core and its output are exactly the in-process replay's):
the stream's NavConfig gets ``learning=True``; after every IMU sample the core's LearnSamples and LearnQueries
of the --learn-targets variants are published. A query stays pending until its correction (matched by the
query's src/seq) arrives; an answer is fused only if no GNSS fix was fused since the query and the query is
at most --correction-max-age seconds of data time old (else counted: stale, late); unmatched answers
(duplicates, other ins instances, expired queries) are counted and dropped. Because the answers arrive
asynchronously, a run with learning on is not bit-reproducible.

Sensor messages are consumed strictly in the ingest's ``cseq`` order (zennav.messages.SequenceMerger), and
only from the source whose stream_start is live, so the core sees exactly the sequence the in-process
replay feeds it. Invalid payloads are rejected by the bus validator, counted and never reach the core.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from zennav import messages as M
from zennav.learn.link import LearningLink
from zennav.service import ServiceRunner, add_bus_args


def solution_msg(nav, ok, imu_cseq: int, imu_pub_ns: int) -> dict:
    """nav_solution message of the navigator's current state. Fast path (the hot loop at >= 20 kHz): read the
    state's floats directly and compute roll/pitch/yaw with the same float operations as
    zennav.nav.rotation.quat_to_euler; falls back to ``nav.solution()`` when the core's state layout differs.
    tests/unit/test_messages.py checks both paths agree."""
    s = getattr(nav, "state", None)
    if ok is not True or s is None or not hasattr(s, "q3") or not hasattr(nav, "std_att"):
        sol = nav.solution() if ok is True else ok
        return M.nav_solution_msg(sol, imu_cseq, imu_pub_ns)
    q0, q1, q2, q3 = s.q0, s.q1, s.q2, s.q3
    c20 = 2 * (q1 * q3 - q0 * q2)
    c21 = 2 * (q2 * q3 + q0 * q1)
    c22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    c10 = 2 * (q1 * q2 + q0 * q3)
    c00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    euler = [math.atan2(c21, c22), math.atan2(-c20, math.hypot(c21, c22)), math.atan2(c10, c00)]
    return M.make("nav_solution", nav.t_ns, llh=[s.lat, s.lon, s.h], v_n=[s.vn, s.ve, s.vd], q_nb=[q0, q1, q2, q3],
                  euler=euler, gyro_bias=_as_list(nav.gyro_bias), accel_bias=_as_list(nav.accel_bias),
                  std_pos_ned=_as_list(nav.std_pos_ned), std_v_n=_as_list(nav.std_v_n),
                  std_euler=_as_list(nav.std_att), gnss_state=str(nav.gnss_state), imu_cseq=int(imu_cseq),
                  imu_pub_ns=int(imu_pub_ns))


_LIST_CACHE: dict[int, tuple] = {}


def _as_list(a) -> list:
    """M.floats(a), cached by object identity: the core replaces (never mutates) its bias lists and std
    arrays when they change, so most samples reuse the previous conversion."""
    hit = _LIST_CACHE.get(id(a))
    if hit is not None and hit[0] is a:
        return hit[1]
    out = M.floats(a)
    if len(_LIST_CACHE) > 64:
        _LIST_CACHE.clear()
    _LIST_CACHE[id(a)] = (a, out)
    return out


class InsNode:
    """The transport-free part of the ins service (testable without zenoh): feed it validated messages with
    ``on_sensor(key, msg)``; it calls ``publish(kind, msg)`` with kind in solution/aid/status."""

    def __init__(self, publish, log, solution_every: int = 1, status_period_ns: int = 1_000_000_000,
                 on_state=None, bus_rejected=None, learning: LearningLink | None = None):
        self.publish = publish
        self.learn = learning  # None: learning off (the default; the core runs exactly as in the replay)
        self.bus_rejected = bus_rejected or dict
        self.on_state = on_state or (lambda detail: None)
        self.log = log
        self.solution_every = max(1, int(solution_every))
        self.status_period_ns = status_period_ns
        self.nav = None
        self.src: str | None = None
        self.dataset = ""
        self.merger: M.SequenceMerger | None = None
        self.done = False
        self.last_cseq = -1
        self.imu_count = 0
        self.gnss_count = 0
        self.sol_count = 0
        self.drops: dict[str, int] = {"foreign_source": 0, "no_stream": 0}
        self.corrections = 0
        self._next_status_t = None
        self._gnss_state = None
        self._align_state = None
        self.attitude_taken = 0
        self._wall0 = 0.0
        self.wall_s = 0.0

    # ------------------------------------------------------------------ input
    def on_sensor(self, key: str, msg: dict) -> None:
        schema = msg["schema"]
        if schema == "stream_start":
            self._start(msg)
            return
        if msg["src"] != self.src:
            self.drops["foreign_source" if self.src is not None else "no_stream"] += 1
            n = sum(self.drops.values())
            if n <= 3 or n % 1000 == 0:
                self.log.warning("dropped %s from %s: not the live stream (%s)", schema, msg["src"], self.src)
            return
        if schema == "imu_batch":
            for m in M.samples(msg):
                self.merger.push(m["cseq"], m, self._consume)
            return
        self.merger.push(msg["cseq"], msg, self._consume)

    def _start(self, msg: dict) -> None:
        from zennav.nav.navigator import Navigator
        from zennav.nav.types import InitialState, NavConfig

        if self.src is not None and msg["src"] != self.src:
            self.log.warning("new stream %s from %s replaces %s", msg["dataset"], msg["src"], self.src)
        elif self.src == msg["src"]:
            self.drops["duplicate_start"] = self.drops.get("duplicate_start", 0) + 1
            return
        config = M.map_to_dataclass(NavConfig, msg["config"])
        initial = M.map_to_dataclass(InitialState, msg["initial"])
        if self.learn is not None:
            config = config.with_(learning=True)
            self.learn.reset()
        self.nav = Navigator(config, initial)
        self.src = msg["src"]
        self.dataset = msg["dataset"]
        self.merger = M.SequenceMerger(msg["cseq"] + 1)
        self.done = False
        self.last_cseq = -1
        self.imu_count = self.gnss_count = self.sol_count = 0
        self._next_status_t = int(initial.t_ns) + self.status_period_ns
        self._gnss_state = self.nav.gnss_state
        self._align_state = getattr(self.nav, "align_state", None)
        self._wall0 = time.perf_counter()
        self.wall_s = 0.0
        self.log.info("stream %s from %s: %s IMU, %s GNSS expected", self.dataset, self.src,
                      msg["counts"].get("imu"), msg["counts"].get("gnss"))
        self.on_state(f"navigating stream {self.dataset} from {self.src}")

    def _consume(self, msg: dict) -> None:
        schema = msg["schema"]
        nav = self.nav
        if schema == "imu":
            self.imu_count += 1
            ok = nav.on_imu(msg["t_ns"], msg["dtheta"], msg["dvel"])  # False: rejected by the core (counted)
            self._reports()
            if self.learn is not None:
                self.learn.after_imu(nav)
            if ok:
                self.sol_count += 1
                if self.sol_count % self.solution_every == 0:
                    self.publish("solution", solution_msg(nav, ok, msg["cseq"], msg["pub_ns"]))
            align = getattr(nav, "align_state", None)
            if nav.gnss_state != self._gnss_state or align != self._align_state or msg["t_ns"] >= self._next_status_t:
                self._gnss_state, self._align_state = nav.gnss_state, align
                while self._next_status_t <= msg["t_ns"]:
                    self._next_status_t += self.status_period_ns
                self.publish("status", self.status_msg())
        elif schema == "gnss":
            self.gnss_count += 1
            nav.on_gnss(M.gnss_fix(msg))
            self._reports()
        elif schema == "stream_end":
            self.merger.flush(self._consume)
            self.done = True
            self.wall_s = time.perf_counter() - self._wall0
            self.last_cseq = msg["last_cseq"]
            c = msg["counts"]
            lost = (c.get("imu", 0) - self.imu_count, c.get("gnss", 0) - self.gnss_count)
            (self.log.info if lost == (0, 0) else self.log.error)(
                "end of stream %s: consumed %d/%d IMU, %d/%d GNSS in %.2f s (%.0f IMU/s); merger %s", self.dataset,
                self.imu_count, c.get("imu", 0), self.gnss_count, c.get("gnss", 0), self.wall_s,
                self.imu_count / max(self.wall_s, 1e-9), dict(self.merger.counts))
            self.publish("status", self.status_msg())
            self.on_state(f"stream {self.dataset} done: {self.imu_count} IMU, {self.gnss_count} GNSS, "
                          f"{self.sol_count} solutions")

    def on_attitude(self, msg: dict, tilt_std_rad: float) -> bool:
        """attitude message -> roll/pitch for coarse alignment (Navigator.on_attitude), only while the heading is
        unknown ('coarse'), the vehicle stands still (the GNSS velocity held in coarse alignment below
        align_still_speed_mps) and the filter's accelerometer is not rejected (weight 1): the accelerometer-only
        tilt is wrong under sustained acceleration (about atan(a/g); 12 deg of pitch on sim:car's 1.5 m/s^2 for
        15 s), so only the at-rest tilt is taken; the ins then carries it into the motion on its gyros. Returns
        whether taken. Opt-in (--attitude-alignment): the moment a message arrives is not part of the sensor
        sequence, so a run that takes it is not bit-reproducible by the in-process replay."""
        nav = self.nav
        if nav is None or getattr(nav, "align_state", None) != "coarse" or msg["weight"] < 1.0:
            return False
        if math.hypot(nav.state.vn, nav.state.ve) > nav.config.align_still_speed_mps:
            return False
        roll, pitch = msg["euler"][0], msg["euler"][1]
        taken = bool(nav.on_attitude(msg["t_ns"], roll, pitch, tilt_std_rad))
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

    # ------------------------------------------------------------------ output
    def status_msg(self) -> dict:
        st = self.nav.status() if self.nav is not None else {"counters": {}, "gnss_state": "unknown"}
        m = self.merger
        stream = {"src": self.src or "", "dataset": self.dataset, "done": self.done, "last_cseq": self.last_cseq,
                  "next_cseq": m.next if m else -1, "held": m.held if m else 0,
                  "solutions": self.sol_count, "wall_s": self.wall_s, **({k: int(v) for k, v in m.counts.items()} if m else {})}
        t = self.nav.t_ns if self.nav is not None else 0
        extra = {}
        if "alignment" in st:
            extra["alignment"] = alignment_map(st["alignment"])
        if "measurement_noise" in st:
            extra["adaptive_r"] = bool(st.get("adaptive_r", False))
            extra["measurement_noise"] = noise_map(st["measurement_noise"])
        return M.make("nav_status", t, gnss_state=str(st.get("gnss_state", "unknown")),
                      counters={str(k): int(v) for k, v in st.get("counters", {}).items()},
                      rejected={**{k: int(v) for k, v in self.bus_rejected().items()},
                                **{k: int(v) for k, v in self.drops.items()}}, imu_count=self.imu_count,
                      gnss_count=self.gnss_count, stream=stream,
                      model={"corrections_received": self.corrections,
                             **(self.learn.status() if self.learn is not None else
                                {"learning": False, "corrections_fused": 0})}, **extra)


def _finite(x: float, default: float) -> float:
    x = float(x)
    return x if math.isfinite(x) else default


def alignment_map(al: dict) -> dict:
    """Navigator.status()["alignment"] -> the nav_status ``alignment`` map (see zennav.messages.check_nav_status)."""
    return {"state": str(al["state"]), "method": str(al.get("method") or ""),
            "heading_std_rad": _finite(al["heading_std_rad"], 1e9),
            "times_ns": {str(k): int(v) for k, v in al.get("times_ns", {}).items()},
            "tilt_source": str(al.get("tilt_source") or ""), "gyrocompass": str(al.get("gyrocompass") or "")}


def noise_map(noise: dict) -> dict:
    """Navigator.status()["measurement_noise"] -> per source {R_diag, ratio, branch[, k, inflate, fading]}: the live
    R diagonal [m^2 or (m/s)^2], its ratio to the reported R (None when R is not adapted) and the seed-001 branch
    taken last ('inflate' / 'fading'; 'fixed' when adaptive R is off)."""
    out = {}
    for src, r in noise.items():
        e = {"R_diag": [float(x) for x in np.diag(np.asarray(r["R"], dtype=float))]}
        if "scale_diag" in r:
            e.update(ratio=[float(x) for x in r["scale_diag"]], branch=str(r.get("branch") or "none"),
                     **{k: int(r[k]) for k in ("k", "inflate", "fading") if k in r})
        else:
            e.update(ratio=None, branch="fixed")
        out[str(src)] = e
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="zennav-ins", description="zennav ins service: GNSS/INS navigation engine")
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
    p.add_argument("--attitude-alignment", action="store_true",
                   help="take roll/pitch from the attitude service during coarse alignment (heading unknown)")
    p.add_argument("--attitude-tilt-std", type=float, default=1.0,
                   help="1-sigma [deg] credited to the attitude service's at-rest roll/pitch for coarse alignment")
    return add_bus_args(p)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    run = ServiceRunner("ins", args)
    import zennav.nav.navigator  # noqa: F401  (import the core, scipy included, before announcing)
    k = run.keys
    bus = run.bus
    pubs = {"solution": bus.publisher(k.nav_solution()), "status": bus.publisher(k.nav_status())}
    aid_pubs: dict[str, object] = {}

    def publish(kind: str, msg: dict) -> None:
        if kind == "aid":
            p = aid_pubs.get(msg["source"])
            if p is None:
                p = aid_pubs[msg["source"]] = bus.publisher(k.nav_aid(msg["source"]))
            p.put(msg)
        else:
            pubs[kind].put(msg)

    learn = None
    if args.learning:
        from zennav.nav.learning import TARGETS

        targets = [t.strip() for t in args.learn_targets.split(",") if t.strip()]
        if not targets or not set(targets) <= set(TARGETS):
            raise SystemExit(f"--learn-targets: choose from {TARGETS}")
        pubs["sample"] = bus.publisher(k.learn_samples())
        pubs["query"] = bus.publisher(k.learn_query())
        learn = LearningLink(publish, run.log, targets, args.correction_max_age)
    node = InsNode(publish, run.log, args.solution_every, on_state=lambda d: setattr(run, "detail", d),
                   bus_rejected=bus.rejected_counts, learning=learn)
    imu_key, gnss_key, stream_key = k.imu(args.imu_id), k.gnss(args.gnss_id), k.stream()

    def on_sensor(key, msg, recv_ns):
        if key == imu_key or key == gnss_key or key == stream_key:
            node.on_sensor(key, msg)

    def counters():
        return {"imu": node.imu_count, "gnss": node.gnss_count, "solutions": node.sol_count,
                **{f"drop_{a}": b for a, b in node.drops.items()},
                **({f"learn_{a}": b for a, b in dict(learn.counts).items()} if learn is not None else {})}

    run.counters = counters
    bus.subscribe(k.sensors(), on_sensor, channel="fifo", capacity=args.queue, name="sensors")
    if args.attitude_alignment:
        tilt_std = math.radians(args.attitude_tilt_std)
        bus.subscribe(k.attitude(), lambda key, msg, recv_ns: node.on_attitude(msg, tilt_std), channel="ring",
                      capacity=16, name="attitude")
    bus.subscribe(k.learn_correction(), lambda key, msg, recv_ns: node.on_correction(key, msg), channel="fifo", name="correction")
    return run.serve("running", "waiting for a sensor stream")


if __name__ == "__main__":
    sys.exit(main())
