"""Bad input never corrupts the engine: it is rejected with a counted reason and the solution is the
same as without it. GNSS quality gates, the 100 m jump, outage declaration and recovery."""
from __future__ import annotations

import math

import numpy as np
import pytest

from zennav.nav import earth
from zennav.nav.navigator import Navigator
from zennav.nav.rotation import euler_to_dcm
from zennav.nav.types import NS, FixType, GnssFix, InitialState, NavConfig

LLH0 = np.array([math.radians(30.5), math.radians(114.3), 20.0])
EULER0 = np.radians([1.0, -2.0, 30.0])
DT_NS = 10_000_000  # 100 Hz


def static_imu():
    C_nb = euler_to_dcm(EULER0)
    f_b = C_nb.T @ np.array([0.0, 0.0, -earth.gravity(LLH0[0], LLH0[2])])
    omega_b = C_nb.T @ earth.omega_ie_n(LLH0[0])
    return omega_b * DT_NS / NS, f_b * DT_NS / NS


def fix(t_ns, offset_ned=(0.0, 0.0, 0.0), **kw):
    llh = earth.ned_to_llh(np.asarray(offset_ned, float), LLH0)
    return GnssFix(t_ns=t_ns, llh=llh, std_ned=np.array([0.5, 0.5, 1.0]), v_n=np.zeros(3),
                   std_v_n=np.full(3, 0.05), **kw)


def run(events, seconds=20.0, config=None):
    """Stationary IMU at 100 Hz; events: {imu index: list of callables(nav)} applied before that sample;
    good GNSS at 1 Hz unless the events replace it. Returns the navigator."""
    nav = Navigator(config or NavConfig(), InitialState(0, LLH0.copy(), np.zeros(3), EULER0.copy()))
    dth, dv = static_imu()
    for k in range(1, int(seconds * 100) + 1):
        for ev in events.get(k, []):
            ev(nav)
        if k % 100 == 0 and k not in events:
            nav.on_gnss(fix(k * DT_NS))
        nav.on_imu(k * DT_NS, dth, dv)
    return nav


def same_solution(a: Navigator, b: Navigator):
    assert a.state == b.state
    assert np.array_equal(a.P, b.P)


def test_bad_imu_samples_are_rejected_and_counted():
    dth, dv = static_imu()
    bad = {
        550: [lambda n: n.on_imu(n.t_ns, dth, dv)],  # duplicate time
        650: [lambda n: n.on_imu(n.t_ns - DT_NS, dth, dv)],  # time going backwards
        750: [lambda n: n.on_imu(n.t_ns + 1, [np.nan, 0, 0], dv)],  # NaN
        850: [lambda n: n.on_imu(n.t_ns + 1, dth, [0, np.inf, 0])],
    }
    nav, ref = run(bad), run({})
    assert nav.counters["imu_duplicate"] == 1 and nav.counters["imu_out_of_order"] == 1
    assert nav.counters["imu_nonfinite"] == 2
    same_solution(nav, ref)


def test_bad_gnss_fixes_are_rejected_with_reasons():
    t = lambda k: k * DT_NS  # noqa: E731
    bad = {
        300: [lambda n: n.on_gnss(fix(t(300), fix=int(FixType.NONE)))],
        400: [lambda n: n.on_gnss(fix(t(400), num_sats=3))],
        500: [lambda n: n.on_gnss(GnssFix(t(500), np.array([np.nan, 0, 0]), np.ones(3)))],
        600: [lambda n: n.on_gnss(GnssFix(t(600), LLH0, np.array([0.5, 0.5, 100.0])))],
        700: [lambda n: (n.on_gnss(fix(t(700))), n.on_gnss(fix(t(700))))],  # duplicate
        900: [lambda n: (n.on_gnss(fix(t(900))), n.on_gnss(fix(t(850))))],  # out of order
    }
    nav = run(bad)
    for reason in ("gnss_fix_quality", "gnss_few_satellites", "gnss_malformed", "gnss_std", "gnss_duplicate",
                   "gnss_out_of_order"):
        assert nav.counters[reason] == 1, reason
    reasons = [r.reason for r in nav.pop_reports() if not r.fused]
    assert "gnss_fix_quality" in reasons and "gnss_std" in reasons


def test_100m_jump_is_rejected_and_solution_unchanged():
    def jumped(t_ns):
        f = fix(t_ns, offset_ned=(100.0, 0.0, 0.0))
        f.v_n = f.std_v_n = None  # position only, so that the run without it is the reference
        return f

    jump = {1000: [lambda n: n.on_gnss(jumped(1000 * DT_NS))]}
    skip = {1000: []}  # the same run without that fix
    nav, ref = run(jump), run(skip)
    assert nav.counters["gnss_pos_jump"] == 1
    rejected = [r for r in nav.pop_reports() if r.source == "gnss_pos" and not r.fused]
    assert len(rejected) == 1 and rejected[0].test_ratio > 1.0 and rejected[0].reason == "gnss_pos_jump"
    np.testing.assert_allclose(nav.state.llh, ref.state.llh, atol=1e-12)
    # The only difference: the covariance was propagated in two steps around the rejected fix.
    np.testing.assert_allclose(nav.P[:6, :6], ref.P[:6, :6], rtol=1e-6, atol=1e-12)


def test_outage_declared_after_timeout_and_recovered():
    withheld = {k: [] for k in range(500, 1600, 100)}  # no fix from 5 s to 15 s
    nav = Navigator(NavConfig(outage_timeout_s=2.0), InitialState(0, LLH0.copy(), np.zeros(3), EULER0.copy()))
    dth, dv = static_imu()
    states = []
    for k in range(1, 2001):
        if k % 100 == 0 and k not in withheld:
            nav.on_gnss(fix(k * DT_NS))
        nav.on_imu(k * DT_NS, dth, dv)
        states.append(nav.gnss_state)
    assert states[550] == "valid" and states[800] == "outage" and states[1700] == "valid"
    assert states.index("outage") == pytest.approx(400 + 200, abs=2)  # last fused at 4 s, declared after 2 s
    assert nav.counters["outage_declared"] == 1 and nav.counters["outage_recovered"] == 1


def test_fix_between_imu_samples_is_fused_at_its_own_time():
    """A fix time inside an IMU interval splits it; the solution equals feeding the same data with the
    fix exactly on a sample boundary when the motion is uniform."""
    dth, dv = static_imu()
    nav = Navigator(NavConfig(), InitialState(0, LLH0.copy(), np.zeros(3), EULER0.copy()))
    for k in range(1, 101):
        nav.on_imu(k * DT_NS, dth, dv)
    nav.on_gnss(fix(100 * DT_NS + DT_NS // 2, offset_ned=(0.3, 0.0, 0.0)))
    nav.on_imu(101 * DT_NS, dth, dv)
    rep = nav.pop_reports()
    assert [r.t_ns for r in rep] == [100 * DT_NS + DT_NS // 2] * 2
    assert rep[0].fused and rep[0].innovation[0] == pytest.approx(-0.3, abs=1e-3)
    assert nav.t_ns == 101 * DT_NS
