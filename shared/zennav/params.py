"""Parameter files in human units (deploy/ins.yaml, deploy/attitude.yaml), converted to SI once, here.

The ins's FILTER settings (gates, floors, outage and gate-reset times, alignment limits, adaptive R, covariance
interval, the engine's learning settings) live in ``deploy/ins.yaml``: every value carries its unit beside it
(``pos_std_floor_m: 0.05 m``, ``align_course_std: 2.0 deg``; probabilities, ratios and counts are plain
numbers). What describes the sensors and the run (IMU noise model, GNSS lever arm, start/end times) is not a
filter setting: it comes with the data (the dataset loaders; over the bus in ``stream_start``), see
``SENSOR_FIELDS``. ``learning`` (on/off) is the ins's ``--learning`` / replay's ``--compensation``.

``nav_config(sensor, filter_params)`` puts the two together into the ``NavConfig`` the engine runs; the ins
service and ``zennav replay`` both read the same file (default ``deploy/ins.yaml``), and the file's values
equal NavConfig's defaults (tests/unit/test_params.py ties them), so code that builds a NavConfig from a
loader alone runs the same filter.

Errors (unknown keys, a unit that is not the expected one, a value that is not a number) raise ``ParamError``
with one line ``file:line: section.key: message``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields
from pathlib import Path

DEPLOY_DIR = Path(__file__).resolve().parents[2] / "deploy"
INS_PARAMS = DEPLOY_DIR / "ins.yaml"
ATTITUDE_PARAMS = DEPLOY_DIR / "attitude.yaml"

SENSOR_FIELDS = ("imu_noise", "lever_arm_b", "dvl_tilt", "dvl_layout", "dvl_mount_euler", "dvl_lever_b",
                 "depth_surface_h_m", "has_dvl", "has_depth", "start_t_ns",
                 "end_t_ns")  # travel with the data (stream_start)
# set by the ins's --learning / replay's --compensation (dvl_learned: with the dvl_beam target; learn_drift: replay's
# compensator of another target turns the drift target's shadow INSs off)
SERVICE_FIELDS = ("learning", "dvl_learned", "learn_drift")


class ParamError(ValueError):
    """A parameter file error: one line, ``file:line: section.key: message``."""


@dataclass(frozen=True)
class Param:
    """One filter setting: its section in the file, the human unit written beside the value, the kind of
    value ("float", "int", "bool", "fix": a FixType name, "vec3": three numbers and one unit, '0, 0, 0 m',
    "choice": one of choices) and the factor to SI (deg -> rad)."""

    section: str
    unit: str
    kind: str = "float"
    to_si: float = 1.0
    choices: tuple = ()


_DEG = math.pi / 180.0

FILTER: dict[str, Param] = {
    # GNSS input checks and the update gate
    "gate_probability": Param("gnss", ""),
    "min_fix": Param("gnss", "", "fix"),
    "min_sats": Param("gnss", "", "int"),
    "max_std_m": Param("gnss", "m"),
    "max_jump_m": Param("gnss", "m"),
    "pos_std_floor_m": Param("gnss", "m"),
    "vel_std_floor_mps": Param("gnss", "m/s"),
    "use_gnss_velocity": Param("gnss", "", "bool"),
    # outage declaration and recovery
    "outage_timeout_s": Param("outage", "s"),
    "gate_reset_s": Param("outage", "s"),
    "gate_reset_max_rate_mps": Param("outage", "m/s"),
    "gate_reset_unsteady_s": Param("outage", "s"),
    "reacquire_fixes": Param("outage", "", "int"),
    # covariance propagation
    "cov_interval_s": Param("covariance", "s"),
    # alignment
    "align_in_motion": Param("alignment", "", "choice", choices=("course", "acceleration", "auto", "dvl")),
    "align_min_speed_mps": Param("alignment", "m/s"),
    "align_course_std": Param("alignment", "deg", to_si=_DEG),
    "align_tilt_std": Param("alignment", "deg", to_si=_DEG),
    "align_still_speed_mps": Param("alignment", "m/s"),
    "align_level_s": Param("alignment", "s"),
    "align_gyrocompass_s": Param("alignment", "s"),
    "align_max_heading_std": Param("alignment", "deg", to_si=_DEG),
    "align_heading_std": Param("alignment", "deg", to_si=_DEG),
    # adaptive measurement noise (seed 001)
    "adaptive_r": Param("adaptive_r", "", "bool"),
    "adaptive_window": Param("adaptive_r", "", "int"),
    "adaptive_forgetting": Param("adaptive_r", ""),
    "adaptive_test_probability": Param("adaptive_r", ""),
    "adaptive_floor": Param("adaptive_r", ""),
    "adaptive_ceiling": Param("adaptive_r", ""),
    # the error state
    "scale_factors": Param("states", "", "bool"),
    # the engine's side of learned compensation
    "learn_after_s": Param("learning", "s"),
    "learn_horizon_s": Param("learning", "s"),
    "learn_answer_max_age_s": Param("learning", "s"),
    "learn_forward_only": Param("learning", "", "bool"),
    "learn_where_better": Param("learning", "", "choice", choices=("off", "nhc", "on")),
    "learn_held_fraction": Param("learning", ""),
    "learn_nhc_floor": Param("learning", "", "bool"),
    "learn_consistency": Param("learning", "", "bool"),
    "learn_consistency_window": Param("learning", "", "int"),
    "dvl_answer_timeout_s": Param("learning", "s"),
    "dvl_anomaly_k_sigma": Param("learning", ""),
    "dvl_anomaly_probability": Param("learning", ""),
    "dvl_anomaly_window": Param("learning", "", "int"),
    "dvl_anomaly_min_count": Param("learning", "", "int"),
    # vehicle-motion constraints
    "nhc": Param("constraints", "", "bool"),
    "nhc_std_mps": Param("constraints", "m/s"),
    "nhc_every_s": Param("constraints", "s"),
    "nhc_corr_s": Param("constraints", "s"),
    "vehicle_mount_euler": Param("constraints", "deg", "vec3", _DEG),
    "vehicle_lever_b": Param("constraints", "m", "vec3"),
    "zupt": Param("constraints", "", "bool"),
    "zupt_window_s": Param("constraints", "s"),
    "zupt_accel_std_mps2": Param("constraints", "m/s^2"),
    "zupt_gyro_rms": Param("constraints", "deg/s", to_si=_DEG),
    "zupt_accel_mps2": Param("constraints", "m/s^2"),
    "zupt_accel_change_mps2": Param("constraints", "m/s^2"),
    "zupt_gnss_speed_mps": Param("constraints", "m/s"),
    "zupt_ins_speed_mps": Param("constraints", "m/s"),
    "zupt_enter_s": Param("constraints", "s"),
    "zupt_every_s": Param("constraints", "s"),
    "zupt_std_mps": Param("constraints", "m/s"),
    "zaru": Param("constraints", "", "bool"),
    "zaru_std": Param("constraints", "deg/s", to_si=_DEG),
    "odometer": Param("constraints", "", "bool"),
    "odo_std_mps": Param("constraints", "m/s"),
    "odo_scale_std": Param("constraints", "%", to_si=0.01),
    "odo_scale_psd": Param("constraints", "%^2/s", to_si=1e-4),
    "odo_scale_tau_s": Param("constraints", "s"),
    "odo_max_age_s": Param("constraints", "s"),
    "odo_max_speed_mps": Param("constraints", "m/s"),
    # consistency monitoring and robust gating
    "consistency": Param("robust", "", "bool"),
    "consistency_window": Param("robust", "", "int"),
    "consistency_test_probability": Param("robust", ""),
    "consistency_max_pos_m": Param("robust", "m"),
    "consistency_max_vel_mps": Param("robust", "m/s"),
    "consistency_max_factor": Param("robust", ""),
    # DVL and depth aiding (an AUV)
    "dvl_mode": Param("dvl", "", "choice", choices=("off", "loose", "tight")),
    "dvl_beam_std_mps": Param("dvl", "m/s"),
    "dvl_velocity_std_mps": Param("dvl", "m/s"),
    "dvl_bias_std_mps": Param("dvl", "m/s"),
    "dvl_bias_psd": Param("dvl", "m^2/s^3"),
    "dvl_bias_tau_s": Param("dvl", "s"),
    "dvl_scale_std": Param("dvl", "%", to_si=0.01),
    "dvl_scale_psd": Param("dvl", "%^2/s", to_si=1e-4),
    "dvl_scale_tau_s": Param("dvl", "s"),
    "dvl_mount_std": Param("dvl", "deg", to_si=_DEG),
    "dvl_mount_psd": Param("dvl", "deg^2/s", to_si=_DEG**2),
    "dvl_mount_tau_s": Param("dvl", "s"),
    "dvl_delay_std_s": Param("dvl", "s"),
    "dvl_delay_psd": Param("dvl", "s^2/s"),
    "dvl_delay_tau_s": Param("dvl", "s"),
    "dvl_max_age_s": Param("dvl", "s"),
    "dvl_max_beam_mps": Param("dvl", "m/s"),
    "depth": Param("dvl", "", "bool"),
    "depth_std_m": Param("dvl", "m"),
    "depth_bias_std_m": Param("dvl", "m"),
    "depth_bias_psd": Param("dvl", "m^2/s"),
    "depth_bias_tau_s": Param("dvl", "s"),
    "depth_max_age_s": Param("dvl", "s"),
    # variational-Bayes adaptive measurement noise
    "vb_dvl": Param("vb", "", "bool"),
    "vb_gnss": Param("vb", "", "bool"),
    "vb_forgetting": Param("vb", ""),
    "vb_iterations": Param("vb", "", "int"),
    "vb_floor": Param("vb", ""),
    "vb_ceiling": Param("vb", ""),
}

# Vehicle profiles (deploy/ins.yaml ``profiles``): the constraints a vehicle runs (a name here: its NavConfig
# switch) and the filter settings it changes (an AUV cruises at 1-2 m/s: in-motion alignment needs a lower speed).
CONSTRAINTS = {"nhc": "nhc", "zupt": "zupt", "odo": "odometer"}
NO_PROFILE = "none"  # constraints.profile: none keeps the file's own switches


@dataclass(frozen=True)
class Profile:
    """A vehicle profile: its constraint names (CONSTRAINTS) and filter settings {NavConfig field: SI value}."""

    constraints: tuple[str, ...] = ()
    settings: tuple[tuple[str, object], ...] = ()

    def filter_settings(self) -> dict:
        """{NavConfig field: value} the profile sets: every constraint switch (on if listed) and its settings."""
        return {**constraint_flags(self.constraints), **dict(self.settings)}


def constraint_flags(names) -> dict:
    """{NavConfig switch: on} for a list of constraint names (CONSTRAINTS); those not named are off. ParamError
    for an unknown name."""
    names = list(names)
    unknown = [n for n in names if n not in CONSTRAINTS]
    if unknown:
        raise ParamError(f"unknown constraint {unknown[0]!r}; known: {', '.join(CONSTRAINTS)}")
    return {flag: name in names for name, flag in CONSTRAINTS.items()}


def load_filter_params(path: str | os.PathLike | None = None, profile: str | None = None) -> dict:
    """{NavConfig field: SI value} from an ins parameter file (``ins:`` mapping of sections). path None:
    deploy/ins.yaml, or NavConfig's defaults when the package is installed without deploy/. A partial file
    leaves the other settings at NavConfig's defaults. A vehicle profile other than none (profile, else the file's
    ``constraints.profile``) sets the constraint switches (nhc, zupt, odometer) to the ones its ``profiles`` entry
    lists, and its own settings over the file's. ParamError for a profile the file does not have."""
    settings, profiles, (name, where) = _load_ins_file(path)
    if profile is not None:
        name, where = profile, "--profile"
    if name == NO_PROFILE:
        return settings
    if name not in profiles:
        raise ParamError(f"{where}: unknown profile {name!r}; the profiles of {path or INS_PARAMS}: "
                         f"{', '.join(sorted(profiles)) or 'none'} (or {NO_PROFILE})")
    return {**settings, **profiles[name].filter_settings()}


