"""Loaders on the real recordings in the shared data folder (rtklibexplorer drive_0708, comma2k19 segment).

Skipped, with the reason, only when the data folder is absent."""
from __future__ import annotations

import math
import shutil
import time
from datetime import datetime

import numpy as np
import pytest

from zennav.datasets import comma2k19, kfgins, registry, rtklibexplorer
from zennav.datasets.errors import DataError
from zennav.nav import earth
from zennav.nav.rotation import dcm_to_euler, euler_to_dcm, rotvec_to_dcm, wrap_angle
from zennav.nav.types import NS, FixType


def _folder(name: str):
    try:
        folder = registry.data_root() / name
    except DataError as exc:
        pytest.skip(f"shared data folder not found ({exc})")
    if not folder.is_dir():
        pytest.skip(f"data folder {folder} is absent")
    return folder


def gps_ns(text: str) -> int:
    """'YYYY-mm-dd HH:MM:SS.fff' read as GPST -> GPS ns since 1980-01-06."""
    delta = datetime.fromisoformat(text) - datetime(1980, 1, 6)
    return (delta.days * 86400 + delta.seconds) * NS + delta.microseconds * 1000


def rates(imu):
    """Mean angular rate [rad/s] and specific force [m/s^2] over each interval (from the increments)."""
    dt = (np.diff(imu.t_ns) / NS)[:, None]
    return imu.dtheta[1:] / dt, imu.dvel[1:] / dt


@pytest.fixture(scope="module")
def rtk_folder():
    return _folder("rtklibexplorer_drive_0708")


@pytest.fixture(scope="module")
def rtk(rtk_folder):
    start = time.perf_counter()
    ds = rtklibexplorer.load(rtk_folder)
    ds.notes["test_load_s"] = time.perf_counter() - start
    return ds


@pytest.fixture(scope="module")
def comma():
    return comma2k19.load(_folder("comma2k19_example_segment"))


# ------------------------------------------------------------------------------------ rtklibexplorer


def test_rtk_counts_rates_and_times(rtk):
    assert len(rtk.imu) == 54858  # first and last csv rows skipped, as the source converter
    assert 99.5 < rtk.notes["imu_rate_hz"] < 100.5
    assert len(rtk.gnss) == 2197 and rtk.notes["gnss_rate_hz"] == pytest.approx(4.0)
    assert np.count_nonzero(rtk.gnss.fix == FixType.RTK_FIXED) == 2189
    assert np.count_nonzero(rtk.gnss.fix == FixType.RTK_FLOAT) == 8
    assert rtk.gnss.num_sats[0] == 21
    # tag start 1752003261.854 (Unix-style count in GPST) = 2025-07-08 19:34:21.854 GPST, minus 0.125 s delay
    assert rtk.imu.t_ns[0] == gps_ns("2025-07-08 19:34:21.729")
    # last row: start + 548.731 s (last tag tick) - 0.125 s
    assert rtk.imu.t_ns[-1] == gps_ns("2025-07-08 19:34:21.854") + 548_731_000_000 - 125_000_000
    assert rtk.gnss.t_ns[0] == gps_ns("2025-07-08 19:34:18.499")
    assert rtk.gnss.t_ns[-1] == gps_ns("2025-07-08 19:43:27.499")
    overlap_s = (min(rtk.imu.t_ns[-1], rtk.gnss.t_ns[-1]) - max(rtk.imu.t_ns[0], rtk.gnss.t_ns[0])) / NS
    assert overlap_s > 540.0
    assert rtk.notes["test_load_s"] < 3.0


def test_rtk_stationary_specific_force_is_minus_g_in_frd(rtk):
    """The axis mapping (Groves Euler_to_CTM of imu_misalign) must give f_b ~ (0, 0, -g) at rest."""
    _, f_b = rates(rtk.imu)
    still = rtk.imu.t_ns[1:] < gps_ns("2025-07-08 19:34:55")  # the car starts to move at 19:34:56
    mean = f_b[still].mean(axis=0)
    g = earth.gravity(rtk.initial.llh[0], rtk.initial.llh[2])
    assert abs(mean[2] + g) < 0.15  # measured -9.93 vs g 9.797: accel scale/bias of a consumer MEMS
    # measured (-0.01, +0.20): the README's misalignment has no roll term and the car may stand on a side slope;
    # the transposed rotation would give 2.3 m/s^2 forward
    assert abs(mean[0]) < 0.15 and abs(mean[1]) < 0.25


