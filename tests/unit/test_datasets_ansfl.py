"""ANSFL quadrotor flight folders: parsing of small synthetic GT.csv / IMU_1.csv.gz files (axes, units, time repairs,
time-offset estimate, geodetic origin) and user errors that must come back as one DataError naming file and line."""
from __future__ import annotations

import gzip
import math

import numpy as np
import pytest

from zennav.datasets import ansfl, registry
from zennav.datasets.errors import DataError
from zennav.nav import earth
from zennav.nav.types import NS

GT_HEADER = ("time,distance(meters),speed(m/s), compass_heading(degrees), pitch(degrees), roll(degrees),"
             "height_above_takeoff(meters),North,East,Down")
IMU_HEADER = "time,Euler_X,Euler_Y,Euler_Z,Acc_X,Acc_Y,Acc_Z,Gyr_X,Gyr_Y,Gyr_Z"
GTX_HEADER = ("time(millisecond),latitude,longitude,altitude_above_seaLevel(meters),North,East,Down, xSpeed(m/s), "
              "ySpeed(m/s), zSpeed(m/s), roll(degrees), pitch(degrees), compass_heading(degrees)")
DT_IMU = 0.008333


def yaw_deg(t):
    """Heading [deg] of the synthetic flight: a 30 deg/s-amplitude yaw oscillation at 0.5 Hz about 250 deg."""
    return 250.0 + 30.0 / math.pi * np.sin(math.pi * t)


def gt_rows(duration=4.0):
    t = np.arange(0.0, duration + 1e-9, 0.1)
    north, east = 2.0 * t, -0.5 * t
    return [f"{tk:.1f},100.0,2.06,{yaw_deg(tk):.3f},-3.0,1.0,17.3,{n},{e},0.0"
            for tk, n, e in zip(t, north, east)]


def imu_rows(duration=4.0, offset=0.0):
    """IMU rows in Xsens axes (FLU on the drone) for the GT above, stamped t_IMU = t_GT - offset."""
    rows = []
    for k in range(int(duration / DT_IMU) + 1):
        t = k * DT_IMU
        yaw_rate = 30.0 * math.cos(math.pi * (t + offset))  # deg/s about down
        rows.append(f"{t:.6f},1.0,3.0,-160.0,0.1,0.2,9.8,0.5,-0.25,{-yaw_rate:.6f}")
    return rows


def write_flight(folder, gt=None, imu=None, gtx=None):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "GT.csv").write_text("\n".join([GT_HEADER] + (gt or gt_rows())) + "\n")
    with gzip.open(folder / "IMU_1.csv.gz", "wt") as f:
        f.write("\n".join([IMU_HEADER] + (imu or imu_rows())) + "\n")
    if gtx is not None:
        (folder / "GTExtended.csv").write_text("\n".join([GTX_HEADER] + gtx) + "\n")
    return folder


def test_axes_units_increments_and_gnss(tmp_path):
    ds = ansfl.load(write_flight(tmp_path / "path_1"), time_offset_s=0.0)
    assert ds.name == f"ansfl_{tmp_path.name}_path_1"
    dt = np.diff(ds.imu.t_ns)[:, None] / NS
    f_b = ds.imu.dvel[1:] / dt
    w_b = ds.imu.dtheta[1:] / dt
    # FLU sensor axes -> FRD body (plus the small fixed mounting rotation)
    np.testing.assert_allclose(ansfl.C_B_S @ [0.1, 0.2, 9.8], f_b[0], rtol=1e-12)
    assert f_b[0, 2] == pytest.approx(-9.8, abs=0.3) and f_b[0, 1] == pytest.approx(-0.2, abs=0.3)
    assert abs(ansfl.C_B_S[0, 0] - 1) < 1e-3 and abs(ansfl.C_B_S[1, 1] + 1) < 1e-3 and abs(ansfl.C_B_S[2, 2] + 1) < 1e-3
    assert w_b[0, 2] == pytest.approx(math.radians(30.0), rel=0.05)  # deg/s -> rad/s, up -> down
    assert ds.notes["imu_rate_hz"] == pytest.approx(1 / DT_IMU, rel=1e-4)
    # GNSS = GT positions about the README origin, height = height above take-off; no velocity
    assert len(ds.gnss) == 41 and ds.gnss.v_n is None and (ds.gnss.std_ned == ansfl.GNSS_STD_M).all()
    origin = np.array([math.radians(32.8257), math.radians(34.9560), 17.3])
    np.testing.assert_allclose(ds.gnss.llh[0], origin, atol=1e-12)
    np.testing.assert_allclose(earth.llh_to_ned(ds.gnss.llh[10], origin), [2.0, -0.5, 0.0], atol=1e-6)
    # truth is the same GT, with velocity and attitude
    np.testing.assert_array_equal(ds.truth.llh, ds.gnss.llh)
    np.testing.assert_allclose(ds.truth.v_n[5:-5], np.tile([2.0, -0.5, 0.0], (31, 1)), atol=1e-9)
    np.testing.assert_allclose(ds.truth.euler[0, :2], np.deg2rad([1.0, -3.0]), atol=1e-12)
    init = ds.initial
    assert init.heading_known and init.t_ns == ds.imu.t_ns[0] == ds.config.start_t_ns
    assert math.degrees(init.euler[2]) == pytest.approx(250.0 - 360.0, abs=1e-6)
    np.testing.assert_allclose(init.v_n, [2.0, -0.5, 0.0], atol=1e-9)


