"""Navigator.get_state / set_state: a run stopped at any sample, its state taken, round-tripped through msgpack and
restored into a fresh Navigator, continues exactly as the uninterrupted run: every output bit for bit (solution,
aiding reports, learning samples, queries and the fused answers)."""
from __future__ import annotations

from dataclasses import replace

import msgpack
import numpy as np
import pytest

from zennav.datasets import kfgins
from zennav.datasets.registry import load_dataset
from zennav.nav.learning import OUTPUTS
from zennav.nav.navigator import Navigator
from zennav.nav.types import NS
from zennav.sim.scenarios import make_dataset


def _pack(x) -> bytes:
    return msgpack.packb(x, default=lambda a: a.tolist() if isinstance(a, np.ndarray) else float(a))


class Answers:
    """A deterministic, stateless stand-in for a compensator: answers every target with zeros (a car does not
    slide sideways or jump; forward speed unknown: a large 1-sigma); position / velocity / drift small errors."""

    def add(self, samples) -> None:
        self.n_samples = getattr(self, "n_samples", 0) + len(samples)

    def predict(self, query):
        n = len(OUTPUTS[query.target])
        std = np.array([30.0, 0.3, 0.3]) if query.target == "body_velocity" else np.full(n, 2.0)
        return np.zeros(n), std


class Drive:
    """Feeds a dataset to a navigator sample by sample like the replay, with GNSS fixes handed over lead_s ahead of
    the IMU (so that some are pending in the engine), outages [(start_s, length_s)] without fixes, and queries
    answered one IMU sample after they were asked. ``imu(nav, k)`` runs sample k; ``drain(nav)`` then returns the
    packed outputs of that sample."""

    def __init__(self, ds, outages=(), lead_s: float = 0.3, answers: Answers | None = None):
        self.ds, self.answers = ds, answers
        t0 = int(ds.imu.t_ns[0])
        self.lead_ns = int(lead_s * NS)
        t = ds.gnss.t_ns
        keep = np.ones(len(t), dtype=bool)
        for start, length in outages:
            keep &= ~((t >= t0 + start * NS) & (t < t0 + (start + length) * NS))
        self.fixes = np.flatnonzero(keep)
        self.j = 0
        self.held = []  # queries of the previous sample, answered now

    def imu(self, nav: Navigator, k: int) -> None:
        t = int(self.ds.imu.t_ns[k])
        while self.j < len(self.fixes) and self.ds.gnss.t_ns[self.fixes[self.j]] <= t + self.lead_ns:
            nav.on_gnss(self.ds.gnss.fix_at(int(self.fixes[self.j])))
            self.j += 1
        nav.on_imu(t, self.ds.imu.dtheta[k], self.ds.imu.dvel[k])

    def drain(self, nav: Navigator) -> bytes:
        sol = nav.solution()
        out = [vars(sol), [vars(r) for r in nav.pop_reports()]]
        if self.answers is not None:
            fused = [nav.on_correction(q, *self.answers.predict(q)) for q in self.held]
            samples, self.held = nav.pop_samples(), nav.pop_queries()
            self.answers.add(samples)
            out += [fused, [vars(s) for s in samples], [vars(q) for q in self.held],
                    [vars(r) for r in nav.pop_reports()]]
        return _pack(out)


def run(ds, config, initial, n: int, snap: int | None = None, perturb=None, **drive_kw):
    """Outputs of samples 1..n-1; with snap: the navigator is replaced after sample snap's on_imu by a fresh one
    restored from its msgpack round-tripped state (perturb(state) may alter it). Returns (outputs, navigator at the
    snapshot or None, the state dict)."""
    drive = Drive(ds, **drive_kw)
    nav = Navigator(config, initial)
    out, at_snap, state = [], None, None
    for k in range(1, n):
        drive.imu(nav, k)
        if k == snap:
            state = msgpack.unpackb(msgpack.packb(nav.get_state()), strict_map_key=False)
            if perturb is not None:
                perturb(state)
            at_snap, nav = nav, Navigator(config, initial)
            nav.set_state(state)
        out.append(drive.drain(nav))
    return out, at_snap, state


def first_sample(ds, config, initial, cond, start: int = 1, end: int = 20000, **drive_kw) -> int | None:
    """The first sample k >= start after whose on_imu cond(navigator) holds."""
    drive = Drive(ds, **drive_kw)
    nav = Navigator(config, initial)
    for k in range(1, end):
        drive.imu(nav, k)
        if k >= start and cond(nav):
            return k
        drive.drain(nav)
    return None