def load_profiles(path: str | os.PathLike | None = None) -> dict[str, Profile]:
    """{vehicle profile: Profile} of an ins parameter file's ``profiles`` section (path None: deploy/ins.yaml)."""
    return _load_ins_file(path)[1]


def _load_ins_file(path) -> tuple[dict, dict, tuple[str, str]]:
    """(filter settings without the profile, profiles, (the file's constraints.profile, where it is written)) of an
    ins parameter file (see load_filter_params)."""
    import yaml

    from .yamlfile import load_with_nodes

    p = Path(path) if path else INS_PARAMS
    if not p.exists():
        if path:
            raise ParamError(f"{p}: ins parameter file not found")
        return {}, {}, (NO_PROFILE, "")
    text = p.read_text()
    try:
        doc, root = load_with_nodes(text)
        doc, lines = doc or {}, _key_lines(root)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        raise ParamError(f"{p}:{mark.line + 1 if mark else 0}: not YAML: {getattr(e, 'problem', e)}") from None
    if not isinstance(doc, dict) or set(doc) != {"ins"} or not isinstance(doc["ins"], dict):
        raise ParamError(f"{p}:1: needs one top-level mapping 'ins:' of sections")
    out: dict = {}
    profiles: dict[str, Profile] = {}
    profile = (NO_PROFILE, "")
    for section, entries in doc["ins"].items():
        where = f"{p}:{lines.get((section,), 0)}: {section}"
        if not isinstance(entries, dict):
            raise ParamError(f"{where}: a section is a mapping of settings")
        if section == "profiles":
            profiles = _profiles(entries, p, lines)
            continue
        for key, value in entries.items():
            if (section, key) == ("constraints", "profile"):
                profile = (str(value), f"{p}:{lines.get((section, key), 0)}: {section}.{key}")
                continue
            spec = FILTER.get(key)
            where = f"{p}:{lines.get((section, key), 0)}: {section}.{key}"
            if spec is None or spec.section != section:
                hint = f" (it belongs in section '{spec.section}')" if spec is not None else ""
                raise ParamError(f"{where}: unknown setting{hint}; known in {section}: "
                                 f"{sorted(k for k, s in FILTER.items() if s.section == section) or 'none'}")
            out[key] = _convert(value, spec, where)
    if profile[0] != NO_PROFILE and profile[0] not in profiles:
        raise ParamError(f"{profile[1]}: unknown profile {profile[0]!r}; the file's profiles: "
                         f"{sorted(profiles) or 'none'} (or {NO_PROFILE})")
    return out, profiles, profile


