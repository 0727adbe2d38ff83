"""Earth model known values and rotation round trips."""
import math

import numpy as np
import pytest

from zennav.nav import earth
from zennav.nav import rotation as rot


def test_radii_known_values():
    r_m, r_n = earth.radii(0.0)
    assert r_m == pytest.approx(6335439.327, abs=1e-3)
    assert r_n == pytest.approx(6378137.0, abs=1e-6)
    r_m, r_n = earth.radii(math.pi / 2)
    assert r_m == pytest.approx(6399593.626, abs=1e-3) and r_n == pytest.approx(6399593.626, abs=1e-3)


def test_normal_gravity_known_values():
    assert earth.gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert earth.gravity(math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-10)
    assert earth.gravity(math.radians(45.0), 0.0) == pytest.approx(9.806199, abs=3e-6)  # tabulated WGS-84 value
    gradient = (earth.gravity(math.radians(45.0), 1000.0) - earth.gravity(math.radians(45.0), 0.0)) / 1000.0
    assert gradient == pytest.approx(-3.0861e-6, rel=2e-3)  # free-air gradient


def test_rates():
    lat = math.radians(30.0)
    w = earth.omega_ie_n(lat)
    assert np.linalg.norm(w) == pytest.approx(7.2921151467e-5)
    assert w[0] > 0 and w[2] < 0 and w[1] == 0
    r_m, r_n = earth.radii(lat)
    w_en = earth.omega_en_n(lat, 100.0, (10.0, 20.0, 0.0))
    assert w_en == pytest.approx([20.0 / (r_n + 100), -10.0 / (r_m + 100), -20.0 * math.tan(lat) / (r_n + 100)])


def test_ecef_round_trip_and_ned():
    rng = np.random.default_rng(1)
    llh = np.column_stack([rng.uniform(-1.5, 1.5, 200), rng.uniform(-3.1, 3.1, 200), rng.uniform(-100, 1e4, 200)])
    back = earth.ecef_to_llh(earth.llh_to_ecef(llh))
    assert np.max(np.abs(back[:, :2] - llh[:, :2])) < 1e-12
    assert np.max(np.abs(back[:, 2] - llh[:, 2])) < 1e-6
    assert earth.llh_to_ecef([0.0, 0.0, 0.0]) == pytest.approx([earth.A, 0.0, 0.0])
    ref = np.array([0.5, 1.9, 20.0])
    offsets = rng.normal(0, 500, (50, 3))
    assert earth.llh_to_ned(earth.ned_to_llh(offsets, ref), ref) == pytest.approx(offsets, abs=1e-6)
    north = earth.llh_to_ned(ref + [1e-6, 0, 0], ref)
    assert north[0] == pytest.approx(1e-6 * (earth.radii(0.5)[0] + 20.0), rel=1e-6) and abs(north[1]) < 1e-9


def test_rotation_round_trips():
    rng = np.random.default_rng(2)
    for _ in range(500):
        euler = np.array([rng.uniform(-math.pi, math.pi), rng.uniform(-1.5, 1.5), rng.uniform(-math.pi, math.pi)])
        C = rot.euler_to_dcm(euler)
        q = rot.euler_to_quat(euler)
        assert np.allclose(rot.quat_to_dcm(q), C, atol=1e-12)
        assert np.allclose(rot.dcm_to_euler(C), euler, atol=1e-9)
        assert np.allclose(rot.dcm_to_quat(C), q, atol=1e-12)
        rv = rot.quat_to_rotvec(q)
        assert np.allclose(rot.rotvec_to_quat(rv), q, atol=1e-12)
        assert np.allclose(C @ C.T, np.eye(3), atol=1e-12)