def assert_continues_exactly(ds, config, initial, n: int, snap: int, **drive_kw):
    ref, _, _ = run(ds, config, initial, n, **drive_kw)
    got, nav, state = run(ds, config, initial, n, snap, **drive_kw)
    assert len(got) == len(ref)
    bad = [k for k, (a, b) in enumerate(zip(got, ref)) if a != b]
    assert not bad, f"{len(bad)} samples differ, the first at sample {bad[0] + 1} (snapshot at {snap})"
    return nav, state


@pytest.fixture(scope="module")
def car():
    return load_dataset("sim:car", duration_s=150.0)


def test_state_is_plain_and_survives_msgpack(car):
    nav = Navigator(car.config, car.initial)
    Drive(car).imu(nav, 1)
    state = nav.get_state()
    assert msgpack.unpackb(msgpack.packb(state), strict_map_key=False) == state


def test_restore_with_pending_fixes(car):
    nav, state = assert_continues_exactly(car, car.config, car.initial, 8000, 4350)
    assert state["pending"] and nav.gnss_state == "valid"


def test_restore_inside_an_outage(car):
    nav, state = assert_continues_exactly(car, car.config, car.initial, 9000, 6500, outages=[(30.0, 15.0)])
    assert nav.gnss_state == "outage" and state["sources"]["gnss_pos"]["gnss_state"] == "outage"


def test_restore_mid_coarse_alignment(car):
    initial = replace(car.initial, heading_known=False)
    aligned = first_sample(car, car.config, initial, lambda nav: nav.align_state != "coarse")
    assert aligned is not None and aligned > 400, "the car must stay a while in coarse alignment"
    nav, state = assert_continues_exactly(car, car.config, initial, aligned + 2000, aligned - 300)
    assert nav.align_state == "coarse" and state["alignment"]["prev_track"] is not None
    assert state["alignment"]["accel_sums"][4] > 5  # the velocity changes so far go on


def test_restore_with_learning_and_answers(car):
    config = car.config.with_(learning=True, learn_after_s=10.0)
    kw = {"outages": [(40.0, 20.0)], "answers": Answers()}
    snap = first_sample(car, config, car.initial, lambda nav: len(nav.tap.queries) > 0, 9500, **kw)
    nav, state = assert_continues_exactly(car, config, car.initial, 12500, snap, **kw)
    tap = state["tap"]
    assert nav.gnss_state == "outage" and tap["shadows"] and tap["queries"]
    assert nav.counters["learned_body_velocity_fused"] > 0 and nav.counters["learned_drift_fused"] > 0


def test_restore_kf_gins_files_with_gnss_velocity_and_adaptive_r(tmp_path):
    ds = kfgins.load_config(kfgins.write_dataset(load_dataset("sim:multirotor", duration_s=60.0), tmp_path))
    assert ds.gnss.v_n is not None
    config = ds.config.with_(adaptive_r=True)
    nav, state = assert_continues_exactly(ds, config, ds.initial, 10000, 5003, outages=[(30.0, 8.0)])
    assert state["sources"]["gnss_vel"]["adaptive"]["C"] and nav.counters["gnss_vel_fused"] > 0


def test_a_perturbed_state_changes_the_output(car):
    """The check can fail: one covariance entry changed by a relative 1e-9 changes the continued output."""
    ref, _, _ = run(car, car.config, car.initial, 6000)

    def perturb(state):
        state["P"][0][0] *= 1.0 + 1e-9

    got, _, _ = run(car, car.config, car.initial, 6000, 4321, perturb=perturb)
    assert got[:4320] == ref[:4320] and got != ref


def test_a_state_of_another_configuration_is_refused(car):
    state = Navigator(car.config.with_(learning=True), car.initial).get_state()
    with pytest.raises(ValueError):
        Navigator(car.config, car.initial).set_state(state)


def test_restore_with_the_non_holonomic_constraint(car):
    """The constraint's own clock (its next update time) is part of the state: restored mid-period inside an
    outage, the run continues exactly."""
    config = car.config.with_(nhc=True, nhc_every_s=0.1)
    nav, state = assert_continues_exactly(car, config, car.initial, 9000, 6511, outages=[(30.0, 15.0)])
    assert state["sources"]["nhc"]["next_ns"] > 0 and nav.counters["nhc_fused"] > 0


def test_restore_with_scale_factor_states():
    """The 21-state option's augmented states (values and covariance) are part of the state."""
    car = make_dataset("car", duration_s=60.0, seed=3, scale_ppm=(5000.0, 5000.0))
    nav, state = assert_continues_exactly(car, car.config, car.initial, 9000, 6017, outages=[(30.0, 10.0)])
    assert nav.n_states == 21 and len(state["aug"]["x"]) == 6 and any(x != 0.0 for x in state["aug"]["x"])