def _profiles(entries: dict, p: Path, lines: dict) -> dict[str, Profile]:
    """The ``profiles`` section, checked: {name: [constraint names]} or {name: {constraints: [names], setting:
    value in its unit, ...}}."""
    out = {}
    for name, entry in entries.items():
        where = f"{p}:{lines.get(('profiles', name), 0)}: profiles.{name}"
        body = entry if isinstance(entry, dict) else {"constraints": entry}
        names = body.get("constraints", [])
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise ParamError(f"{where}: a profile is a list of constraint names ({', '.join(CONSTRAINTS)}) or a "
                             "mapping of 'constraints: [names]' and filter settings")
        try:
            constraint_flags(names)
        except ParamError as e:
            raise ParamError(f"{where}: {e}") from None
        settings = []
        for key, value in body.items():
            if key == "constraints":
                continue
            spec = FILTER.get(key)
            if spec is None or key in CONSTRAINTS.values():
                raise ParamError(f"{where}.{key}: not a filter setting a profile can set (the constraint switches "
                                 "come from its constraints list)")
            settings.append((key, _convert(value, spec, f"{where}.{key}")))
        out[str(name)] = Profile(tuple(names), tuple(settings))
    return out


def _key_lines(node) -> dict:
    """{(section,): line, (section, key): line} (1-based) of an ``ins:`` document's composed YAML node."""
    out: dict[tuple, int] = {}
    if node is None or not hasattr(node, "value") or not isinstance(node.value, list):
        return out
    for k_top, v_top in node.value:
        if getattr(k_top, "value", None) != "ins" or not isinstance(getattr(v_top, "value", None), list):
            continue
        for k_sec, v_sec in v_top.value:
            out[(k_sec.value,)] = k_sec.start_mark.line + 1
            if isinstance(getattr(v_sec, "value", None), list):
                for k, _v in v_sec.value:
                    out[(k_sec.value, k.value)] = k.start_mark.line + 1
    return out


