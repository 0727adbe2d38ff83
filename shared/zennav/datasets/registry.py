"""Find and load datasets by name: the recordings in the shared data folder, KF-GINS YAML files, the simulator."""
from __future__ import annotations

import inspect
import logging
import os
from collections.abc import Callable
from functools import partial
from pathlib import Path

from zennav.datasets.errors import DataError
from zennav.nav.types import Dataset

log = logging.getLogger("zennav.datasets")

RECORDINGS = {"rtklibexplorer": "rtklibexplorer_drive_0708", "comma2k19": "comma2k19_example_segment"}
SIM_KINDS = ("car", "multirotor", "static", "auv")
ANSFL_FOLDER = "ansfl_quadrotor_dji_rtk"
ANSFL_FLIGHTS = {"Horizontal": 27, "Vertical": 30, "StraightLine": 4}  # ansfl:<group>/path_1..N
ANSFL_ACCEPTED = ", ".join(f"ansfl:{group}/path_1..{n}" for group, n in ANSFL_FLIGHTS.items())
AKIT_FOLDER = "akit_snapir_auv_dvl"
AKIT_TRAJECTORIES = 13  # akit:Trajectory1..13
AKIT_ACCEPTED = f"akit:Trajectory1..{AKIT_TRAJECTORIES}"
ACCEPTED = (
    f"{', '.join(RECORDINGS)}, {ANSFL_ACCEPTED}, {AKIT_ACCEPTED}, a KF-GINS .yaml/.yml file, a dataset folder, or "
    + ", ".join(f"sim:{kind}" for kind in SIM_KINDS)
)


# The vehicle of each named dataset: its profile in the ins parameter file (zennav replay --profile dataset).
VEHICLES = {"rtklibexplorer": "car", "comma2k19": "car", "sim:car": "car", "sim:multirotor": "multirotor",
            "ansfl:": "multirotor", "sim:auv": "auv", "akit:": "auv"}


def vehicle_of(spec: str) -> str:
    """The vehicle profile of a dataset spec (VEHICLES; ansfl:* flights are multirotors, akit:* trajectories
    AUVs); "none" when unknown (sim:static, dataset folders, KF-GINS files)."""
    prefix = next((p for p in ("ansfl:", "akit:") if spec.startswith(p)), None)
    return VEHICLES.get(spec, "none" if prefix is None else VEHICLES[prefix])


def ansfl_specs() -> list[str]:
    """Every ansfl:<group>/path_<n> spec, in order."""
    return [f"ansfl:{group}/path_{k}" for group, n in ANSFL_FLIGHTS.items() for k in range(1, n + 1)]


def akit_specs() -> list[str]:
    """Every akit:TrajectoryN spec, in order."""
    return [f"akit:Trajectory{n}" for n in range(1, AKIT_TRAJECTORIES + 1)]


def data_root() -> Path:
    """The shared data folder: $ZENNAV_DATA, else the first existing of <repo>/../shared/data (repo found by
    walking up from this file to pyproject.toml), ./../shared/data, /work/shared/data."""
    env = os.environ.get("ZENNAV_DATA")
    if env:
        if not Path(env).is_dir():
            raise DataError(env, "ZENNAV_DATA is not a directory")
        return Path(env)
    here = Path(__file__).resolve()
    repo = next((p for p in here.parents if (p / "pyproject.toml").is_file()), None)
    candidates = ([repo.parent / "shared" / "data"] if repo else []) + [Path.cwd().parent / "shared" / "data"]
    candidates.append(Path("/work/shared/data"))
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    raise DataError("data root", f"no data folder found (set ZENNAV_DATA); looked in {', '.join(map(str, candidates))}")


def _folder_loader(folder: Path) -> Callable[..., Dataset]:
    """The loader of a dataset folder, recognized by its files (only that loader is imported: start-up time)."""
    if (folder / "global_pose").is_dir() and (folder / "processed_log").is_dir():
        from zennav.datasets import comma2k19

        return partial(comma2k19.load, folder)
    if (folder / "GT.csv").is_file() and (folder / "IMU_1.csv.gz").is_file():
        from zennav.datasets import ansfl

        return partial(ansfl.load, folder)
    if any(folder.glob("imu_*.csv.tag")) and any(folder.glob("*.pos")):
        from zennav.datasets import rtklibexplorer

        return partial(rtklibexplorer.load, folder)
    configs = sorted(folder.glob("*.yaml")) + sorted(folder.glob("*.yml"))
    if len(configs) == 1:
        from zennav.datasets import kfgins

        return partial(kfgins.load_config, configs[0])
    raise DataError(folder, f"not a known dataset folder (comma2k19, rtklibexplorer, an ANSFL flight, or one "
                            f"KF-GINS YAML); "
                            f"found {len(configs)} YAML files")