def test_time_offset_is_estimated_and_applied(tmp_path):
    ds = ansfl.load(write_flight(tmp_path / "p", gt=gt_rows(8.0), imu=imu_rows(8.0, offset=0.25)))
    assert ds.notes["imu_time_offset_s"] == pytest.approx(0.25, abs=0.004)
    assert ds.notes["imu_time_fit_rms_dps"] < 5.0  # the constant x/y rates are not in the GT attitude
    assert ds.imu.t_ns[0] == pytest.approx(0.25 * NS, abs=0.01 * NS)  # samples before the GT start are dropped
    forced = ansfl.load(tmp_path / "p", time_offset_s=-0.1)
    assert forced.notes["imu_time_offset"] == "given" and forced.imu.t_ns[0] == 8_329_000  # 13 * 0.008333 - 0.1 s
    write_flight(tmp_path / "short")  # 4 s: too short for a +-1.5 s search
    with pytest.raises(DataError, match=r"short/IMU_1\.csv\.gz: IMU and GT overlap too little"):
        ansfl.load(tmp_path / "short")


def test_imu_time_wrap_and_restamped_row(tmp_path):
    rows = imu_rows()
    t = [k * DT_IMU for k in range(len(rows))]
    t[100] = t[101]  # "t, t+2d, t+2d": the row at t+d carries its successor's stamp
    t[300:] = [x - ansfl.WRAP_S for x in t[300:]]  # 2^32 us counter wrap
    rows = [f"{tk:.6f}," + r.split(",", 1)[1] for tk, r in zip(t, rows)]
    ds = ansfl.load(write_flight(tmp_path / "p", imu=rows), time_offset_s=0.0)
    assert ds.notes["imu_time_wraps"] == 1 and ds.notes["imu_rows_restamped"] == 1
    assert len(ds.imu) == len(rows)
    np.testing.assert_allclose(np.diff(ds.imu.t_ns), DT_IMU * NS, atol=2000)


def test_origin_from_gt_extended(tmp_path):
    gtx = ["56100,32.8256829718786,34.9559595644856,10.1942341,0.0,0.0,0.0,-0.1,0.0,0.0,0.0,-1.7,247.0",
           "56200,32.8256827608982,34.9559595548387,10.1942341,-0.0234,-0.0009,0.0,-0.1,0.0,0.2,0.8,-1.1,247.0"]
    ds = ansfl.load(write_flight(tmp_path / "p", gtx=gtx), time_offset_s=0.0)
    np.testing.assert_allclose(ds.gnss.llh[0], [math.radians(32.8256829718786), math.radians(34.9559595644856),
                                                10.1942341], atol=1e-12)
    assert "GTExtended" in ds.notes["origin"]


# ------------------------------------------------------------------------------------- user errors


def with_line(rows, number, text):
    """rows with data row `number` (1-based, the header is line 1) replaced."""
    rows = list(rows)
    rows[number - 2] = text
    return rows