def _convert(value, spec: Param, where: str):
    """A file value ('0.05 m', 2, 'SINGLE', true) -> its SI value, checking the unit."""
    from .nav.types import FixType

    if spec.kind == "bool":
        if type(value) is not bool:
            raise ParamError(f"{where}: {value!r} is not true/false")
        return value
    if spec.kind == "fix":
        names = [f.name for f in FixType]
        if not isinstance(value, str) or value.upper() not in names:
            raise ParamError(f"{where}: {value!r} is not a fix type ({', '.join(names)})")
        return int(FixType[value.upper()])
    if spec.kind == "vec3":
        return _convert_vec3(value, spec, where)
    if spec.kind == "choice":
        if isinstance(value, bool) and ("on" if value else "off") in spec.choices:
            value = "on" if value else "off"  # YAML 1.1 reads a bare on / off as a boolean
        if not isinstance(value, str) or value not in spec.choices:
            raise ParamError(f"{where}: {value!r} is not one of {', '.join(spec.choices)}")
        return value
    number, unit = value, ""
    if isinstance(value, str):
        number, _, unit = value.strip().partition(" ")
        unit = unit.strip()
    if unit != spec.unit:
        want = f"'{spec.unit}'" if spec.unit else "no unit (a plain number)"
        got = f"unit '{unit}'" if unit else "no unit"
        raise ParamError(f"{where}: {got} where {want} is expected")
    if spec.kind == "int":
        if type(number) is not int and not (isinstance(number, str) and number.lstrip("-").isdigit()):
            raise ParamError(f"{where}: {value!r} is not an integer")
        return int(number)
    try:
        x = float(number)
    except (TypeError, ValueError):
        raise ParamError(f"{where}: {value!r} is not a number{f' in {spec.unit}' if spec.unit else ''}") from None
    if not math.isfinite(x):
        raise ParamError(f"{where}: {value!r} is not finite")
    return x * spec.to_si if spec.to_si != 1.0 else x


