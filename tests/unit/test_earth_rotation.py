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