def test_rtk_prefilter_is_zero_phase_lowpass(rtk_folder, rtk):
    raw = rtklibexplorer.load(rtk_folder, prefilter="none")
    w_raw, f_raw = rates(raw.imu)
    w_filt, f_filt = rates(rtk.imu)
    still = slice(100, 3000)
    # the engine-vibration noise on the gyro is mostly above 10 Hz: the filter removes most of it
    assert (w_filt[still].std(axis=0) < 0.6 * w_raw[still].std(axis=0))[:2].all()
    np.testing.assert_allclose(w_filt[still].mean(axis=0), w_raw[still].mean(axis=0), atol=2e-4)
    np.testing.assert_allclose(f_filt[still].mean(axis=0), f_raw[still].mean(axis=0), atol=5e-3)
    # zero phase: no lag between the filtered and raw yaw rate while driving
    moving = slice(6000, 20000)
    lags = range(-5, 6)
    corr = [np.corrcoef(np.roll(w_filt[moving, 2], lag), w_raw[moving, 2])[0, 1] for lag in lags]
    assert lags[int(np.argmax(corr))] == 0
    np.testing.assert_array_equal(raw.imu.t_ns, rtk.imu.t_ns)


def test_rtk_gnss_velocity_is_ned(rtk):
    """Height change must follow -v_down: the NEU -> NED flip of vu (the drive is on a hill)."""
    g = rtk.gnss
    t = g.t_ns / NS
    climb = np.gradient(g.llh[:, 2], t)
    assert np.corrcoef(climb, -g.v_n[:, 2])[0, 1] > 0.9
    lat0, lon0 = g.llh[0, :2]
    r_m, r_n = earth.radii(lat0)
    north = np.gradient(g.llh[:, 0], t) * r_m
    east = np.gradient(g.llh[:, 1], t) * r_n * math.cos(lat0)
    assert np.corrcoef(north, g.v_n[:, 0])[0, 1] > 0.99 and np.corrcoef(east, g.v_n[:, 1])[0, 1] > 0.99


def test_rtk_imu_time_aligns_with_gnss(rtk):
    """The gyro yaw rate and the GNSS course rate line up in time: the tag mapping plus the -0.125 s logging
    delay leave a lag of a few tens of ms (without the delay it would be about 155 ms)."""
    imu, g = rtk.imu, rtk.gnss
    w_b, _ = rates(imu)
    t_mid = imu.t_ns[1:] - np.diff(imu.t_ns) // 2  # a rate over an interval belongs to its middle
    moving = np.hypot(g.v_n[:, 0], g.v_n[:, 1]) > 3.0
    course_rate = np.gradient(np.unwrap(np.arctan2(g.v_n[:, 1], g.v_n[:, 0])), g.t_ns / NS)
    lags_ms = np.arange(-300, 301, 10)
    corr = [np.corrcoef(np.interp(g.t_ns + lag * 1_000_000, t_mid, w_b[:, 2])[moving], course_rate[moving])[0, 1]
            for lag in lags_ms]
    assert max(corr) > 0.98  # z down: a right turn is a positive yaw rate in both
    assert abs(lags_ms[int(np.argmax(corr))]) <= 60


def test_rtk_initial_state(rtk):
    init, g = rtk.initial, rtk.gnss
    speed = np.hypot(g.v_n[:, 0], g.v_n[:, 1])
    k = int(np.argmax(speed > 2.0))
    assert g.t_ns[k] == gps_ns("2025-07-08 19:34:58.999")
    assert g.t_ns[k] < init.t_ns == rtk.config.start_t_ns < g.t_ns[k] + 20_000_000
    assert init.t_ns in set(rtk.imu.t_ns.tolist())
    assert 2.0 < np.hypot(*init.v_n[:2]) < 2.2
    # the IMU position plus the lever arm is the antenna position
    antenna = earth.ned_to_llh(euler_to_dcm(init.euler) @ rtk.config.lever_arm_b, init.llh)
    assert np.linalg.norm(earth.llh_to_ned(antenna, g.llh[k])) < 0.05
    np.testing.assert_allclose(rtk.config.lever_arm_b, [0.0, -0.05, 0.0])
    # roll/pitch from levelling: the stationary specific force rotated to n is vertical
    f_b = np.array(rtk.notes["stationary_f_b_mps2"])
    f_n = euler_to_dcm(init.euler) @ f_b
    assert np.hypot(f_n[0], f_n[1]) < 1e-9
    np.testing.assert_allclose(init.std_euler, np.deg2rad([1, 1, 3]))
    assert (init.std_pos_ned >= 0.05).all()


