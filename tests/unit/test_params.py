"""The ins's parameter file (deploy/ins.yaml, zennav.params): human units converted to SI once, the file equal to
NavConfig's defaults, every NavConfig field accounted for, one clear error line per mistake, and the same
filter in the ins and in `zennav replay`."""
from __future__ import annotations

import math

import numpy as np
import pytest

from zennav.nav.types import FixType, ImuNoise, NavConfig
from zennav.params import (
    FILTER,
    INS_PARAMS,
    SENSOR_FIELDS,
    ParamError,
    check_complete,
    load_filter_params,
    nav_config,
    sensor_map,
)


def test_shipped_file_is_navconfig_defaults_and_complete():
    """deploy/ins.yaml holds every filter setting, and its values (converted) are NavConfig's defaults, bit for
    bit and with the same types: code that builds a NavConfig from a loader alone runs the ins's filter."""
    got = load_filter_params()
    default = NavConfig()
    assert set(got) == set(FILTER)
    for k, v in got.items():
        assert v == getattr(default, k) and type(v) is type(getattr(default, k)), k
    assert check_complete() == []
    assert got["align_course_std"] == math.radians(2.0) and got["min_fix"] == int(FixType.SINGLE)


def _write(tmp_path, body: str):
    p = tmp_path / "ins.yaml"
    p.write_text("ins:\n" + body)
    return p


def test_units_convert_and_partial_file_keeps_defaults(tmp_path):
    p = _write(tmp_path, "  alignment:\n    align_heading_std: 0.25 deg\n  gnss:\n    min_fix: rtk_float\n"
                         "    pos_std_floor_m: 0.5 m\n    gate_probability: 0.99\n    min_sats: 6\n")
    got = load_filter_params(p)
    assert got == {"align_heading_std": math.radians(0.25), "min_fix": int(FixType.RTK_FLOAT),
                   "pos_std_floor_m": 0.5, "gate_probability": 0.99, "min_sats": 6}
    cfg = nav_config(NavConfig(lever_arm_b=np.array([0.1, 0.2, 0.3])), got)
    assert cfg.pos_std_floor_m == 0.5 and cfg.outage_timeout_s == NavConfig().outage_timeout_s
    assert np.array_equal(cfg.lever_arm_b, [0.1, 0.2, 0.3])


def test_a_bare_on_or_off_is_the_choice_of_that_name(tmp_path):
    """YAML reads a bare off / on as a boolean: a choice setting with such a choice takes it by name."""
    p = _write(tmp_path, "  learning:\n    learn_where_better: off\n  dvl:\n    dvl_mode: off\n")
    assert load_filter_params(p) == {"learn_where_better": "off", "dvl_mode": "off"}
    p = _write(tmp_path, "  learning:\n    learn_where_better: on\n")
    assert load_filter_params(p) == {"learn_where_better": "on"}
    with pytest.raises(ParamError, match="True is not one of off, loose, tight"):
        load_filter_params(_write(tmp_path, "  dvl:\n    dvl_mode: on\n"))


@pytest.mark.parametrize("body, line, message", [
    ("  gnss:\n    pos_std_floor_m: 5 cm\n", 3, "gnss.pos_std_floor_m: unit 'cm' where 'm' is expected"),
    ("  gnss:\n    pos_std_floor_m: 0.05\n", 3, "gnss.pos_std_floor_m: no unit where 'm' is expected"),
    ("  gnss:\n    gate_probability: 0.99 m\n", 3, "unit 'm' where no unit (a plain number) is expected"),
    ("  alignment:\n    align_course_std: 0.03 rad\n", 3, "unit 'rad' where 'deg' is expected"),
    ("  gnss:\n    max_jump: 20 m\n", 3, "gnss.max_jump: unknown setting"),
    ("  gnss:\n    align_level_s: 5 s\n", 3, "(it belongs in section 'alignment')"),
    ("  outage:\n    outage_timeout_s: soon s\n", 3, "'soon s' is not a number in s"),
    ("  outage:\n    reacquire_fixes: 2.5\n", 3, "is not an integer"),
    ("  gnss:\n    min_fix: GOOD\n", 3, "'GOOD' is not a fix type"),
    ("  adaptive_r:\n    adaptive_r: yes please\n", 3, "is not true/false"),
    ("  covariance:\n    cov_interval_s: inf s\n", 3, "is not finite"),
    ("  gnss: 3\n", 2, "gnss: a section is a mapping"),
])
def test_each_mistake_is_one_clear_error_line(tmp_path, body, line, message):
    p = _write(tmp_path, body)
    with pytest.raises(ParamError) as e:
        load_filter_params(p)
    text = str(e.value)
    assert "\n" not in text and text.startswith(f"{p}:{line}: ") and message in text, text


def test_file_level_errors(tmp_path):
    with pytest.raises(ParamError, match="not found"):
        load_filter_params(tmp_path / "missing.yaml")
    bad = tmp_path / "x.yaml"
    bad.write_text("filter:\n  gnss: {}\n")
    with pytest.raises(ParamError, match=r"x.yaml:1: needs one top-level mapping 'ins:'"):
        load_filter_params(bad)
    bad.write_text("ins: [\n")
    with pytest.raises(ParamError, match="not YAML"):
        load_filter_params(bad)


def test_stream_carries_the_sensor_description_only():
    """stream_start's config: the IMU noise model, lever arm, start/end; the ins takes only those from a map
    (a filter setting slipped into it is ignored) and adds its own file's settings."""
    cfg = NavConfig(imu_noise=ImuNoise(arw=1e-3), lever_arm_b=np.array([1.0, 0.0, -0.5]), start_t_ns=5,
                    end_t_ns=9, gate_reset_s=99.0)
    m = sensor_map(cfg)
    assert set(m) == set(SENSOR_FIELDS) and m["imu_noise"]["arw"] == 1e-3
    back = nav_config({**m, "gate_reset_s": 1.0}, {"adaptive_r": True})
    assert back.imu_noise == cfg.imu_noise and np.array_equal(back.lever_arm_b, cfg.lever_arm_b)
    assert (back.start_t_ns, back.end_t_ns, back.gate_reset_s, back.adaptive_r) == (5, 9, 10.0, True)


def test_replay_reads_the_same_file(tmp_path):
    """zennav replay --params FILE runs the filter of FILE (here a tighter GNSS gate changes the solution);
    without --params it is deploy/ins.yaml, i.e. the loader's NavConfig."""
    from click.testing import CliRunner

    from zennav.cli import main

    tight = tmp_path / "tight.yaml"
    tight.write_text(INS_PARAMS.read_text().replace("pos_std_floor_m: 0.05 m", "pos_std_floor_m: 3.0 m"))
    runs = {}
    for name, extra in (("file", []), ("tight", ["--params", str(tight)])):
        out = tmp_path / name
        r = CliRunner().invoke(main, ["replay", "sim:car", "--outage", "40:10", "--out", str(out), *extra])
        assert r.exit_code == 0, r.output
        runs[name] = (out / "nav.txt").read_text()
    from zennav.datasets.registry import load_dataset
    from zennav.metrics import write_outputs
    from zennav.replay import run_replay

    ds = load_dataset("sim:car")
    res = run_replay(ds, outages=[(40.0, 10.0)])
    write_outputs(tmp_path / "code", ds, res, {})
    assert runs["file"] == (tmp_path / "code" / "nav.txt").read_text() != runs["tight"]
