"""A-KIT AUV loader (zennav.datasets.akit) on the real recordings, and the DVL anomaly injection
(zennav.datasets.dvl_anomalies). Skipped where ../shared/data has no A-KIT folder."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.datasets import akit, dvl_anomalies, registry
from zennav.datasets.errors import DataError
from zennav.nav.beams import janus_directions, velocity_from_beams
from zennav.nav.rotation import wrap_angle
from zennav.nav.types import NS, DvlData, ImuData


def _root():
    try:
        root = registry.data_root() / registry.AKIT_FOLDER
    except DataError:
        return None
    return root if (root / "Trajectory12").is_dir() else None


ROOT = _root()
needs_data = pytest.mark.skipif(ROOT is None, reason="A-KIT data not in the shared data folder")


@pytest.fixture(scope="module")
def t12():
    return registry.load_dataset("akit:Trajectory12", gnss_s=0)


def _gyro_attitude_error_deg(ds, imu: ImuData) -> np.ndarray:
    """Max |gyro-only attitude - GT| (roll, pitch, yaw) [deg] at the GT rows of the run."""
    t, euler = akit.gyro_attitude(imu, ds.initial.t_ns, ds.initial.euler, float(ds.initial.llh[0]))
    truth = ds.truth
    rows = (truth.t_ns > t[0]) & (truth.t_ns <= t[-1])
    k = np.searchsorted(t, truth.t_ns[rows])
    return np.degrees(np.abs(wrap_angle(euler[k] - truth.euler[rows])).max(axis=0))


@needs_data
def test_y_flip_keeps_gyro_attitude_on_the_reference(t12):
    flipped = _gyro_attitude_error_deg(t12, t12.imu)
    raw = ImuData(t12.imu.t_ns, t12.imu.dtheta * [1.0, -1.0, 1.0], t12.imu.dvel * [1.0, -1.0, 1.0])
    unflipped = _gyro_attitude_error_deg(t12, raw)
    assert np.all(flipped < 0.6), flipped  # README: 0.44/0.26/0.10 deg over 400 s with the flip
    assert unflipped.max() > 3.0, unflipped  # README: 8.3 deg in pitch without it
    # the accelerometer agrees: roll from the specific force averaged over each GT interval, atan2(-f_y, -f_z),
    # follows the GT roll (README: r = -0.95 without the flip)
    t, truth = t12.imu.t_ns, t12.truth
    k = np.searchsorted(t, truth.t_ns)
    inside = (k > 0) & (k < len(t))
    k = k[inside]
    cum = np.cumsum(t12.imu.dvel, axis=0)
    f_b = (cum[k[1:]] - cum[k[:-1]]) / (np.diff(t[k]) / NS)[:, None]
    roll_gt = 0.5 * (truth.euler[inside][1:, 0] + truth.euler[inside][:-1, 0])
    assert np.corrcoef(np.arctan2(-f_b[:, 1], -f_b[:, 2]), roll_gt)[0, 1] > 0.9
    assert np.corrcoef(np.arctan2(f_b[:, 1], -f_b[:, 2]), roll_gt)[0, 1] < -0.9


@needs_data
def test_skew_is_recovered_after_a_known_shift(tmp_path, t12):
    folder = ROOT / "Trajectory12"
    shifted = tmp_path / "Trajectory12"
    shifted.mkdir()
    for name in ("DVL_trajectory12.csv", "GT_trajectory12.csv"):
        (shifted / name).write_text((folder / name).read_text())
    import gzip

    lines = gzip.open(folder / "IMU_trajectory12.csv.gz", "rt").read().splitlines()
    out = [lines[0]] + [f"{float(t) - 0.5!r},{rest}" for t, rest in (ln.split(",", 1) for ln in lines[1:])]
    with gzip.open(shifted / "IMU_trajectory12.csv.gz", "wt") as f:
        f.write("\n".join(out) + "\n")
    again = akit.load(shifted, gnss_s=0)
    assert abs(again.notes["skew_s"] - t12.notes["skew_s"] - 0.5) < 0.05, (again.notes["skew_s"], t12.notes["skew_s"])
    given = akit.load(shifted, gnss_s=0, skew_s=0.25)
    assert given.notes["skew_s"] == 0.25 and given.notes["skew"] == "given"
    with pytest.raises(DataError, match="skew_s"):
        akit.load(folder, skew_s="later")


@needs_data
def test_dvl_beams_depth_and_gnss_are_derived_as_stated(t12):
    dvl = t12.dvl
    B = janus_directions(t12.config.dvl_tilt, t12.config.dvl_layout)
    assert dvl.beam_valid.all() and dvl.velocity_valid.all()
    v_back = np.array([velocity_from_beams(b, ok, B) for b, ok in zip(dvl.beams, dvl.beam_valid, strict=True)])
    assert np.abs(v_back - dvl.velocity_d).max() < 1e-12
    assert dvl.velocity_d[:, 0].mean() > 1.5  # forward at about 2 m/s
    depth_error = t12.depth.depth_m + np.interp(t12.depth.t_ns, t12.truth.t_ns, t12.truth.llh[:, 2])
    assert abs(depth_error.mean()) < 0.02 and 0.04 < depth_error.std() < 0.06  # N(0, 0.05 m)
    assert len(t12.gnss) == 0 and "none" in t12.notes["gnss"]
    with_gnss = registry.load_dataset("akit:Trajectory12", gnss_s=30, seed=4)
    assert len(with_gnss.gnss) == 30 and with_gnss.gnss.t_ns[-1] - with_gnss.initial.t_ns <= 30 * NS
    assert "DERIVED" in with_gnss.notes["gnss"] and "DERIVED" in with_gnss.notes["dvl"]
    assert "DERIVED" in with_gnss.notes["depth"]


def _clean_dvl(n: int = 400) -> tuple[DvlData, np.ndarray]:
    B = janus_directions(np.radians(30.0), "x")
    v_d = np.tile([2.0, 0.1, 0.05], (n, 1))
    beams = v_d @ B.T
    t_ns = np.arange(n, dtype=np.int64) * NS
    return DvlData(t_ns, beams, np.ones((n, 4), bool), v_d, np.ones(n, bool)), B


def test_anomalies_counts_kinds_and_seed():
    dvl, B = _clean_dvl()
    spec = "outlier:5,bias:2,noise:1,lost1:1,lost2p:1,lost2o:1,lostall:1"
    out, events = dvl_anomalies.inject(dvl, spec, B, seed=7, t_from_ns=60 * NS)
    kinds = [e.kind for e in events]
    assert sorted(kinds) == sorted(["outlier"] * 5 + ["bias"] * 2 + ["noise", "lost1", "lost2p", "lost2o", "lostall"])
    assert all(e.start_ns >= 60 * NS for e in events)
    spans = sorted((e.start_ns, e.end_ns) for e in events)
    assert all(b[0] > a[1] + NS for a, b in zip(spans, spans[1:], strict=False))  # no overlap, a clean sample between
    changed = np.abs(out.beams - dvl.beams) > 1e-12
    for e in events:
        rows = (dvl.t_ns >= e.start_ns) & (dvl.t_ns <= e.end_ns)
        assert rows.sum() == e.samples
        if e.kind in ("outlier", "bias"):
            assert np.allclose(out.beams[rows, e.beams[0]] - dvl.beams[rows, e.beams[0]], e.magnitude_mps)
            assert abs(e.magnitude_mps) == pytest.approx((20.0 if e.kind == "outlier" else 5.0) * 0.02)
        elif e.kind == "noise":
            assert e.magnitude_mps == pytest.approx(0.2) and changed[rows, e.beams[0]].all()
        else:
            assert not out.beam_valid[rows][:, list(e.beams)].any()
            horizontal = B[list(e.beams), :2]
            if e.kind == "lost2p":
                assert abs(np.linalg.det(horizontal)) < 1e-12  # opposite beams
            if e.kind == "lost2o":
                assert abs(np.dot(*horizontal)) < 1e-12  # perpendicular beams
            assert out.velocity_valid[rows].all() == (e.kind == "lost1")
    assert changed.sum() == 5 + 2 * 30 + 30  # outliers, bias steps, the noise burst (one beam each)
    assert (~out.beam_valid).sum() == 30 * (1 + 2 + 2 + 4)
    # the DVL's velocity follows the changed beams; untouched rows stay the recorded velocity
    bias = next(e for e in events if e.kind == "bias")
    row = int(np.searchsorted(dvl.t_ns, bias.start_ns))
    assert np.abs(out.velocity_d[row] - dvl.velocity_d[row]).max() > 0.01
    clean = ~(changed.any(1) | (~out.beam_valid).any(1))
    assert np.array_equal(out.velocity_d[clean], dvl.velocity_d[clean])
    again, events_again = dvl_anomalies.inject(dvl, spec, B, seed=7, t_from_ns=60 * NS)
    assert events_again == events and np.array_equal(again.beams, out.beams)
    other, events_other = dvl_anomalies.inject(dvl, spec, B, seed=8, t_from_ns=60 * NS)
    assert [e.start_ns for e in events_other] != [e.start_ns for e in events]


def test_anomaly_spec_errors():
    dvl, B = _clean_dvl(50)
    for bad in ("spike:1", "bias:1.5", "bias:1:-2", "noise:1:2:3:4"):
        with pytest.raises(ValueError, match="DVL anomaly"):
            dvl_anomalies.parse_spec(bad)
    with pytest.raises(ValueError, match="no room"):
        dvl_anomalies.inject(dvl, "lostall:3:0:20", B)
    assert len(dvl_anomalies.parse_spec("all")) == len(dvl_anomalies.KINDS)


@needs_data
def test_loader_records_anomalies_and_rejects_bad_options():
    ds = registry.load_dataset("akit:Trajectory13", anomalies="all", anomalies_from_s=60, seed=3)
    events = ds.notes["dvl_anomalies"]
    assert len(events) == len(dvl_anomalies.KINDS)
    assert all(e["start_ns"] >= ds.initial.t_ns + 60 * NS for e in events)
    with pytest.raises(DataError, match="DVL anomaly"):
        registry.load_dataset("akit:Trajectory13", anomalies="spike:3")
    with pytest.raises(DataError, match="accepted"):
        registry.load_dataset("akit:Trajectory14")
    assert registry.vehicle_of("akit:Trajectory3") == "auv"
    assert "akit:Trajectory13" in registry.available()