def test_rtk_initial_yaw_agrees_with_gnss_course_after_gyro_propagation(rtk):
    """The car turns while leaving rest (course changes ~10 deg/s at the start), so check that the initial
    yaw, carried forward with the gyros, matches the GNSS course on the straight road 17-27 s later."""
    imu, g, init = rtk.imu, rtk.gnss, rtk.initial
    w_b, _ = rates(imu)
    still = imu.t_ns[1:] < gps_ns("2025-07-08 19:34:55")
    bias = w_b[still].mean(axis=0)
    k0 = int(np.searchsorted(imu.t_ns, init.t_ns))
    C_nb = euler_to_dcm(init.euler)
    t_end = init.t_ns + 27 * NS
    yaw = {}
    for k in range(k0 + 1, int(np.searchsorted(imu.t_ns, t_end))):
        dt = (imu.t_ns[k] - imu.t_ns[k - 1]) / NS
        C_nb = C_nb @ rotvec_to_dcm(imu.dtheta[k] - bias * dt)
        yaw[int(imu.t_ns[k])] = dcm_to_euler(C_nb)[2]
    straight = (g.t_ns > init.t_ns + 17 * NS) & (g.t_ns < t_end)
    course = np.arctan2(g.v_n[straight, 1], g.v_n[straight, 0])
    t_imu = np.array(list(yaw))
    yaw_at = np.interp(g.t_ns[straight], t_imu, np.unwrap(list(yaw.values())))
    error_deg = np.degrees(wrap_angle(yaw_at - course))
    assert np.abs(np.median(error_deg)) < 2.0, error_deg


def test_rtk_truth_is_rtk_fixed_antenna_positions(rtk):
    assert len(rtk.truth.t_ns) == 2189 and rtk.truth.euler is None and rtk.truth.at_antenna
    assert "not independent" in rtk.truth.source


def test_rtk_converted_to_kfgins_files_loads_the_same(rtk, tmp_path):
    back = kfgins.load_config(kfgins.write_dataset(rtk, tmp_path))
    week = int(rtk.imu.t_ns[0] // kfgins.WEEK_NS)
    shift = week * kfgins.WEEK_NS
    keep = rtk.imu.t_ns >= rtk.initial.t_ns
    np.testing.assert_array_equal(back.imu.t_ns + shift, rtk.imu.t_ns[keep])
    np.testing.assert_array_equal(back.imu.dtheta, rtk.imu.dtheta[keep])
    np.testing.assert_array_equal(back.imu.dvel, rtk.imu.dvel[keep])
    after = rtk.gnss.t_ns > rtk.initial.t_ns
    np.testing.assert_array_equal(back.gnss.t_ns + shift, rtk.gnss.t_ns[after])
    np.testing.assert_allclose(back.gnss.llh[:, :2], rtk.gnss.llh[after, :2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.gnss.v_n, rtk.gnss.v_n[after], rtol=0, atol=1e-9)
    assert back.initial.t_ns + shift == rtk.initial.t_ns
    np.testing.assert_allclose(back.initial.llh[:2], rtk.initial.llh[:2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.initial.euler, rtk.initial.euler, rtol=1e-13)
    np.testing.assert_allclose(back.initial.std_gyro_bias, rtk.initial.std_gyro_bias, rtol=1e-13)
    assert back.config.imu_noise.arw == pytest.approx(rtk.config.imu_noise.arw, rel=1e-14)
    assert back.truth.at_antenna and back.truth.euler is None and len(back.truth.t_ns) == 2189


def test_rtk_bad_lines_in_real_files_are_named(rtk_folder, tmp_path):
    folder = tmp_path / "drive"
    shutil.copytree(rtk_folder, folder)
    for path in folder.iterdir():
        path.chmod(0o644)
    pos = folder / "gnss_1934_sf.pos"
    lines = pos.read_text().splitlines()
    lines[99] = lines[99].replace("40.0966", "4O.0966", 1)
    pos.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"gnss_1934_sf\.pos:100: cannot parse '4O\.0966\d*' in column 3"):
        rtklibexplorer.load(folder)
    lines[99] = lines[99].replace("4O.0966", "40.0966").replace("2025/07/08", "2025/13/08")
    pos.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"gnss_1934_sf\.pos:100: cannot parse date/time '2025/13/08"):
        rtklibexplorer.load(folder)
    csv = folder / "imu_1934.csv"
    rows = csv.read_text().splitlines()
    rows[500] = rows[500].rsplit(",", 1)[0]
    csv.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"imu_1934\.csv:501: line has 6 columns, expected 7"):
        rtklibexplorer.load_imu(csv)


# ------------------------------------------------------------------------------------ comma2k19