def _convert_vec3(value, spec: Param, where: str) -> tuple:
    """'x, y, z unit' -> (x, y, z) in SI, checking the unit."""
    numbers, _, unit = str(value).strip().rpartition(" ")
    if unit != spec.unit:
        raise ParamError(f"{where}: {value!r}: three numbers and the unit '{spec.unit}' expected "
                         f"('0, 0, 0 {spec.unit}')")
    try:
        xyz = [float(x) for x in numbers.split(",")]
    except ValueError:
        raise ParamError(f"{where}: {value!r} is not three numbers in {spec.unit}") from None
    if len(xyz) != 3 or not all(map(math.isfinite, xyz)):
        raise ParamError(f"{where}: {value!r} is not three finite numbers in {spec.unit}")
    return tuple(x * spec.to_si if spec.to_si != 1.0 else x for x in xyz)


def nav_config(sensor, filter_params: dict):
    """The NavConfig the engine runs: the sensor description (a NavConfig or a stream_start ``config`` map;
    only SENSOR_FIELDS are taken) with the filter settings of a parameter file (load_filter_params)."""
    from .messages import map_to_dataclass
    from .nav.types import NavConfig

    if isinstance(sensor, dict):
        sensor = map_to_dataclass(NavConfig, {k: v for k, v in sensor.items() if k in SENSOR_FIELDS})
    return NavConfig(**{f: getattr(sensor, f) for f in SENSOR_FIELDS}).with_(**filter_params)


def sensor_map(config) -> dict:
    """The sensor description of a NavConfig as a msgpack-able map (stream_start's ``config``)."""
    from .messages import pyval

    return {f: pyval(getattr(config, f)) for f in SENSOR_FIELDS}


def check_complete() -> list[str]:
    """NavConfig fields that are neither sensor description, service switch nor a FILTER setting (should be
    none: a new engine setting must be given a unit and a section here and a line in deploy/ins.yaml)."""
    from .nav.types import NavConfig

    return [f.name for f in fields(NavConfig) if f.name not in FILTER and f.name not in SENSOR_FIELDS
            and f.name not in SERVICE_FIELDS]


def load_attitude_params(path: str | os.PathLike | None = None):
    """(ComplementaryConfig, origin) from an attitude parameter file (``attitude:`` mapping, human units). path
    None: the ZENNAV_ATTITUDE_CONFIG file, else deploy/attitude.yaml, else the built-in defaults (same values)."""
    import yaml

    from .attitude.complementary import ComplementaryConfig

    explicit = path or os.environ.get("ZENNAV_ATTITUDE_CONFIG")
    p = Path(explicit) if explicit else ATTITUDE_PARAMS
    if not p.exists():
        if explicit:
            raise ParamError(f"{p}: attitude parameter file not found")
        return ComplementaryConfig(), "built-in defaults"
    doc = yaml.safe_load(p.read_text()) or {}
    if not isinstance(doc, dict) or not isinstance(doc.get("attitude"), dict):
        raise ParamError(f"{p}:1: needs an 'attitude:' mapping")
    try:
        return ComplementaryConfig.from_mapping(doc["attitude"]), str(p)
    except ValueError as e:
        raise ParamError(f"{p}: {e}") from None
