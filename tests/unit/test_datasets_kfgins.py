"""KF-GINS text files and YAML: write/read round trips, unit conversion of the configuration, and user errors
that must come back as one DataError naming the file and the line."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from zennav.datasets import kfgins
from zennav.datasets.errors import DataError
from zennav.nav.types import NS, Dataset, FixType, GnssData, ImuData, ImuNoise, InitialState, NavConfig, Truth

SOW0 = 456300.0  # seconds of week of the first IMU sample, as in the KF-GINS demo


def make_dataset(seed: int = 7, n_imu: int = 400, week: int = 0) -> Dataset:
    """A small random dataset at 200 Hz IMU / 1 Hz GNSS with irregular nanosecond times (seeded)."""
    rng = np.random.default_rng(seed)
    t0 = week * kfgins.WEEK_NS + int(SOW0 * NS)
    imu_t = t0 + np.cumsum(np.r_[0, rng.integers(4_990_000, 5_010_000, n_imu - 1)])
    imu = ImuData(imu_t, rng.normal(0, 1e-3, (n_imu, 3)), rng.normal(0, 5e-2, (n_imu, 3)) + [0, 0, -0.049])
    m = 2
    gnss_t = t0 + np.array([1, 1 + NS // 1000 * 999]) + NS // 2  # 0.5 s and 1.499 s after the start
    lat = np.deg2rad(30.4447873701 + rng.normal(0, 1e-6, m))
    lon = np.deg2rad(114.4718632047 + rng.normal(0, 1e-6, m))
    llh = np.column_stack([lat, lon, 20.9 + rng.normal(0, 0.01, m)])
    gnss = GnssData(gnss_t, llh, rng.uniform(0.005, 0.02, (m, 3)), rng.normal(0, 1, (m, 3)),
                    rng.uniform(0.01, 0.05, (m, 3)))
    t_truth = imu_t[::20]
    k = len(t_truth)
    euler = rng.uniform(-math.pi, math.pi, (k, 3)) * [0.1, 0.1, 1]
    truth = Truth(t_truth, np.repeat(llh[:1], k, axis=0), rng.normal(0, 1, (k, 3)), euler, "test truth")
    noise = ImuNoise(arw=1e-5, vrw=2e-4, gyro_bias_std=3e-6, accel_bias_std=4e-4,
                     gyro_bias_tau=7200.0, accel_bias_tau=3600.0)
    initial = InitialState(
        t_ns=int(imu_t[5]),
        llh=llh[0].copy(),
        v_n=np.array([0.1, -0.2, 0.01]),
        euler=np.array([0.0149, -0.0355, 3.2411 - 2 * math.pi]),
        std_pos_ned=np.array([0.005, 0.004, 0.008]),
        std_v_n=np.array([0.003, 0.004, 0.004]),
        std_euler=np.deg2rad([0.003, 0.003, 0.023]),
        gyro_bias=np.array([1e-6, -2e-6, 3e-6]),
        accel_bias=np.array([1e-4, 2e-4, -3e-4]),
        std_gyro_bias=np.full(3, 5e-6),
        std_accel_bias=None,
    )
    config = NavConfig(imu_noise=noise, lever_arm_b=np.array([0.136, -0.301, -0.184]), start_t_ns=initial.t_ns)
    return Dataset("synthetic", imu, gnss, config, initial, truth)


def test_dataerror_str_names_file_and_line():
    assert str(DataError("a/b.txt", "bad value", 12)) == "a/b.txt:12: bad value"
    assert str(DataError("a/b.txt", "file not found")) == "a/b.txt: file not found"
    err = DataError("x.yaml", "m", 3)
    assert (err.path, err.line, err.message) == ("x.yaml", 3, "m")


@pytest.mark.parametrize("week", [0, 2373])
def test_imu_gnss_nav_round_trip_is_exact(tmp_path, week):
    ds = make_dataset(week=week)
    kfgins.write_imu(tmp_path / "imu.txt", ds.imu, week)
    kfgins.write_gnss(tmp_path / "gnss.txt", ds.gnss, week, tmp_path / "vel.txt")
    tr = ds.truth
    kfgins.write_nav(tmp_path / "truth.nav", week, tr.t_ns, tr.llh, tr.v_n, tr.euler)
    shift = week * kfgins.WEEK_NS  # the files hold seconds of week

    imu = kfgins.load_imu(tmp_path / "imu.txt")
    np.testing.assert_array_equal(imu.t_ns, ds.imu.t_ns - shift)
    np.testing.assert_allclose(imu.dtheta, ds.imu.dtheta, rtol=1e-15, atol=0)
    np.testing.assert_allclose(imu.dvel, ds.imu.dvel, rtol=1e-15, atol=0)

    gnss = kfgins.load_gnss(tmp_path / "gnss.txt", tmp_path / "vel.txt")
    np.testing.assert_array_equal(gnss.t_ns, ds.gnss.t_ns - shift)
    np.testing.assert_allclose(gnss.llh[:, :2], ds.gnss.llh[:, :2], rtol=0, atol=1e-15)  # 1e-13 deg written
    np.testing.assert_allclose(gnss.llh[:, 2], ds.gnss.llh[:, 2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(gnss.std_ned, ds.gnss.std_ned, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gnss.v_n, ds.gnss.v_n, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gnss.std_v_n, ds.gnss.std_v_n, rtol=0, atol=1e-9)
    assert (gnss.fix == int(FixType.SINGLE)).all() and (gnss.num_sats == -1).all()

    truth = kfgins.load_nav(tmp_path / "truth.nav")
    np.testing.assert_array_equal(truth.t_ns, tr.t_ns - shift)
    np.testing.assert_allclose(truth.llh[:, :2], tr.llh[:, :2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(truth.v_n, tr.v_n, rtol=0, atol=1e-9)
    np.testing.assert_allclose(truth.euler, tr.euler, rtol=0, atol=1e-13)
    assert (tmp_path / "truth.nav").read_text().split()[0] == str(week)


def test_gnss_13_columns_in_kfgins_loader_order(tmp_path):
    # KF-GINS GnssFileLoader: sow, lat, lon, h, vn, ve, vd, std n e d, std vn ve vd
    (tmp_path / "g.txt").write_text("100.5 30.0 114.0 20.0 1.0 2.0 3.0 0.1 0.2 0.3 0.01 0.02 0.03\n"
                                    "101.5,30.0,114.0,20.0,1.0,2.0,3.0,0.1,0.2,0.3,0.01,0.02,0.03\n")
    gnss = kfgins.load_gnss(tmp_path / "g.txt")
    np.testing.assert_array_equal(gnss.t_ns, [100_500_000_000, 101_500_000_000])
    np.testing.assert_allclose(gnss.v_n[1], [1, 2, 3])
    np.testing.assert_allclose(gnss.std_ned[1], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(gnss.std_v_n[0], [0.01, 0.02, 0.03])
    np.testing.assert_allclose(gnss.llh[0], [math.radians(30), math.radians(114), 20])


def write_demo(folder, imu_rows=None, gnss_rows=None, **overrides) -> Path:
    """A KF-GINS demo-like configuration (the repo's dataset/kf-gins.yaml values) with small data files."""
    imu_rows = imu_rows or [f"{SOW0 + 0.005 * k:.3f} 1e-5 -2e-5 3e-5 1e-3 2e-3 -0.049" for k in range(-2, 10)]
    gnss_rows = gnss_rows or [f"{SOW0 + s:.3f} 30.4447858 114.4718661 21.09 0.010 0.009 0.019"
                              for s in (0.0, 0.02, 0.04)]
    (folder / "imu.txt").write_text("\n".join(imu_rows) + "\n")
    (folder / "gnss.txt").write_text("\n".join(gnss_rows) + "\n")
    config = {
        "imupath": "imu.txt", "gnsspath": "gnss.txt", "outputpath": ".", "imudatalen": 7, "imudatarate": 200,
        "starttime": SOW0, "endtime": -1,
        "initpos": [30.4447873701, 114.4718632047, 20.899], "initvel": [0.0, 0.0, 0.0],
        "initatt": [0.85421502, -2.03480295, 185.70235133],
        "initgyrbias": [0, 0, 0], "initaccbias": [0, 0, 0], "initgyrscale": [0, 0, 0], "initaccscale": [0, 0, 0],
        "initposstd": [0.005, 0.004, 0.008], "initvelstd": [0.003, 0.004, 0.004], "initattstd": [0.003, 0.003, 0.023],
        "imunoise": {"arw": [0.003, 0.003, 0.003], "vrw": [0.03, 0.03, 0.03], "gbstd": [0.027, 0.027, 0.027],
                     "abstd": [15.0, 15.0, 15.0], "gsstd": [300.0] * 3, "asstd": [300.0] * 3, "corrtime": 4.0},
        "antlever": [0.136, -0.301, -0.184],
    }
    config.update(overrides)
    path = folder / "kf-gins.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False, default_flow_style=None))
    return path


def test_config_units_converted_to_si(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path.parent)  # relative paths resolve against the YAML folder when not in the cwd
    ds = kfgins.load_config(write_demo(tmp_path, initgyrbias=[36.0, 0, 0], initaccbias=[0, 0, 100.0]))
    noise, init = ds.config.imu_noise, ds.initial
    assert noise.arw == pytest.approx(0.003 * math.pi / 180 / 60, rel=1e-14)  # deg/sqrt(h) -> rad/sqrt(s)
    assert noise.vrw == pytest.approx(0.03 / 60, rel=1e-14)  # m/s/sqrt(h) -> m/s/sqrt(s)
    assert noise.gyro_bias_std == pytest.approx(0.027 * math.pi / 180 / 3600, rel=1e-14)  # deg/h -> rad/s
    assert noise.accel_bias_std == pytest.approx(15e-5, rel=1e-14)  # mGal -> m/s^2
    assert noise.gyro_bias_tau == noise.accel_bias_tau == 4 * 3600.0
    np.testing.assert_allclose(init.llh, [math.radians(30.4447873701), math.radians(114.4718632047), 20.899],
                               rtol=1e-15)
    np.testing.assert_allclose(init.euler, np.deg2rad([0.85421502, -2.03480295, 185.70235133]), rtol=1e-15)
    np.testing.assert_allclose(init.std_euler, np.deg2rad([0.003, 0.003, 0.023]), rtol=1e-15)
    np.testing.assert_allclose(init.gyro_bias, [math.radians(36) / 3600, 0, 0], rtol=1e-15)
    np.testing.assert_allclose(init.accel_bias, [0, 0, 1e-3], rtol=1e-15)
    # without initbgstd/initbastd the initial bias std is gbstd/abstd, as in KF-GINS
    np.testing.assert_allclose(init.std_gyro_bias, np.full(3, noise.gyro_bias_std), rtol=1e-15)
    np.testing.assert_allclose(init.std_accel_bias, np.full(3, 15e-5), rtol=1e-15)
    np.testing.assert_allclose(ds.config.lever_arm_b, [0.136, -0.301, -0.184])
    # window: IMU from starttime on, GNSS strictly after it; initial state at the first IMU sample
    assert ds.imu.t_ns[0] == init.t_ns == ds.config.start_t_ns == int(SOW0 * NS)
    assert len(ds.imu) == 10 and ds.config.end_t_ns is None  # endtime -1: to the last IMU sample
    np.testing.assert_array_equal(ds.gnss.t_ns, [int((SOW0 + 0.02) * NS), int((SOW0 + 0.04) * NS)])
    assert ds.notes["imu_rate_hz"] == 200
    # scale factors [ppm -> -]: KF-GINS's 21-state model (without initsgstd/initsastd their std is gsstd/asstd)
    assert noise.gyro_scale_std == noise.accel_scale_std == pytest.approx(300e-6, rel=1e-14)
    assert noise.gyro_scale_tau == noise.accel_scale_tau == 4 * 3600.0
    assert init.std_gyro_scale is None and not any("scale" in r for r in ds.notes["remarks"])
    ds = kfgins.load_config(write_demo(tmp_path, initgyrscale=[1000.0, 0, 0], initsastd=[50.0] * 3))
    np.testing.assert_allclose(ds.initial.gyro_scale, [1e-3, 0, 0], rtol=1e-15)
    np.testing.assert_allclose(ds.initial.std_accel_scale, np.full(3, 50e-6), rtol=1e-15)


def test_config_options_window_and_cwd_first(tmp_path, monkeypatch):
    other = tmp_path / "cwd"
    other.mkdir()
    path = write_demo(tmp_path, endtime=SOW0 + 0.02, initbgstd=[1.0, 1.0, 1.0], initbastd=[50.0] * 3)
    # KF-GINS resolves relative paths against the current directory first
    (other / "imu.txt").write_text("".join(f"{SOW0 + 0.01 * k:.3f} 0 0 0 0 0 -0.098\n" for k in range(5)))
    monkeypatch.chdir(other)
    ds = kfgins.load_config(path)
    assert len(ds.imu) == 3 and (ds.imu.dvel[:, 2] == -0.098).all()
    assert ds.config.end_t_ns == int(round((SOW0 + 0.02) * 1e9))  # endtime
    assert len(ds.gnss) == 1  # (starttime, endtime]
    np.testing.assert_allclose(ds.initial.std_gyro_bias, np.full(3, math.radians(1) / 3600), rtol=1e-15)
    np.testing.assert_allclose(ds.initial.std_accel_bias, np.full(3, 50e-5), rtol=1e-15)


def test_write_dataset_then_load_config_reproduces_the_dataset(tmp_path):
    ds = make_dataset(week=2373)
    back = kfgins.load_config(kfgins.write_dataset(ds, tmp_path))
    shift = 2373 * kfgins.WEEK_NS
    keep = ds.imu.t_ns >= ds.initial.t_ns
    np.testing.assert_array_equal(back.imu.t_ns, ds.imu.t_ns[keep] - shift)
    np.testing.assert_array_equal(back.imu.dtheta, ds.imu.dtheta[keep])
    np.testing.assert_array_equal(back.imu.dvel, ds.imu.dvel[keep])
    np.testing.assert_array_equal(back.gnss.t_ns, ds.gnss.t_ns - shift)
    a, b = back.initial, ds.initial
    assert a.t_ns == b.t_ns - shift == back.config.start_t_ns
    for name in ("llh", "v_n", "euler", "std_pos_ned", "std_v_n", "std_euler", "gyro_bias", "accel_bias",
                 "std_gyro_bias"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-14, atol=1e-15, err_msg=name)
    # no initbastd written: KF-GINS falls back to abstd
    np.testing.assert_allclose(a.std_accel_bias, np.full(3, ds.config.imu_noise.accel_bias_std), rtol=1e-14)
    for name in ("arw", "vrw", "gyro_bias_std", "accel_bias_std", "gyro_bias_tau", "accel_bias_tau"):
        assert getattr(back.config.imu_noise, name) == pytest.approx(getattr(ds.config.imu_noise, name), rel=1e-14)
    np.testing.assert_array_equal(back.config.lever_arm_b, ds.config.lever_arm_b)
    np.testing.assert_allclose(back.truth.euler, ds.truth.euler, atol=1e-13)
    assert back.truth.source == "test truth"


def test_truth_without_attitude_round_trips_as_none(tmp_path):
    ds = make_dataset()
    ds.truth.euler = None
    ds.truth.at_antenna = True
    back = kfgins.load_config(kfgins.write_dataset(ds, tmp_path))
    assert back.truth.euler is None and back.truth.v_n is not None and back.truth.at_antenna


# ------------------------------------------------------------------------------------- user errors


def good_imu(n=8):
    return [f"{SOW0 + 0.005 * k:.3f} 1e-5 -2e-5 3e-5 1e-3 2e-3 -0.049" for k in range(n)]


def with_line(rows, number, text):
    rows = list(rows)
    rows[number - 1] = text
    return rows


@pytest.mark.parametrize(
    "rows, line, words",
    [
        (with_line(good_imu(), 3, f"{SOW0 + 0.010:.3f} 1e-5 -2e-5 3e-5 1e-3 2e-3"), 3, "6 columns, expected 7"),
        (with_line(good_imu(), 4, f"{SOW0 + 0.015:.3f} 1e-5 abc 3e-5 1e-3 2e-3 -0.049"), 4, "'abc'"),
        (with_line(good_imu(), 5, f"{SOW0 + 0.020:.3f} 1e-5 nan 3e-5 1e-3 2e-3 -0.049"), 5, "NaN or infinite"),
        (with_line(good_imu(), 6, f"{SOW0 + 0.020:.3f} 1e-5 0 3e-5 1e-3 inf -0.049"), 6, "NaN or infinite"),
        (with_line(good_imu(), 7, f"{SOW0 + 0.025:.3f} 0 0 0 0 0 0"), 7, "not after the previous"),
        (["# header comment", ""] + with_line(good_imu(), 2, "1 2 3"), 4, "3 columns"),
        ([" ".join(["1"] * 6)] * 3, 1, "6 columns, expected 7"),
    ],
)
def test_bad_imu_file_names_file_and_line(tmp_path, rows, line, words):
    (tmp_path / "my_imu.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError) as info:
        kfgins.load_imu(tmp_path / "my_imu.txt")
    message = str(info.value)
    assert f"my_imu.txt:{line}: " in message and words in message and "\n" not in message
    assert info.value.line == line


def test_bad_gnss_and_velocity_files(tmp_path):
    rows = [f"{SOW0 + s} 30.4 114.4 21.0 0.01 0.01 0.02" for s in range(4)]
    (tmp_path / "g.txt").write_text("\n".join(with_line(rows, 3, rows[2] + " 0.5")) + "\n")
    with pytest.raises(DataError, match=r"g\.txt:3: line has 8 columns, expected 7 like the first"):
        kfgins.load_gnss(tmp_path / "g.txt")
    (tmp_path / "g.txt").write_text("\n".join(with_line(rows, 2, f"{SOW0 + 1} 30.4 114.4 21.0 0.01 0 0.02")) + "\n")
    with pytest.raises(DataError, match=r"g\.txt:2: position std must be positive"):
        kfgins.load_gnss(tmp_path / "g.txt")
    (tmp_path / "g.txt").write_text("\n".join(with_line(rows, 4, f"{SOW0 + 3} 114.4 300.4 21.0 0.01 0.01 0.02")) + "\n")
    with pytest.raises(DataError, match=r"g\.txt:4: latitude 114.4"):
        kfgins.load_gnss(tmp_path / "g.txt")
    (tmp_path / "g.txt").write_text("\n".join(rows) + "\n")
    vel = [f"{SOW0 + s} 1.0 2.0 0.0 0.05 0.05 0.1" for s in range(4)]
    (tmp_path / "v.txt").write_text("\n".join(with_line(vel, 2, f"{SOW0 + 1.5} 1.0 2.0 0.0 0.05 0.05 0.1")) + "\n")
    with pytest.raises(DataError,
                       match=r"v\.txt:2: time 456301\.500000000 s does not match the GNSS epoch 456301\.000000000 s"):
        kfgins.load_gnss(tmp_path / "g.txt", tmp_path / "v.txt")
    (tmp_path / "v.txt").write_text("\n".join(vel[:3]) + "\n")
    with pytest.raises(DataError, match=r"v\.txt: 3 velocity rows for 4 GNSS epochs"):
        kfgins.load_gnss(tmp_path / "g.txt", tmp_path / "v.txt")
    (tmp_path / "empty.txt").write_text("# nothing\n\n")
    with pytest.raises(DataError, match=r"empty\.txt: no data rows"):
        kfgins.load_gnss(tmp_path / "empty.txt")
    with pytest.raises(DataError, match=r"missing\.txt: file not found"):
        kfgins.load_gnss(tmp_path / "missing.txt")
    (tmp_path / "t.nav").write_text("0 1 30 114 20 0 0 0 0 0\n")
    with pytest.raises(DataError, match=r"t\.nav:1: line has 10 columns, expected 11"):
        kfgins.load_nav(tmp_path / "t.nav")


def test_yaml_errors_name_the_yaml_and_the_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = write_demo(tmp_path)
    lines = path.read_text().splitlines()

    def expect(text, pattern):
        path.write_text(text)
        with pytest.raises(DataError, match=pattern) as info:
            kfgins.load_config(path)
        assert "kf-gins.yaml" in str(info.value) and "\n" not in str(info.value)

    number = next(i for i, l in enumerate(lines, 1) if l.startswith("initatt:"))
    expect("\n".join(l for l in lines if not l.startswith("initatt:")),
           r"kf-gins\.yaml: missing required key 'initatt'")
    expect("\n".join(l for l in lines if "corrtime" not in l),
           r"kf-gins\.yaml:\d+: missing required key 'imunoise\.corrtime'")
    expect("\n".join(with_line(lines, number, "initatt: [1.0, 2.0]")),
           rf"kf-gins\.yaml:{number}: initatt: expected a list of 3")
    expect("\n".join(with_line(lines, number, "initatt: [1.0, 2.0, .nan]")),
           rf"kf-gins\.yaml:{number}: initatt: expected a list of 3 finite")
    expect("\n".join(with_line(lines, number, "initatt: [1.0, 2.0")), r"kf-gins\.yaml:\d+: invalid YAML")
    imu_line = next(i for i, l in enumerate(lines, 1) if l.startswith("imupath:"))
    expect("\n".join(with_line(lines, imu_line, "imupath: nowhere/imu.txt")),
           rf"kf-gins\.yaml:{imu_line}: imupath: file 'nowhere/imu.txt' not found")
    start_line = next(i for i, l in enumerate(lines, 1) if l.startswith("starttime:"))
    expect("\n".join(with_line(lines, start_line, "starttime: 456200")),
           rf"kf-gins\.yaml:{start_line}: starttime: .* before the first IMU time")
    std_line = next(i for i, l in enumerate(lines, 1) if l.startswith("initposstd:"))
    expect("\n".join(with_line(lines, std_line, "initposstd: [0.1, 0.0, 0.1]")),
           rf"kf-gins\.yaml:{std_line}: initposstd: standard deviations must be positive")
    expect("- just\n- a list\n", r"kf-gins\.yaml: expected a mapping")
    # an error inside a data file names that file and its line, not the YAML
    (tmp_path / "imu.txt").write_text("\n".join(with_line(good_imu(), 2, "x")) + "\n")
    path.write_text("\n".join(lines))
    with pytest.raises(DataError, match=r"imu\.txt:2: line has 1 columns"):
        kfgins.load_config(path)


def test_kfgins_repository_layout_runs_from_any_directory(tmp_path, monkeypatch):
    """KF-GINS's own dataset/kf-gins.yaml names its files ./dataset/X.txt, relative to the repository's root (where
    KF-GINS runs): found from there and from any other directory."""
    dataset = tmp_path / "KF-GINS" / "dataset"
    dataset.mkdir(parents=True)
    path = write_demo(dataset, imupath="./dataset/imu.txt", gnsspath="./dataset/gnss.txt")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    for cwd in (tmp_path / "KF-GINS", elsewhere):
        monkeypatch.chdir(cwd)
        ds = kfgins.load_config(path)
        assert len(ds.imu) == 10 and len(ds.gnss) == 2
    (dataset / "gnss.txt").unlink()
    with pytest.raises(DataError, match=r"gnsspath.*'./dataset/gnss.txt' not found"):
        kfgins.load_config(path)


def test_duplicated_and_out_of_order_rows_are_left_out_and_remarked(tmp_path):
    """A real file's duplicated or out-of-order record is left out with a remark the replay prints (strict callers
    still get the line's error)."""
    imu = good_imu(12)
    imu = imu[:5] + [imu[4], imu[6], imu[5]] + imu[7:]  # row 5 twice, rows 6 and 7 swapped
    gnss = [f"{SOW0 + s:.3f} 30.4447858 114.4718661 21.09 0.010 0.009 0.019" for s in (0.0, 0.02, 0.04)]
    path = write_demo(tmp_path, imu_rows=imu, gnss_rows=gnss)
    ds = kfgins.load_config(path)
    t = ds.imu.t_ns
    assert (np.diff(t) > 0).all() and len(t) == 11  # 12 rows and a duplicate, one of them and one swapped left out
    remarks = "\n".join(ds.notes["remarks"])
    assert "imu.txt: 2 rows left out" in remarks and "line 6" in remarks
    with pytest.raises(DataError, match=r"imu\.txt:6: time .* is not after the previous"):
        kfgins.load_imu(tmp_path / "imu.txt")