def test_comma_imu_rate_and_time(comma):
    assert 103.5 < comma.notes["imu_rate_hz"] < 105.0
    assert len(comma.imu) == 6256
    week, tow = divmod(comma.imu.t_ns[0], kfgins.WEEK_NS)
    assert week == 2012 and 404106 * NS < tow < 404107 * NS  # README: GPS week 2012, TOW 404106-404166 s
    assert comma.notes["boot_to_gps_fit_residual_s"] < 1e-6
    _, f_b = rates(comma.imu)
    np.testing.assert_allclose(f_b.mean(axis=0), [-0.57, -0.13, -9.66], atol=0.02)  # README segment mean, FRD


def test_comma_gnss_agrees_with_truth(comma):
    truth = comma.truth
    g = comma.gnss.slice((comma.gnss.t_ns >= truth.t_ns[0]) & (comma.gnss.t_ns <= truth.t_ns[-1]))
    assert len(g) > 570  # of 579: the fix time is utc_timestamp + 18 s, within the pose's time span
    ref = np.column_stack([np.interp(g.t_ns, truth.t_ns, truth.llh[:, i]) for i in range(3)])
    ned = np.array([earth.llh_to_ned(g.llh[k], ref[k]) for k in range(len(g))])
    assert math.sqrt(np.mean(ned[:, 0] ** 2 + ned[:, 1] ** 2)) < 3.0  # measured 2.09 m
    assert abs(ned[:, 2].mean()) < 3.0  # altitude is ellipsoidal (MSL would be ~32 m off)
    v_ref = np.column_stack([np.interp(g.t_ns, truth.t_ns, truth.v_n[:, i]) for i in range(2)])
    assert np.sqrt(np.mean(np.sum((g.v_n[:, :2] - v_ref) ** 2, axis=1))) < 0.5


def test_comma_truth_attitude_is_ned_and_matches_motion(comma):
    truth = comma.truth
    speed = np.hypot(truth.v_n[:, 0], truth.v_n[:, 1])
    course = np.arctan2(truth.v_n[:, 1], truth.v_n[:, 0])
    assert speed.min() > 5.0
    assert np.abs(np.degrees(wrap_angle(truth.euler[:, 2] - course))).max() < 3.0  # measured about 0.9
    assert np.abs(np.degrees(truth.euler[:, :2])).max() < 10.0  # a car on a highway is nearly level
    # the gyro's z (down) rate follows the truth's yaw rate: FRD axes and sign
    w_b, _ = rates(comma.imu)
    yaw_rate = np.gradient(np.unwrap(truth.euler[:, 2]), truth.t_ns / NS)
    w_z = np.interp(truth.t_ns, comma.imu.t_ns[1:], w_b[:, 2])
    assert np.corrcoef(w_z, yaw_rate)[0, 1] > 0.7


def test_comma_initial_state_from_truth(comma):
    init, truth = comma.initial, comma.truth
    assert init.t_ns == comma.imu.t_ns[0] == comma.config.start_t_ns and truth.t_ns[0] <= init.t_ns
    k = int(np.searchsorted(truth.t_ns, init.t_ns))
    assert np.linalg.norm(earth.llh_to_ned(init.llh, truth.llh[k])) < 1.0
    np.testing.assert_allclose(init.v_n, truth.v_n[k], atol=0.2)
    np.testing.assert_allclose(init.euler, truth.euler[k], atol=math.radians(0.5))
    np.testing.assert_allclose(init.std_euler, np.deg2rad([2, 2, 5]))
    np.testing.assert_array_equal(comma.config.lever_arm_b, np.zeros(3))
    assert "assumed" in comma.notes["gnss_std_assumed"]


# ------------------------------------------------------------------------------------ registry


def test_registry_specs(rtk_folder, monkeypatch):
    assert {"rtklibexplorer", "comma2k19", "sim:car"} <= set(registry.available())
    assert len(registry.load_dataset("rtklibexplorer", prefilter="none").imu) == 54858
    assert registry.load_dataset(str(rtk_folder)).name == "rtklibexplorer_drive_0708"
    with pytest.raises(DataError, match=r"^nonsense: unknown dataset; accepted: rtklibexplorer, comma2k19, .*sim:car"):
        registry.load_dataset("nonsense")
    with pytest.raises(DataError, match=r"sim:boat: unknown simulator scenario"):
        registry.load_dataset("sim:boat")
    monkeypatch.setenv("ZENNAV_DATA", str(rtk_folder / "missing"))
    with pytest.raises(DataError, match="ZENNAV_DATA is not a directory"):
        registry.data_root()
    monkeypatch.setenv("ZENNAV_DATA", str(rtk_folder.parent))
    assert registry.data_root() == rtk_folder.parent