def test_rotation_conventions():
    # yaw of +90 deg: body x (forward) points east in NED.
    C_nb = rot.euler_to_dcm([0.0, 0.0, math.pi / 2])
    assert C_nb @ [1, 0, 0] == pytest.approx([0, 1, 0], abs=1e-12)
    # pitch up: forward axis gets a negative down component.
    C_nb = rot.euler_to_dcm([0.0, 0.3, 0.0])
    assert (C_nb @ [1, 0, 0])[2] == pytest.approx(-math.sin(0.3))
    # composition: q_ac = q_ab * q_bc corresponds to C_ab @ C_bc.
    q_ab, q_bc = rot.euler_to_quat([0.1, 0.2, 0.3]), rot.euler_to_quat([-0.4, 0.5, 2.0])
    assert np.allclose(rot.quat_to_dcm(rot.quat_multiply(q_ab, q_bc)), rot.quat_to_dcm(q_ab) @ rot.quat_to_dcm(q_bc))
    # a rotation vector about z rotates like a yaw.
    assert np.allclose(rot.rotvec_to_dcm([0, 0, 0.7]), rot.euler_to_dcm([0, 0, 0.7]))
    assert rot.skew([1, 2, 3]) @ np.array([4, 5, 6]) == pytest.approx(np.cross([1, 2, 3], [4, 5, 6]))
    assert rot.wrap_angle(np.array([math.pi + 0.1, -math.pi - 0.1]))== pytest.approx([-math.pi + 0.1, math.pi - 0.1])


def test_small_ned_offsets_and_llh_increments_are_inverse_and_match_d_inverse():
    lat, h = math.radians(47.3), 512.0
    d_ned = (12.5, -3.25, 0.75)
    dllh = earth.ned_to_dllh(d_ned, lat, h)
    np.testing.assert_allclose(earth.dllh_to_ned(dllh, lat, h), d_ned, rtol=1e-15)
    assert dllh[2] == -0.75
    np.testing.assert_allclose(np.array(dllh), earth.dr_to_dllh(lat, h) * d_ned, rtol=1e-15)
    lats, hs = np.radians([-60.0, 0.0, 45.0]), np.array([0.0, 100.0, -20.0])  # arrays: element by element the same
    batch = np.stack(earth.ned_to_dllh(np.tile(d_ned, (3, 1)).T, lats, hs), -1)
    assert np.array_equal(batch, [earth.ned_to_dllh(d_ned, float(a), float(b)) for a, b in zip(lats, hs)])
    # Against the exact conversion: first order in the offset.
    exact = earth.llh_to_ned(np.array([lat, 0.0, h]) + dllh, np.array([lat, 0.0, h]))
    np.testing.assert_allclose(exact, d_ned, atol=1e-4)


def test_batch_rotations_equal_the_scalar_ones():
    rng = np.random.default_rng(3)
    q = np.array([rot.quat_normalize(x) for x in rng.standard_normal((50, 4))])
    C = rot.quat_to_dcm(q)
    assert C.shape == (50, 3, 3) and all(np.array_equal(C[i], rot.quat_to_dcm(q[i])) for i in range(50))
    e = rot.quat_to_euler(q)  # numpy's and math's atan2 may differ in the last bit
    assert e.shape == (50, 3)
    np.testing.assert_allclose(e, [rot.quat_to_euler(x) for x in q], rtol=0.0, atol=1e-15)


def test_strapdown_position_step_is_ned_to_dllh_of_the_trapezoid_displacement():
    """strapdown.mechanize inlines the position update (hot loop): the same formula as earth.ned_to_dllh with the
    meridian radius at the start latitude and the prime-vertical radius at the mid latitude, both at the mid
    height."""
    from zennav.nav.strapdown import NavState, mechanize

    s = NavState(math.radians(30.0), math.radians(114.0), 50.0, 20.0, -7.0, 0.5, 1.0, 0.0, 0.0, 0.0)
    s0, dt = s.copy(), 0.01
    mechanize(s, (0.0, 0.0, 0.0), (0.01, -0.02, -0.0980665), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), dt)
    d_ned = (0.5 * (s0.vn + s.vn) * dt, 0.5 * (s0.ve + s.ve) * dt, 0.5 * (s0.vd + s.vd) * dt)
    hm = 0.5 * (s0.h + s.h)
    assert s.h - s0.h == pytest.approx(earth.ned_to_dllh(d_ned, s0.lat, hm)[2], rel=1e-9)
    assert s.lat - s0.lat == pytest.approx(earth.ned_to_dllh(d_ned, s0.lat, hm)[0], rel=1e-12)
    latm = 0.5 * (s0.lat + s.lat)
    assert s.lon - s0.lon == pytest.approx(earth.ned_to_dllh(d_ned, latm, hm)[1], rel=1e-12)