@pytest.mark.parametrize(
    "gt, imu, name, line, words",
    [
        (with_line(gt_rows(), 4, "0.2,100,2,250,-3,1,17.3,0.4,-0.1"), None, "GT.csv", 4, "9 columns, expected 10"),
        (with_line(gt_rows(), 5, "0.3,100,2,nan,-3,1,17.3,0.6,-0.15,0"), None, "GT.csv", 5, "NaN or infinite"),
        (with_line(gt_rows(), 6, "0.3,100,2,250,-3,1,17.3,0.8,-0.2,0"), None, "GT.csv", 6, "not after the previous"),
        (with_line(gt_rows(), 6, "0.45,100,2,250,-3,1,17.3,0.8,-0.2,0"), None, "GT.csv", 6, "not evenly spaced"),
        (None, with_line(imu_rows(), 3, "0.008333,1,3,-160,0.1,0.2,9.8,0.5,-0.25"), "IMU_1.csv.gz", 3,
         "9 columns, expected 10"),
        (None, with_line(imu_rows(), 7, "0.05,1,3,-160,0.1,0.2,inf,0.5,-0.25,0"), "IMU_1.csv.gz", 7,
         "NaN or infinite"),
        (None, with_line(imu_rows(), 8, "0.02,1,3,-160,0.1,0.2,9.8,0.5,-0.25,0"), "IMU_1.csv.gz", 8,
         "IMU time 0.020000000 s is not after the previous"),
        (None, with_line(imu_rows(), 9, "0.06,1,3,-160,0.1,abc,9.8,0.5,-0.25,0"), "IMU_1.csv.gz", 9, "'abc'"),
    ],
)
def test_bad_files_name_file_and_line(tmp_path, gt, imu, name, line, words):
    write_flight(tmp_path / "p", gt=gt, imu=imu)
    with pytest.raises(DataError) as info:
        ansfl.load(tmp_path / "p", time_offset_s=0.0)
    message = str(info.value)
    assert f"{name}:{line}: " in message and words in message and "\n" not in message
    assert info.value.line == line


def test_missing_files_and_wrong_headers(tmp_path):
    with pytest.raises(DataError, match=r"nowhere: flight folder not found"):
        ansfl.load(tmp_path / "nowhere")
    folder = write_flight(tmp_path / "p")
    (folder / "IMU_1.csv.gz").unlink()
    with pytest.raises(DataError, match=r"IMU_1\.csv\.gz: file not found"):
        ansfl.load(folder)
    (folder / "GT.csv").unlink()
    with pytest.raises(DataError, match=r"GT\.csv: file not found"):
        ansfl.load(folder)
    # the IMU file given as GT: the header names the wrong columns
    write_flight(folder)
    (folder / "GT.csv").write_text("\n".join([IMU_HEADER] + imu_rows()[:20]) + "\n")
    with pytest.raises(DataError, match=r"GT\.csv:1: header 'time,Euler_X.*does not name the columns time, distance"):
        ansfl.load(folder)
    (folder / "IMU_1.csv.gz").write_bytes(b"not gzip at all")
    (folder / "GT.csv").write_text("\n".join([GT_HEADER] + gt_rows()) + "\n")
    with pytest.raises(DataError, match=r"IMU_1\.csv\.gz: cannot read as text"):
        ansfl.load(folder)


def test_registry_specs(tmp_path, monkeypatch):
    root = tmp_path / "data"
    write_flight(root / registry.ANSFL_FOLDER / "Vertical" / "path_12")
    monkeypatch.setenv("ZENNAV_DATA", str(root))
    assert "ansfl:Vertical/path_12" in registry.available()
    assert "ansfl:Horizontal/path_5" not in registry.available()  # folder absent
    ds = registry.load_dataset("ansfl:Vertical/path_12", time_offset_s=0.0)
    assert ds.name == "ansfl_Vertical_path_12" and ds.notes["flight"] == "Vertical/path_12"
    assert registry.load_dataset(str(root / registry.ANSFL_FOLDER / "Vertical" / "path_12"),
                                 time_offset_s=0.0).name == ds.name  # a flight folder is recognized
    for bad in ("ansfl:Vertical/path_31", "ansfl:Sideways/path_1", "ansfl:Horizontal/path_05"):
        with pytest.raises(DataError, match=rf"^{bad}: unknown ANSFL flight; accepted: ansfl:Horizontal/path_1\.\.27, "
                                            r"ansfl:Vertical/path_1\.\.30, ansfl:StraightLine/path_1\.\.4$"):
            registry.load_dataset(bad)
    with pytest.raises(DataError, match=r"Horizontal/path_5: flight folder not found"):
        registry.load_dataset("ansfl:Horizontal/path_5")
