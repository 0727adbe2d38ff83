"""The `zennav` command: replay with outages writes the promised files and fields; a user's mistake gives
a one-line error, never a traceback."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from zennav.cli import main
from zennav.datasets import kfgins
from zennav.sim.scenarios import make_dataset

METRIC_KEYS = {"dataset", "duration_s", "imu_rate_hz", "wall_s", "realtime_factor", "horizontal_rms_m",
               "vertical_rms_m", "velocity_rms_mps", "attitude_rms_deg", "outages", "outage_max_horizontal_rms_m",
               "outage_max_horizontal_max_m"}


def test_help_explains_frames_and_units():
    out = "".join(CliRunner().invoke(main, ["--help"], terminal_width=200).output)
    assert "NED" in out and "forward-right-down" in out and "degrees" in out
    assert "replay" in out and "demo" in out


def test_replay_kf_gins_config_with_outages_writes_outputs(tmp_path):
    ds = make_dataset("car", duration_s=120.0, imu_rate_hz=100.0, seed=3)
    yaml_path = kfgins.write_dataset(ds, tmp_path / "data")
    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["replay", "--kf-gins-config", str(yaml_path), "--outage", "40:20",
                                    "--outage-every", "50:10:80", "--out", str(out)])
    assert res.exit_code == 0, res.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert METRIC_KEYS <= metrics.keys()
    fused = metrics["engine"]["counters"]["gnss_pos_fused"]
    assert f"GNSS fused: pos {fused}, vel " in res.output and "outages declared 2" in res.output
    assert [(o["start_s"], o["duration_s"]) for o in metrics["outages"]] == [(40.0, 20.0), (80.0, 10.0)]
    assert set(metrics["attitude_rms_deg"]) == {"roll", "pitch", "yaw"}
    assert 0.0 < metrics["horizontal_rms_m"] < 5.0
    nav = np.loadtxt(out / "nav.txt")
    assert nav.shape[1] == 11 and len(nav) == 12000
    truth = kfgins.load_nav(out / "nav.txt")  # the output reads back as a KF-GINS .nav file
    assert len(truth.t_ns) == 12000
    assert (out / "nav.csv").read_text().startswith("t_s,lat_deg")


def test_kf_gins_configuration_without_out_writes_into_its_outputpath(tmp_path, monkeypatch):
    """As KF-GINS: the solution goes to the configuration's outputpath (relative to the current directory, else to
    the YAML's folder where that folder exists), also under KF-GINS's file name."""
    import yaml

    ds = make_dataset("static", duration_s=5.0, imu_rate_hz=100.0, seed=1)
    yaml_path = kfgins.write_dataset(ds, tmp_path / "data")
    config = yaml.safe_load(yaml_path.read_text())
    (tmp_path / "data" / "results").mkdir()
    yaml_path.write_text(yaml.safe_dump({**config, "outputpath": "results"}))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    res = CliRunner().invoke(main, ["replay", "--kf-gins-config", str(yaml_path)])
    assert res.exit_code == 0, res.output
    results = tmp_path / "data" / "results"
    assert (results / "KF_GINS_Navresult.nav").read_bytes() == (results / "nav.txt").read_bytes()
    assert len(np.loadtxt(results / "nav.txt")) == 500 and (results / "metrics.json").is_file()
    assert list(elsewhere.iterdir()) == []
    (elsewhere / "results").mkdir()  # KF-GINS's rule first: the current directory's folder when it exists
    assert CliRunner().invoke(main, ["replay", str(yaml_path)]).exit_code == 0
    assert (elsewhere / "results" / "KF_GINS_Navresult.nav").is_file()


@pytest.mark.parametrize("scale_states", [False, True], ids=["15-states", "21-states"])
def test_kf_gins_configuration_writes_its_imu_error_and_std_files(tmp_path, monkeypatch, scale_states):
    """Beside KF_GINS_Navresult.nav, KF-GINS's KF_GINS_IMU_ERR.txt (13 columns) and KF_GINS_STD.txt (22), once per
    second of data at solution times, in KF-GINS's units: the gyro biases those of biases.csv, the position 1-sigma
    that of nav.csv; the scale factors and their 1-sigma 0 with 15 states, estimated with 21 (gsstd/asstd given)."""
    import yaml

    ds = make_dataset("static", duration_s=10.0, imu_rate_hz=100.0, seed=1)
    yaml_path = kfgins.write_dataset(ds, tmp_path)
    config = yaml.safe_load(yaml_path.read_text())
    if scale_states:
        config["imunoise"].update(gsstd=[1000.0] * 3, asstd=[1000.0] * 3)
        config.update(initsgstd=[1000.0] * 3, initsastd=[1000.0] * 3)
    yaml_path.write_text(yaml.safe_dump({**config, "outputpath": "out"}))
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(main, ["replay", str(yaml_path), "-q"])
    assert res.exit_code == 0, res.output
    err, std = np.loadtxt(out / "KF_GINS_IMU_ERR.txt"), np.loadtxt(out / "KF_GINS_STD.txt")
    nav, csv = np.loadtxt(out / "nav.txt"), np.loadtxt(out / "nav.csv", delimiter=",", skiprows=1)
    biases = np.loadtxt(out / "biases.csv", delimiter=",", skiprows=1)
    assert err.shape == (10, 13) and std.shape == (10, 22)
    rows = np.searchsorted(nav[:, 1], err[:, 0])
    assert np.allclose(nav[rows, 1], err[:, 0], rtol=0, atol=1e-9) and np.array_equal(err[:, 0], std[:, 0])
    assert np.allclose(np.diff(err[:, 0]), 1.0, atol=0.011)
    assert np.allclose(err[:, 1:4], biases[:, 1:4], rtol=1e-5, atol=1e-9)  # deg/h both
    assert np.allclose(std[:, 1:4], csv[rows, 10:13], rtol=0, atol=1e-4)  # m, NED both
    assert np.all(std[:, 1:16] > 0)
    assert np.all(std[:, 16:] > 0) if scale_states else not err[:, 7:].any() and not std[:, 16:].any()


def test_an_outage_after_the_end_of_the_run_is_said_not_dropped_silently():
    res = CliRunner().invoke(main, ["replay", "sim:static", "-o", "duration_s=5", "--outage", "100:10", "--outage",
                                    "2:1", "-q"])
    assert res.exit_code == 0, res.output
    assert "note: outage 100:10 starts after the run's 5.0 s: none" in res.output
    assert "outage 2s+1s" in res.output and "100s" not in res.output


def test_a_learned_replay_says_what_the_learning_did():
    """Too little GNSS time to learn: the replay says no model was made, not a silent plain run."""
    res = CliRunner().invoke(main, ["replay", "sim:car", "-o", "duration_s=60", "--outage", "40:10",
                                    "--compensation", "elman", "-q"])
    assert res.exit_code == 0, res.output
    assert "learning (elman, body_velocity): " in res.output
    assert "no model made (it needs 200 samples): the run equals a plain one" in res.output


def test_user_mistakes_give_one_line_errors(tmp_path):
    runner = CliRunner()
    cfg = kfgins.write_dataset(make_dataset("static", duration_s=5.0, imu_rate_hz=100.0), tmp_path, name="s")
    imu_file = tmp_path / "s_imu.txt"
    lines = imu_file.read_text().splitlines(keepends=True)
    lines[1] = " ".join(lines[1].split()[:6]) + "\n"  # line 2 loses a column
    imu_file.write_text("".join(lines))
    cases = [
        (["replay", str(tmp_path / "nope.yaml")], "nope.yaml"),
        (["replay", "--kf-gins-config", str(cfg)], "s_imu.txt:2"),
        (["replay", "sim:car", "--outage", "10"], "START:DURATION"),
        (["replay", "sim:car", "--outage-every", "10:20"], "PERIOD:DURATION"),
        (["replay", "no-such-dataset"], "accepted"),
    ]
    for args, needle in cases:
        res = runner.invoke(main, args)
        assert res.exit_code != 0, args
        assert needle in res.output, (args, res.output)
        assert "Traceback" not in res.output and not isinstance(res.exception, (TypeError, ValueError, KeyError))



def test_command_line_choices_are_the_cores():
    """The choices the command line writes out (so that it starts without importing the core) are the core's."""
    from zennav import demo_cli, replay_cli
    from zennav.learn.loop import CHOICES
    from zennav.learn.settings import COMPENSATIONS
    from zennav.nav.learning import TARGETS

    assert replay_cli.TARGETS == TARGETS
    assert tuple(demo_cli.COMPENSATIONS) == tuple(COMPENSATIONS)
    replay = next(p for p in replay_cli.replay.params if p.name == "compensation")
    assert tuple(replay.type.choices) == CHOICES


def test_zennav_help_imports_no_numerical_library():
    """`zennav --help` loads the command line only: no numpy, scipy, torch or zenoh (start-up time)."""
    import subprocess
    import sys

    code = ("import sys\nfrom click.testing import CliRunner\nfrom zennav.cli import main\n"
            "r = CliRunner().invoke(main, ['--help'])\nassert r.exit_code == 0, r.output\n"
            "print(sorted(m for m in ('numpy', 'scipy', 'torch', 'zenoh') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
