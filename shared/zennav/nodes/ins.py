"""The ins service's core, transport-free: the navigation engine (zennav.nav.navigator.Navigator) over the sensor
stream, its outputs as messages.

The stream comes through zennav.stream.StreamFollower (one stream, cseq order, late join). At its start the
engine is built from the stream's sensor description and the filter settings of the ins's parameter file
(zennav.params.nav_config) and the stream's initial state; followed from its start, the solution is the
in-process replay's bit for bit. A late joiner starts in coarse alignment at its first sample's start time
(heading unknown; position, velocity and attitude from the next GNSS fixes, as an ins switched on in motion).
Crash recovery: with a Checkpointer the whole state (the engine's get_state, the stream position, counts) is
written atomically every few seconds of data (zennav.checkpoint); a new InsNode with the same file resumes
from it with the stream's messages since (fetched from the ingest's history, zennav.stream.Backfill). IMU
samples lost in a gap up to bridge_max_s are bridged (the next sample's rates held over the gap); after a
longer gap the ins re-aligns as a late joiner. Learning (a LearningLink given; off by default): the engine
emits training samples and queries (NavConfig.learning), the link publishes them and fuses the answers
(zennav.learn.link); only the targets it publishes run in the engine (the drift target's shadow INSs only for
drift). Block loop (``block_loop``): the IMU samples of one sensor message (an imu_batch) are collected and run
through the engine's block loop (Navigator.run_imu: compiled by numba, or as Python), up to each GNSS fix or sample
the step-wise engine must take (with learning also each sample at which the tap may query; none while a shadow INS
runs), which on_imu takes as without it; the loop's rows (each sample's navigation state and 1-sigma) make every
sample's solution the step-wise one, float for float, and the learning samples and queries are the step-wise ones.
"""
from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .. import messages as M
from ..checkpoint import Checkpointer, CheckpointError
from ..checkpoint import load as load_checkpoint
from ..learn.link import LearningLink
from ..params import nav_config
from ..stream import StreamFollower

if TYPE_CHECKING:  # the engine (scipy included) is imported when a stream starts
    from ..nav.navigator import Navigator


