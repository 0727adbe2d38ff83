"""The ins service's core, transport-free: the navigation engine (zennav.nav.navigator.Navigator) over the sensor
stream, its outputs as messages.

The stream comes through zennav.stream.StreamFollower (one stream, cseq order, late join). At its start the
engine is built from the stream's sensor description and the filter settings of the ins's parameter file
(zennav.params.nav_config) and the stream's initial state; followed from its start, the solution is the
in-process replay's bit for bit. A late joiner starts in coarse alignment at its first sample's start time
(heading unknown; position, velocity and attitude from the next GNSS fixes, as an ins switched on in motion).
Learning (a LearningLink given; off by default): the engine emits training samples and queries
(NavConfig.learning), the link publishes them and fuses the answers (zennav.learn.link).
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING

from .. import messages as M
from ..learn.link import LearningLink
from ..params import nav_config
from ..stream import StreamFollower

if TYPE_CHECKING:  # the engine (scipy included) is imported when a stream starts
    from ..nav.navigator import Navigator


class InsNode:
    """The ins service's core (see the module docstring): feed it validated sensor messages with
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
        self.nav: Navigator | None = None
        self.imu_count = self.gnss_count = self.sol_count = self.corrections = self.attitude_taken = 0
        self.wall_s, self._wall0, self._next_status_t, self._states = 0.0, 0.0, 0, (None, None)
        self._late = False  # this stream was joined late (its samples before the join are not ours)

    def _start(self, start: dict, join: dict | None) -> None:
        from ..nav.navigator import Navigator
        from ..nav.types import InitialState

        config = nav_config(start["config"], self.filter_params)
        initial = M.map_to_dataclass(InitialState, start["initial"])
        if join is not None:  # late join: an ins switched on in motion, at the first sample's start time
            initial = replace(initial, t_ns=join["t_ns"] - join["dt_ns"], heading_known=False)
        if self.learn is not None:
            config = config.with_(learning=True)
            self.learn.reset()
        self.nav = nav = Navigator(config, initial)
        self._late = join is not None
        self.imu_count = self.gnss_count = self.sol_count = 0
        self._next_status_t = int(initial.t_ns) + self.status_period_ns
        self._states = (nav.gnss_state, nav.align_state)
        self._wall0, self.wall_s = time.perf_counter(), 0.0
        self.log.info("stream %s from %s%s: %s IMU, %s GNSS expected", start["dataset"], start["src"],
                      " (joined late)" if join else "", start["counts"].get("imu"), start["counts"].get("gnss"))
        self.on_state(f"navigating stream {start['dataset']} from {start['src']}")

    def _sample(self, key: str, msg: dict) -> None:
        schema, nav = msg["schema"], self.nav
        assert nav is not None  # the follower hands samples only after on_start (_start) built the engine
        if self.keys[schema] not in (None, key):
            return
        if schema == "gnss":
            self.gnss_count += 1
            nav.on_gnss(M.gnss_fix(msg))
            self._reports(nav)
            return
        self.imu_count += 1
        ok = nav.on_imu(msg["t_ns"], msg["dtheta"], msg["dvel"])  # False: rejected by the engine (counted)
        self._reports(nav)
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
        (self.log.info if complete or self._late else self.log.error)(
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
            {**self.follower.status(), "solutions": self.sol_count, "wall_s": self.wall_s},
            {**self.bus_rejected(), **self.follower.counts}, self.imu_count, self.gnss_count,
            {"corrections_received": self.corrections,
             **(self.learn.status() if self.learn is not None else {"learning": False, "corrections_fused": 0})})

    def counters(self) -> dict:
        return {"imu": self.imu_count, "gnss": self.gnss_count, "solutions": self.sol_count,
                **{f"drop_{a}": b for a, b in self.follower.counts.items()},
                **({f"learn_{a}": b for a, b in dict(self.learn.counts).items()} if self.learn is not None else {})}
