"""Aiding sources (zennav.nav.aid): the status record of each attempt (last fused time, fault flags), the GNSS
position source's gate-trap recovery after a loss, the learned answers' stale / late rules, the str enums of the
GNSS and alignment states, and a new source plugged into the engine without touching it."""
from __future__ import annotations

import msgpack
import numpy as np
import pytest
from test_navigator_inputs import DT_NS, EULER0, LLH0, fix, run, static_imu

from zennav.nav.aid import AidSource, Measurement
from zennav.nav.eskf import N_STATES
from zennav.nav.learning import LearnQuery
from zennav.nav.navigator import Navigator
from zennav.nav.types import NS, AlignState, FixType, GnssState, InitialState, NavConfig


def test_states_are_enums_that_behave_as_strings():
    for member, text in ((GnssState.VALID, "valid"), (GnssState.OUTAGE, "outage"), (AlignState.COARSE, "coarse"),
                         (AlignState.FINE, "fine"), (AlignState.ALIGNED, "aligned")):
        assert member == text and str(member) == text and f"{member}" == text and f"{member:>8}" == f"{text:>8}"
        assert msgpack.unpackb(msgpack.packb({"s": member})) == {"s": text}
    nav = run({}, seconds=2.0)
    assert nav.gnss_state is GnssState.VALID and nav.align_state is AlignState.FINE  # heading 1-sigma 5 deg


def test_reports_carry_the_last_fused_time_and_the_faults():
    def jumped(n):
        n.on_gnss(fix(1000 * DT_NS, offset_ned=(100.0, 0.0, 0.0)))

    events = {300: [lambda n: n.on_gnss(fix(300 * DT_NS, fix=int(FixType.NONE)))], 1000: [jumped]}
    nav = Navigator(NavConfig(), InitialState(0, LLH0.copy(), np.zeros(3), EULER0.copy()))
    reports = []
    dth, dv = static_imu()
    for k in range(1, 1201):
        for ev in events.get(k, []):
            ev(nav)
        if k % 100 == 0 and k not in events:
            nav.on_gnss(fix(k * DT_NS))
        nav.on_imu(k * DT_NS, dth, dv)
        reports += nav.pop_reports()
    pos = {r.t_ns: r for r in reports if r.source == "gnss_pos"}
    assert pos[300 * DT_NS].reason == "gnss_fix_quality" and pos[300 * DT_NS].faults == ["fix_quality"]
    assert pos[300 * DT_NS].last_fused_t_ns == 200 * DT_NS
    assert pos[1000 * DT_NS].faults == ["jump"] and pos[1000 * DT_NS].last_fused_t_ns == 900 * DT_NS
    assert all(r.last_fused_t_ns == r.t_ns and r.faults == [] for r in reports if r.fused)
    assert {r.source for r in reports} == {"gnss_pos", "gnss_vel"}


def test_position_fixes_rejected_after_a_loss_reset_the_covariance_and_are_fused():
    """After a loss of GNSS the INS may be off by more than its own uncertainty: reacquire_fixes rejected fixes in
    a row and the next one is fused ungated after a position / velocity covariance reset."""
    config = NavConfig(reacquire_fixes=3)
    offset = lambda k: (lambda n: n.on_gnss(fix(k * DT_NS, offset_ned=(30.0, 0.0, 0.0))))  # noqa: E731
    events = {k: [] for k in range(500, 1000, 100)} | {k: [offset(k)] for k in range(1000, 1500, 100)}
    nav = run(events, seconds=15.0, config=config)
    reports = [r for r in nav.pop_reports() if r.source == "gnss_pos" and r.t_ns >= 1000 * DT_NS]
    assert [r.reason for r in reports[:3]] == ["gnss_pos_jump"] * 3
    assert reports[3].fused and reports[3].faults == ["gate_trapped"] and nav.counters["gate_reset"] == 1
    assert nav.counters["outage_declared"] == 1 and nav.counters["outage_recovered"] == 1
    assert nav.gnss_state == "valid"


def test_learned_answers_are_fused_only_when_fresh():
    config = NavConfig(learning=True, learn_answer_max_age_s=1.0)
    nav = run({k: [] for k in range(1500, 2001, 100)}, seconds=20.0, config=config)  # no fix after 14 s
    nav.pop_reports()
    answer = (np.zeros(2), np.full(2, 0.5))

    def query(t_s):
        return LearnQuery(int(t_s * NS), "position", np.zeros(11), 1.0)

    assert not nav.on_correction(query(13.5), *answer)  # the fix of 14 s came after it
    assert not nav.on_correction(query(18.5), *answer)  # 1.5 s old
    assert nav.on_correction(query(19.5), *answer)
    stale, late, fused = nav.pop_reports()
    assert (stale.reason, stale.faults, stale.last_fused_t_ns) == ("learned_stale", ["stale"], -1)
    assert (late.reason, late.faults) == ("learned_late", ["late"])
    assert fused.fused and fused.last_fused_t_ns == query(19.5).t_ns and fused.source == "learned_position"
    assert nav.counters["learned_stale"] == nav.counters["learned_late"] == nav.counters["learned_position_fused"] == 1
    assert not nav.on_correction(query(19.8), np.zeros(3), np.ones(3))  # wrong size: malformed, not reported
    assert nav.counters["correction_malformed"] == 1 and not nav.pop_reports()


class Height(AidSource):
    """A barometer-like height source [m]: one scalar per input ("height", (t_ns, h, std)), at the engine's time."""

    inputs = ("height",)

    def __init__(self):
        super().__init__("height")

    def on_input(self, nav, data) -> bool:
        t_ns, h, std = data
        nav.propagate_covariance()
        H = np.zeros((1, N_STATES))
        H[0, 2] = 1.0  # the down position error: INS height minus the observed one, negated
        return nav.update(self, Measurement(t_ns, np.array([h]), np.array([h - nav.state.h]), H, np.array([[std**2]])))


def test_a_new_source_plugs_in_without_touching_the_engine():
    initial = InitialState(0, LLH0 + [0.0, 0.0, 3.0], np.zeros(3), EULER0.copy())  # 3 m too high
    nav = Navigator(NavConfig(), initial)
    nav.add_source(Height())
    with pytest.raises(ValueError):
        nav.add_source(Height())
    dth, dv = static_imu()
    for k in range(1, 1001):
        nav.on_imu(k * DT_NS, dth, dv)
        if k % 50 == 0:
            assert nav.on_aid("height", (nav.t_ns, float(LLH0[2]), 0.1))
    assert abs(nav.state.h - LLH0[2]) < 0.2 and nav.counters["height_fused"] == 20
    reports = nav.pop_reports()
    assert len(reports) == 20 and reports[-1].source == "height" and len(reports[-1].innovation) == 1
    assert nav.status()["measurement_noise"]["height"]["R"] == [[pytest.approx(0.01)]]
    assert nav.get_state()["sources"]["height"]["last_fused_t_ns"] == nav.t_ns
    assert not nav.on_aid("depth", (nav.t_ns, 1.0, 0.1))  # nobody takes it