class InsNode:
    """The ins service's core (see the module docstring): feed it validated sensor messages with
    ``on_sensor(key, msg)``; it calls ``publish(kind, msg)`` with kind solution/aid/status. filter_params: SI
    settings of a parameter file (zennav.params.load_filter_params; {}: NavConfig's defaults); imu_key /
    gnss_key / aid_keys ({"dvl": key, "depth": key}): the sensors it navigates with (None: any).
    DVL and depth samples (zennav.messages.AID_STREAMS) come before the IMU sample that reaches their time; they
    are held until it is processed and then go to ``Navigator.on_aid`` before its solution is published, as the
    in-process replay hands them over (zennav.replay.run_replay). block_loop: "compiled" (numba) or "python" runs
    the IMU samples of one message through the engine's block loop (module docstring; None: each sample
    step-wise). put_solution(nav, t_ns, row, std, cseq, pub_ns) publishes one solution from its floats (row:
    the 10 of the navigation state, std: the 9 1-sigma; the service packs them straight into bytes,
    zennav.messages.SolutionPacker); None: publish("solution", its message map). put_batch(nav, t_ns, rows, std,
    cseq, pub_ns) (with block_loop; None: put_solution for each row): the solutions of each stretch the block loop
    ran at once in one call (t_ns, cseq, pub_ns: sequences; rows (N, 10) and std (N, 9): arrays;
    zennav.messages.nav_solution_batch_msg); the samples the step-wise engine takes still go to put_solution."""

    def __init__(self, publish, log, filter_params: dict | None = None, solution_every: int = 1,
                 status_period_ns: int = 1_000_000_000, on_state=None, bus_rejected=None,
                 learning: LearningLink | None = None, fetch_start=None, imu_key=None, gnss_key=None,
                 checkpoint: Checkpointer | None = None, bridge_max_s: float = 0.5, takeover_after_s: float = 10.0,
                 aid_keys: dict | None = None, block_loop: str | None = None, put_solution=None, put_batch=None):
        self.publish, self.log = publish, log
        self.filter_params = dict(filter_params or {})
        self.learn = learning  # None: learning off (the default; the engine runs exactly as in the replay)
        self.bus_rejected = bus_rejected or dict
        self.on_state = on_state or (lambda detail: None)
        self.solution_every = max(1, int(solution_every))
        self.status_period_ns = status_period_ns
        self.keys = {"imu": imu_key, "gnss": gnss_key, **{a: None for a in M.AID_STREAMS}, **(aid_keys or {})}
        self.follower = StreamFollower(self._start, self._sample, self._end, fetch_start, log,
                                       takeover_after_s=takeover_after_s, on_resume=self._resume, on_flush=self._flush,
                                       on_batch=self._batch)
        if block_loop not in (None, "compiled", "python"):
            raise ValueError(f"block_loop {block_loop!r}: compiled, python or None")
        self.block_loop = block_loop
        self._block: list[dict] = []  # IMU samples collected for the block loop (block_loop)
        self.on_sensor = self.follower.on_message
        self.put_solution = put_solution or self._solution_map
        self.put_batch = put_batch
        self._std_of: tuple = (None, [])  # the engine's std_pos_ned and the 9 floats of _std
        self.nav: Navigator | None = None
        self.imu_count = self.gnss_count = self.sol_count = self.corrections = self.attitude_taken = 0
        self.aid_count: Counter[str] = Counter()  # aid samples consumed per stream (dvl, depth)
        self._held: list[dict] = []  # aid messages waiting for the IMU sample that reaches their time
        self.wall_s, self._wall0, self._next_status_t, self._states = 0.0, 0.0, 0, (None, None)
        self.cpu_s, self._cpu0 = 0.0, 0.0  # [s] CPU time of this process (all threads) over the stream
        self._late = False  # this stream was joined late (its samples before the join are not ours)
        self.checkpoint = checkpoint or Checkpointer(None)
        self.bridge_max_ns = int(bridge_max_s * 1e9)
        self.recovery: Counter[str] = Counter()  # gaps bridged, re-aligned after; resumed; checkpoint_* failures
        self._initial: dict = {}  # the InitialState the engine was built with (a checkpoint rebuilds it)
        self._t_imu = 0  # [ns] end of the last IMU interval given to the engine
        self._saved: dict | None = None  # the checkpoint to resume from, once its stream's first message arrives
        if self.checkpoint.path is not None:
            self._load_checkpoint()

    def _load_checkpoint(self) -> None:
        assert self.checkpoint.path is not None  # called only with a checkpoint file
        try:
            saved = load_checkpoint(self.checkpoint.path)
        except CheckpointError as e:
            self.recovery["checkpoint_unusable"] += 1
            self.log.error("checkpoint not used: %s", e)
            return
        if saved is not None:
            self._saved = saved
            self.follower.resume(saved["start"], saved["next_cseq"], saved["t_ref_ns"])
            self.log.info("checkpoint of stream %s from %s at cseq %d found: resuming when it is heard",
                          saved["start"]["dataset"], saved["start"]["src"], saved["next_cseq"])

    def _resume(self, start: dict) -> None:
        """The follower resumes the checkpoint's stream: the engine as it was at the checkpoint."""
        saved = self._saved
        assert saved is not None  # the follower resumes only what _load_checkpoint gave it
        self._saved = None
        self._build(start, saved["initial"], saved["late"])
        assert self.nav is not None
        self.nav.set_state(saved["nav"])
        self.imu_count, self.gnss_count, self.sol_count = saved["counts"][:3]
        self.aid_count = Counter(saved.get("aid_counts", {}))
        if self.learn is not None and saved["learn_sent"]:  # the queries' n_samples go on where they were
            self.learn.sent.update({t: n for t, n in saved["learn_sent"].items() if t in self.learn.sent})
        self._t_imu = saved["t_ref_ns"]
        self.recovery["resumed"] += 1
        self.on_state(f"navigating stream {start['dataset']} from {start['src']} (resumed from a checkpoint)")

    def _start(self, start: dict, join: dict | None) -> None:
        from ..nav.types import InitialState

        initial = M.map_to_dataclass(InitialState, start["initial"])
        if join is not None:  # late join: an ins switched on in motion, at the first sample's start time
            initial = replace(initial, t_ns=join["t_ns"] - join["dt_ns"], heading_known=False)
        self._build(start, M.dataclass_to_map(initial), join is not None)
        self.imu_count = self.gnss_count = self.sol_count = 0
        self.aid_count.clear()
        self.log.info("stream %s from %s%s: %s IMU, %s GNSS expected", start["dataset"], start["src"],
                      " (joined late)" if join else "", start["counts"].get("imu"), start["counts"].get("gnss"))
        self.on_state(f"navigating stream {start['dataset']} from {start['src']}")

    def _build(self, start: dict, initial_map: dict, late: bool) -> None:
        """The engine for start's sensors and this ins's filter settings, from initial_map (an InitialState map)."""
        from ..nav.navigator import Navigator
        from ..nav.types import InitialState

        config = nav_config(start["config"], self.filter_params)
        initial = M.map_to_dataclass(InitialState, initial_map)
        if self.learn is not None:
            targets = self.learn.targets  # the drift target's shadow INSs only where its samples are published
            config = config.with_(learning=True, dvl_learned="dvl_beam" in targets, learn_drift="drift" in targets)
            self.learn.reset(start["src"])
        self.nav = nav = Navigator(config, initial)
        self._initial, self._late, self._t_imu = initial_map, late, int(initial.t_ns)
        self._held.clear()
        self._next_status_t = int(initial.t_ns) + self.status_period_ns
        self._states = (nav.gnss_state, nav.align_state)
        self._wall0, self.wall_s = time.perf_counter(), 0.0
        self._cpu0, self.cpu_s = time.process_time(), 0.0

    def _bridge(self, msg: dict) -> dict | None:
        """An IMU sample after lost ones (its interval starts after the last one given to the engine): up to
        bridge_max_s, its increments scaled to the whole gap (the rates held over it); beyond, the ins re-aligns
        from this sample as a late joiner (returns None)."""
        gap_ns = msg["t_ns"] - msg["dt_ns"] - self._t_imu
        if gap_ns > self.bridge_max_ns:
            self.recovery["realigned"] += 1
            self.log.warning("%.3f s of the stream lost: re-aligning from cseq %d", gap_ns / 1e9, msg["cseq"])
            start = self.follower.start
            assert start is not None  # samples come only within a started stream
            self._start(start, msg)
            return None
        k = (msg["t_ns"] - self._t_imu) / msg["dt_ns"]
        self.recovery["bridged"] += 1
        return {**msg, "dtheta": [k * x for x in msg["dtheta"]], "dvel": [k * x for x in msg["dvel"]]}

    def _sample(self, key: str, msg: dict) -> None:
        schema, nav = msg["schema"], self.nav
        assert nav is not None  # the follower hands samples only after on_start (_start) built the engine
        if self.keys[schema] not in (None, key):
            return
        if schema != "imu":
            self._flush()
        if schema == "gnss":
            self.gnss_count += 1
            nav.on_gnss(M.gnss_fix(msg))
            self._reports(nav)
            return
        if schema != "imu":  # dvl, depth: fused right after the IMU sample that reaches its time
            self.aid_count[schema] += 1
            self._held.append(msg)
            return
        if msg["t_ns"] - msg["dt_ns"] > self._t_imu:  # samples lost before this one
            self._flush()
            bridged = self._bridge(msg)
            if bridged is None:
                return
            msg = bridged
        self.imu_count += 1
        self._t_imu = msg["t_ns"]
        if self.block_loop is not None and not self._held:
            self._block.append(msg)
            return
        self._imu(nav, msg)

    def _batch(self, key: str, msg: dict) -> None:
        """An imu_batch that continues the stream (StreamFollower.on_batch): with the block loop, right after the last
        IMU interval and no aid sample held, run from its arrays (_run); else its samples one by one (_sample)."""
        t = msg["t_ns_list"]
        if self.block_loop is None or self._held or self.keys["imu"] not in (None, key) \
                or t[0] - msg["dt_ns_list"][0] != self._t_imu:
            for m in M.samples(msg):
                self._sample(key, m)
            return
        self._flush()
        n, c = len(t), msg["cseq"]
        self.imu_count += n
        self._t_imu = t[-1]
        one: list = []  # its samples as imu messages, built only for one the step-wise engine takes

        def sample(i: int) -> dict:
            if not one:
                one.extend(M.samples(msg))
            return one[i]

        self._run(t, np.array(msg["dtheta"], dtype=float).reshape(n, 3),
                  np.array(msg["dvel"], dtype=float).reshape(n, 3), range(c, c + n), [msg["pub_ns"]] * n, sample)

    def _imu(self, nav: Navigator, msg: dict) -> None:
        """One IMU sample step-wise (Navigator.on_imu), then what follows every sample: the held aid samples, the
        reports, the learning link, the solution, the status and the checkpoint when due."""
        ok = nav.on_imu(msg["t_ns"], msg["dtheta"], msg["dvel"])  # False: rejected by the engine (counted)
        for held in self._held:
            nav.on_aid(held["schema"], M.aid_sample(held))
        self._held.clear()
        self._reports(nav)
        if self.learn is not None:
            self.learn.after_imu(nav)
        if ok:
            self.sol_count += 1
            if self.sol_count % self.solution_every == 0:
                s = nav.state
                self.put_solution(nav, nav.t_ns, (s.lat, s.lon, s.h, s.vn, s.ve, s.vd, s.q0, s.q1, s.q2, s.q3),
                                  self._std(nav), msg["cseq"], msg["pub_ns"])
        self._after(nav, msg["t_ns"], msg["cseq"])

    def _std(self, nav: Navigator) -> list:
        """The engine's 1-sigma of position, velocity and attitude (9 floats), converted once per change: the engine
        replaces its three std arrays together (Navigator._update_stds, set_state), never mutates them."""
        if self._std_of[0] is not nav.std_pos_ned:
            self._std_of = (nav.std_pos_ned, nav.std_pos_ned.tolist() + nav.std_v_n.tolist() + nav.std_att.tolist())
        return self._std_of[1]

    def _solution_map(self, nav: Navigator, t_ns: int, row, std: list, cseq: int, pub_ns: int) -> None:
        """put_solution's default: the solution message's map to publish("solution", ...)."""
        self.publish("solution", M.nav_solution_msg_of_row(nav, t_ns, row, std[0:3], std[3:6], std[6:9], cseq,
                                                           pub_ns))

    def _after(self, nav: Navigator, t_ns: int, cseq: int) -> None:
        """After the IMU sample at t_ns [ns] of cseq (or a block ending with it): the status when the GNSS or
        alignment state changed or a status period passed, the checkpoint when due."""
        states = (nav.gnss_state, nav.align_state)
        if states != self._states or t_ns >= self._next_status_t:
            self._states = states
            while self._next_status_t <= t_ns:
                self._next_status_t += self.status_period_ns
            self.publish("status", self.status_msg())
        if self.checkpoint.due(t_ns):
            self._write_checkpoint(t_ns, cseq)

    def _flush(self) -> None:
        """The IMU samples collected for the block loop (imu messages) through _run."""
        block = self._block
        if not block:
            return
        self._block = []
        n = len(block)
        self._run([m["t_ns"] for m in block], np.array([m["dtheta"] for m in block], dtype=float).reshape(n, 3),
                  np.array([m["dvel"] for m in block], dtype=float).reshape(n, 3), [m["cseq"] for m in block],
                  [m["pub_ns"] for m in block], block.__getitem__)

    def _run(self, t: list, dtheta: np.ndarray, dvel: np.ndarray, cseq, pub_ns: list, sample) -> None:
        """IMU samples t [ns] (increments dtheta, dvel (n, 3) [rad, m/s, body]; the IMU messages' cseq and pub_ns)
        through the block loop, Navigator.run_imu (its rows: each sample's navigation state and 1-sigma), each sample
        it leaves to the step-wise engine taken by _imu (sample(i): its imu message); a solution per sample."""
        nav = self.nav
        assert nav is not None
        n = len(t)
        t_ns = np.array(t, dtype=np.int64)
        out_nav, out_std = np.empty((n, 10)), np.empty((n, 9))
        jit, every, put = self.block_loop == "compiled", self.solution_every, self.put_solution
        k = 0
        while k < n:
            k1 = nav.run_imu(t_ns, dtheta, dvel, k, n, 2**62, out_nav, out_std, jit)
            if k1 == k:  # the step-wise engine's sample (a fix in it, an outage declaration, a rejection, ...)
                self._imu(nav, sample(k))
                k += 1
                continue
            if self.put_batch is not None:  # every solution_every-th row of the block, in one message
                s0, self.sol_count = self.sol_count, self.sol_count + k1 - k
                rows = slice(k + (-(s0 + 1)) % every, k1, every)
                if rows.start < k1:
                    self.put_batch(nav, t[rows], out_nav[rows], out_std[rows], cseq[rows], pub_ns[rows])
            else:
                for i, row, std in zip(range(k, k1), out_nav[k:k1].tolist(), out_std[k:k1].tolist()):
                    self.sol_count += 1
                    if self.sol_count % every == 0:
                        put(nav, t[i], row, std, cseq[i], pub_ns[i])
            if self.learn is not None:  # no samples or queries in a block; the unanswered queries expire
                self.learn.after_imu(nav)
            self._after(nav, t[k1 - 1], cseq[k1 - 1])
            k = k1

    def _write_checkpoint(self, t_ns: int, cseq: int) -> None:
        """The state after the IMU sample at t_ns [ns] of cseq: the stream resumes at the next cseq
        (zennav.checkpoint)."""
        nav, start = self.nav, self.follower.start
        assert nav is not None and start is not None
        try:
            self.checkpoint.write({"start": start, "next_cseq": cseq + 1, "t_ref_ns": t_ns,
                                   "initial": self._initial, "late": self._late, "nav": nav.get_state(),
                                   "counts": [self.imu_count, self.gnss_count, self.sol_count],
                                   "aid_counts": dict(self.aid_count),
                                   "learn_sent": dict(self.learn.sent) if self.learn is not None else {}})
        except OSError as e:
            self.recovery["checkpoint_failed"] += 1
            self.log.error("checkpoint not written: %s", e)

    def _end(self, msg: dict) -> None:
        self._flush()
        self.wall_s = time.perf_counter() - self._wall0
        self.cpu_s = time.process_time() - self._cpu0
        c = msg["counts"]
        got = {"imu": self.imu_count, "gnss": self.gnss_count, **self._aid_counts()}
        complete = all(c.get(kind, 0) == n for kind, n in got.items())
        (self.log.info if complete or self._late else self.log.error)(
            "end of stream %s: consumed %s in %.2f s; merger %s", self.follower.dataset,
            ", ".join(f"{n}/{c.get(kind, 0)} {kind}" for kind, n in got.items()), self.wall_s,
            self.follower.status())
        if self._held:  # none by construction (zennav.replay.sensor_events): a forged stream
            self.log.error("%d aid samples after the last IMU sample not fused", len(self._held))
            self._held.clear()
        self.publish("status", self.status_msg())
        aids = "".join(f", {n} {a}" for a, n in self._aid_counts().items())
        self.on_state(f"stream {self.follower.dataset} done: {self.imu_count} IMU, {self.gnss_count} GNSS{aids}, "
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

    def _reports(self, nav: Navigator) -> None:
        for rep in nav.pop_reports():
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
        self._reports(self.nav)

    def status_msg(self) -> dict:
        nav = self.nav
        return M.nav_status_msg(
            nav.t_ns if nav is not None else 0, nav.status() if nav is not None else None,
            {**self.follower.status(), "solutions": self.sol_count, "wall_s": self.wall_s, "cpu_s": self.cpu_s,
             **self.recovery},
            {**self.bus_rejected(), **self.follower.counts}, self.imu_count, self.gnss_count,
            {"corrections_received": self.corrections,
             **(self.learn.status() if self.learn is not None else {"learning": False, "corrections_fused": 0})},
            self._aid_counts())

    def _aid_counts(self) -> dict:
        """Aid samples consumed per aid stream of the live stream (those its start counts)."""
        start = self.follower.start
        return {a: self.aid_count[a] for a in (start["counts"] if start else ()) if a in M.AID_STREAMS}

    def counters(self) -> dict:
        return {"imu": self.imu_count, "gnss": self.gnss_count, **self.aid_count, "solutions": self.sol_count,
                **{f"drop_{a}": b for a, b in self.follower.counts.items()}, **self.recovery,
                **({f"learn_{a}": b for a, b in dict(self.learn.counts).items()} if self.learn is not None else {})}
