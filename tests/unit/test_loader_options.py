"""Loader options (`-o KEY=VALUE` of zennav replay, zennav-ingest, report, gnss-sim): a wrong name or value is one
error line that names it and, for a name, the options the dataset's loader takes; never a traceback."""
from __future__ import annotations

import pytest
from click.testing import CliRunner

from zennav.cli import main
from zennav.datasets import kfgins
from zennav.datasets.errors import DataError
from zennav.datasets.registry import data_root, load_dataset, parse_loader_options
from zennav.sim.scenarios import make_dataset


def _has_data() -> bool:
    try:
        return (data_root() / "rtklibexplorer_drive_0708").is_dir()
    except DataError:
        return False


@pytest.fixture(scope="module")
def kfgins_yaml(tmp_path_factory):
    return kfgins.write_dataset(make_dataset("static", duration_s=2.0, imu_rate_hz=100.0), tmp_path_factory.mktemp("k"))


@pytest.mark.parametrize("spec, option", [("sim:car", "max_speed=10"), ("sim:static", "yaw_rate=0.1"),
                                          ("sim:auv", "dvl_layout=+"), ("kfgins", "none")])
def test_an_unknown_option_names_what_the_loader_takes(spec, option, kfgins_yaml):
    spec = str(kfgins_yaml) if spec == "kfgins" else spec
    with pytest.raises(DataError, match=f"unknown loader option foo; accepted: .*{option.split('=')[0]}"):
        load_dataset(spec, foo=1)
    if "=" in option:  # the scenario's own options and its trajectory's are taken
        assert len(load_dataset(spec, **parse_loader_options(["duration_s=2", option])).imu.t_ns) > 100


@pytest.mark.parametrize("option, why", [("duration_s=abc", "can't multiply"), ("duration_s=0", "two uniformly"),
                                         ("imu_rate_hz=0", "division by zero"), ("seed=1.5", "SeedSequence"),
                                         ("imu_grade=foo", "unknown IMU grade")])
def test_a_bad_option_value_is_a_data_error(option, why):
    with pytest.raises(DataError, match=f"sim:car: loader options {option.split('=')[0]}=.* not usable: .*{why}"):
        load_dataset("sim:car", **parse_loader_options([option]))


@pytest.mark.skipif(not _has_data(), reason="needs ../shared/data (or $ZENNAV_DATA)")
@pytest.mark.parametrize("spec, accepted", [("rtklibexplorer", "prefilter"), ("comma2k19", "none"),
                                            ("ansfl:Horizontal/path_1", "time_offset_s"),
                                            ("akit:Trajectory1", "gnss_s")])
def test_recordings_name_their_options(spec, accepted):
    with pytest.raises(DataError, match=f"accepted: .*{accepted}"):
        load_dataset(spec, foo=1)


def test_replay_with_a_wrong_option_is_one_line(kfgins_yaml):
    for args in (["replay", "sim:car", "-o", "foo=1"], ["replay", str(kfgins_yaml), "-o", "duration_s=5"],
                 ["replay", "sim:car", "-o", "duration_s=-5"]):
        res = CliRunner().invoke(main, args)
        assert res.exit_code != 0 and "Traceback" not in res.output, (args, res.output)
        assert not isinstance(res.exception, (TypeError, ValueError, IndexError)), (args, res.exception)
        assert "loader option" in res.output.strip().splitlines()[-1], res.output