def _option_names(*fns, skip=()) -> list[str]:
    """The keyword parameters of fns (partials: those not yet bound), minus skip: the loader options they take."""
    names: set[str] = set()
    for fn in fns:
        params = inspect.signature(fn).parameters.values()
        names |= {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    return sorted(names - set(skip))


def _sim_loader(kind: str) -> tuple[Callable[..., Dataset], list[str]]:
    """The simulator's dataset function of a scenario and the options it takes (its own and its trajectory's)."""
    from zennav.sim import trajectory as tr

    moving = {"car": tr.car_trajectory, "multirotor": tr.multirotor_trajectory, "auv": tr.auv_trajectory}
    given = ("kind", "duration_s", "seed", "start_llh")  # make_trajectory's own arguments
    traj = _option_names(moving[kind], skip=given) if kind in moving else ["euler", "yaw_rate"]  # StaticTrajectory
    from zennav.sim.scenarios import make_dataset

    if kind == "auv":
        from zennav.sim.auv import make_auv_dataset

        return make_auv_dataset, sorted(set(_option_names(make_auv_dataset, make_dataset, skip=("kind",)) + traj))
    return partial(make_dataset, kind), sorted(set(_option_names(make_dataset, skip=("kind",)) + traj))


def _call_loader(spec: str, load: Callable[..., Dataset], accepted: list[str], options: dict) -> Dataset:
    """load(**options), a mistake in the options (an unknown name, a value of the wrong type or range) as one
    DataError that names them; the loader's remarks (what it changed or left out: notes["remarks"]) logged as
    warnings."""
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise DataError(spec, f"unknown loader option {', '.join(unknown)}; accepted: {', '.join(accepted) or 'none'}")
    try:
        ds = load(**options)
    except (TypeError, ValueError, ArithmeticError, IndexError) as e:
        if not options:
            raise
        given = ", ".join(f"{k}={v!r}" for k, v in options.items())
        raise DataError(spec, f"loader options {given} not usable: {e}") from None
    for remark in ds.notes.get("remarks") or []:
        log.warning("%s: %s", spec, remark)
    return ds


def parse_loader_options(items) -> dict:
    """Loader options given as 'key=value' strings (the -o of zennav-ingest, zennav replay, report, gnss-sim) ->
    {key: int | float | bool | None | str}."""
    out = {}
    for it in items or []:
        k, _, v = it.partition("=")
        for conv in (int, float):
            try:
                v = conv(v)
                break
            except ValueError:
                pass
        else:
            v = {"true": True, "false": False, "none": None}.get(v.lower(), v)
        out[k] = v
    return out


def load_dataset(spec: str, defer_truth: bool = False, stream_imu: bool = False, **options) -> Dataset:
    """Load a dataset from ``spec``: one of ACCEPTED. ``options`` go to the loader (e.g. prefilter="none"); a wrong
    one is a DataError. defer_truth: a KF-GINS configuration's truth file is left unread (kfgins.load_deferred_truth
    reads it)."""
    load: Callable[..., Dataset]
    if spec in RECORDINGS:
        load = _folder_loader(data_root() / RECORDINGS[spec])
    elif spec.startswith("ansfl:"):
        if spec not in ansfl_specs():
            raise DataError(spec, f"unknown ANSFL flight; accepted: {ANSFL_ACCEPTED}")
        from zennav.datasets import ansfl

        load = partial(ansfl.load, data_root() / ANSFL_FOLDER / spec[6:])
    elif spec.startswith("akit:"):
        if spec not in akit_specs():
            raise DataError(spec, f"unknown A-KIT trajectory; accepted: {AKIT_ACCEPTED}")
        from zennav.datasets import akit

        load = partial(akit.load, data_root() / AKIT_FOLDER / spec[5:])
    elif spec.startswith("sim:"):
        kind = spec[4:]
        if kind not in SIM_KINDS:
            raise DataError(spec, f"unknown simulator scenario; accepted: {', '.join(SIM_KINDS)}")
        load, accepted = _sim_loader(kind)
        return _call_loader(spec, load, accepted, options)
    elif Path(spec).suffix.lower() in (".yaml", ".yml"):
        from zennav.datasets import kfgins

        load = partial(kfgins.load_config, Path(spec), defer_truth=defer_truth, stream_imu=stream_imu)
        return _call_loader(spec, load, _option_names(load, skip=("defer_truth", "stream_imu")), options)
    elif Path(spec).is_dir():
        load = _folder_loader(Path(spec))
    else:
        raise DataError(spec, f"unknown dataset; accepted: {ACCEPTED}")
    return _call_loader(spec, load, _option_names(load), options)


def available() -> list[str]:
    """Specs that load_dataset accepts right now: the recordings, ANSFL flights and A-KIT trajectories present in
    data_root() and the simulator scenarios."""
    try:
        root = data_root()
    except DataError:
        root = None
    recordings = [name for name, folder in RECORDINGS.items() if root is not None and (root / folder).is_dir()]
    flights = [spec for spec in ansfl_specs() if root is not None and (root / ANSFL_FOLDER / spec[6:]).is_dir()]
    auv = [spec for spec in akit_specs() if root is not None and (root / AKIT_FOLDER / spec[5:]).is_dir()]
    return recordings + flights + auv + [f"sim:{kind}" for kind in SIM_KINDS]
