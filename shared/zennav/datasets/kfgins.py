"""KF-GINS (i2Nav-WHU/KF-GINS) text files and YAML configuration, so a KF-GINS user's files run unchanged.

Text files, split on spaces, tabs or commas as KF-GINS does (``#`` starts a comment, a zennav extension):
- IMU: ``imudatalen`` columns (at least 7): GPS seconds of week [s], dtheta x y z [rad], dvel x y z [m/s],
  body frame FRD, increments over the interval that ends at the time; columns after the 7th are ignored.
- GNSS: 7 columns: sow, lat [deg], lon [deg], h [m], std north east down [m]; or 13 columns in the order
  KF-GINS's GnssFileLoader reads them: sow, lat, lon, h, vn ve vd [m/s], std n e d [m], std vn ve vd [m/s].
- GNSS velocity (zennav extension, YAML key ``gnssvelpath``): 7 columns: sow, vn ve vd [m/s], std vn ve vd [m/s],
  one row per GNSS epoch with the same times.
- .nav (truth, and KF-GINS's result): 11 columns: GPS week, sow, lat [deg], lon [deg], h [m], vn ve vd [m/s],
  roll pitch yaw [deg].

Times become ``t_ns = round(sow * 1e9)`` (seconds of week). The writers take a GPS week so that datasets timed in
seconds since the GPS epoch are written as seconds of week; they write exact nanoseconds and 17 significant digits
for the increments, so a run from converted files matches a run from the native loader.
"""
from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import Literal, overload

import numpy as np
import yaml

from zennav.datasets.errors import DataError, Table, read_table, read_table_head, read_text
from zennav.datasets.fasttext import in_background, write_table
from zennav.datasets.streamed import StreamedImu
from zennav.nav.rotation import wrap_angle
from zennav.nav.types import NS, Dataset, FixType, GnssData, ImuData, ImuNoise, InitialState, NavConfig, Truth
from zennav.yamlfile import load_with_nodes

WEEK_NS = 604800 * NS
D2R = math.pi / 180.0
MGAL = 1e-5  # [m/s^2]
DEG_PER_H = D2R / 3600.0  # [rad/s]
PPM = 1e-6  # scale factor [-]
SQRT_H = 60.0  # sqrt(3600 s)
TRUTH_FIELDS = ("pos", "vel", "att")
IMU_HEAD_BYTES = 1 << 18  # [bytes] of an IMU file parsed before a replay starts (the rest on first use: StreamedImu)


def _t_ns(seconds) -> np.ndarray:
    """Seconds [s] -> integer nanoseconds (int64)."""
    return np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64)


def _llh(lat_deg, lon_deg, h, table) -> np.ndarray:
    """(lat, lon [rad], h [m]) from degrees, with a DataError at the first row out of range."""
    bad = np.flatnonzero((np.abs(lat_deg) > 90.0) | (np.abs(lon_deg) > 360.0))
    if bad.size:
        k = int(bad[0])
        raise table.error(k, f"latitude {lat_deg[k]} / longitude {lon_deg[k]} deg out of range")
    return np.column_stack([np.deg2rad(lat_deg), np.deg2rad(lon_deg), h])


def _require_positive(table, values: np.ndarray, what: str) -> None:
    """A DataError at the first row with a value <= 0 (the engine refuses such a fix: counter gnss_std)."""
    bad = np.flatnonzero((values <= 0.0).any(axis=1))
    if bad.size:
        raise table.error(int(bad[0]), f"{what} must be positive")


def _timed_table(path, columns, time_col: int = 0, remarks: list[str] | None = None, table: Table | None = None):
    """A finite table whose column ``time_col`` (sow [s]) increases; returns (table, t_ns, keep). Without remarks a
    time not after the previous row's is a DataError; with remarks such rows (a duplicated or out-of-order record)
    are left out of keep (bool (N,): the rows to use), and a remark counts them. table: the file's rows already
    read (else read here)."""
    table = table or read_table(path, columns, commas_as_space=True)
    table.require_finite()
    t_ns = _t_ns(table.data[:, time_col])
    if remarks is None:
        table.require_increasing(t_ns)
        return table, t_ns, np.ones(len(t_ns), dtype=bool)
    keep = np.ones(len(t_ns), dtype=bool)
    keep[1:] = t_ns[1:] > np.maximum.accumulate(t_ns)[:-1]
    dropped = np.flatnonzero(~keep)
    if dropped.size:
        remarks.append(f"{Path(path).name}: {dropped.size} rows left out, their time not after an earlier row's "
                       f"(a duplicated or out-of-order record; first: line {table.line_of(int(dropped[0]))})")
    return table, t_ns, keep


def load_imu(path, columns: int = 7, remarks: list[str] | None = None, head_bytes: int = 0) -> ImuData:
    """KF-GINS IMU file (``columns`` = imudatalen) -> ImuData (t_ns in seconds of week, FRD increments). remarks:
    leave duplicated and out-of-order rows out and say so there (else they are a DataError). head_bytes > 0: a file
    longer than that comes as a StreamedImu, its head the complete lines within the first head_bytes (a replay
    starts on them), the rest read on first use."""
    if head_bytes > 0:
        head = read_table_head(path, columns, head_bytes, commas_as_space=True)
        if head is not None:  # the head's remarks are the whole's, made when it is read
            rows = _imu_rows(path, columns, None if remarks is None else [], head)
            span_s = (int(rows.t_ns[-1]) - int(rows.t_ns[0])) / NS * Path(path).stat().st_size / head_bytes
            return StreamedImu(rows, partial(load_imu, path, columns, remarks), str(path), span_s=span_s)
    return _imu_rows(path, columns, remarks)


def _imu_rows(path, columns: int, remarks: list[str] | None, table: Table | None = None) -> ImuData:
    """load_imu of the file's rows (table: those already read, else all)."""
    table, t_ns, keep = _timed_table(path, columns, remarks=remarks, table=table)
    d = table.data[keep]
    return ImuData(t_ns[keep], d[:, 1:4].copy(), d[:, 4:7].copy())


def load_gnss(path, vel_path=None, fix: FixType = FixType.SINGLE, remarks: list[str] | None = None) -> GnssData:
    """KF-GINS GNSS file (7 or 13 columns), optionally merged with a zennav velocity file -> GnssData.

    Every epoch gets ``fix`` (the format does not carry it) and num_sats -1 (unknown). remarks: leave duplicated and
    out-of-order epochs out and say so there (else they are a DataError).
    """
    table, t_ns, keep = _timed_table(path, (7, 13), remarks=remarks)
    d = table.data
    llh = _llh(d[:, 1], d[:, 2], d[:, 3], table)
    v_n = std_v_n = None
    if d.shape[1] == 7:
        std_ned = d[:, 4:7].copy()
    else:
        v_n, std_ned, std_v_n = d[:, 4:7].copy(), d[:, 7:10].copy(), d[:, 10:13].copy()
        _require_positive(table, std_v_n, "velocity std")
    _require_positive(table, std_ned, "position std")
    if vel_path is not None:
        if v_n is not None:
            raise DataError(vel_path, f"velocity given twice: {Path(path).name} already has 13 columns")
        v_n, std_v_n = _load_velocity(vel_path, t_ns)
    m = int(keep.sum())
    return GnssData(t_ns[keep], llh[keep], std_ned[keep], None if v_n is None else v_n[keep],
                    None if std_v_n is None else std_v_n[keep], np.full(m, int(fix), dtype=np.int64),
                    np.full(m, -1, dtype=np.int64))


def _load_velocity(path, gnss_t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """zennav GNSS velocity file -> (v_n, std_v_n) [m/s]; its times must equal the GNSS file's, row by row (all rows:
    load_gnss leaves the same ones out of both)."""
    table = read_table(path, 7, commas_as_space=True)
    table.require_finite()
    t_ns = _t_ns(table.data[:, 0])
    n = min(len(t_ns), len(gnss_t_ns))
    bad = np.flatnonzero(t_ns[:n] != gnss_t_ns[:n])
    if bad.size:
        k = int(bad[0])
        raise table.error(k, f"time {t_ns[k] / 1e9:.9f} s does not match the GNSS epoch {gnss_t_ns[k] / 1e9:.9f} s")
    if len(t_ns) != len(gnss_t_ns):
        raise DataError(path, f"{len(t_ns)} velocity rows for {len(gnss_t_ns)} GNSS epochs")
    _require_positive(table, table.data[:, 4:7], "velocity std")
    return table.data[:, 1:4].copy(), table.data[:, 4:7].copy()


def load_nav(path, source: str = "", fields=TRUTH_FIELDS, at_antenna: bool = False) -> Truth:
    """KF-GINS .nav file (11 columns) -> Truth (t_ns in seconds of week; yaw wrapped to (-pi, pi]).

    fields: which of "pos", "vel", "att" hold data; the others are left None (a zennav extension).
    """
    table, t_ns, _ = _timed_table(path, 11, time_col=1)
    d = table.data
    euler = np.deg2rad(d[:, 8:11])
    euler[:, 2] = wrap_angle(euler[:, 2])
    return Truth(
        t_ns=t_ns,
        llh=_llh(d[:, 2], d[:, 3], d[:, 4], table),
        v_n=d[:, 5:8].copy() if "vel" in fields else None,
        euler=euler if "att" in fields else None,
        source=source or f"KF-GINS .nav file {Path(path).name}",
        at_antenna=at_antenna,
    )


# ----------------------------------------------------------------------------------------------- writers


def _sow_ns(t_ns, week: int) -> np.ndarray:
    """Nanoseconds of GPS week ``week`` of t_ns [ns]; ValueError if a time is before the week."""
    sow_ns = np.asarray(t_ns, dtype=np.int64) - np.int64(week) * WEEK_NS
    if sow_ns.size and sow_ns.min() < 0:
        raise ValueError(f"times before GPS week {week}")
    return sow_ns


def _write_rows(path, t_ns, week: int, columns: list[np.ndarray], fmt: str, lead: str | None = None) -> None:
    """One line per row: [lead] sow as exact decimal seconds ('%d.%09d'), the columns (N,) formatted with ``fmt`` (one
    %-spec per column)."""
    write_table(path, columns, fmt.split(" "), " ", lead, _sow_ns(t_ns, week))


def write_imu(path, imu: ImuData, week: int = 0) -> None:
    """KF-GINS IMU file (7 columns): sow [s], dtheta [rad], dvel [m/s], 17 significant digits."""
    _write_rows(path, imu.t_ns, week, [*imu.dtheta.T, *imu.dvel.T], " ".join(["%.16e"] * 6))


def write_gnss(path, gnss: GnssData, week: int = 0, vel_path=None) -> None:
    """KF-GINS GNSS file (7 columns) and, if vel_path is given, the zennav velocity file (needs gnss.v_n)."""
    deg = [np.rad2deg(gnss.llh[:, 0]), np.rad2deg(gnss.llh[:, 1]), gnss.llh[:, 2], *gnss.std_ned.T]
    _write_rows(path, gnss.t_ns, week, deg, "%.13f %.13f %.9f %.9f %.9f %.9f")
    if vel_path is not None:
        if gnss.v_n is None or gnss.std_v_n is None:
            raise ValueError("write_gnss: vel_path given but the GNSS data has no velocity")
        _write_rows(vel_path, gnss.t_ns, week, [*gnss.v_n.T, *gnss.std_v_n.T], " ".join(["%.9f"] * 6))


def write_nav(path, week: int, t_ns, llh, v_n, euler) -> None:
    """KF-GINS .nav file: week, sow, lat lon [deg], h [m], v_n [m/s], roll pitch yaw [deg] (llh/euler in rad)."""
    llh, v_n, euler = (np.asarray(x, dtype=float) for x in (llh, v_n, euler))
    cols = [np.rad2deg(llh[:, 0]), np.rad2deg(llh[:, 1]), llh[:, 2], *v_n.T, *np.rad2deg(euler).T]
    fmt = "%.13f %.13f %.9f %.9f %.9f %.9f %.12f %.12f %.12f"
    _write_rows(path, t_ns, week, cols, fmt, lead=str(week))


def write_dataset(dataset: Dataset, folder, name: str | None = None) -> Path:
    """Write a Dataset as KF-GINS files plus a YAML configuration in ``folder``; returns the YAML path.

    Times are written as seconds of the GPS week of the first IMU sample. The KF-GINS format keeps no fix type,
    satellite count or zennav-only NavConfig fields (gates, timeouts): load_config gives their defaults.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    name = name or dataset.name
    imu, gnss, init, cfg, noise = dataset.imu, dataset.gnss, dataset.initial, dataset.config, dataset.config.imu_noise
    week = int(imu.t_ns[0] // WEEK_NS)
    files = {"imupath": f"{name}_imu.txt", "gnsspath": f"{name}_gnss.txt"}
    if gnss.v_n is not None:
        files["gnssvelpath"] = f"{name}_gnssvel.txt"
    write_imu(folder / files["imupath"], imu, week)
    vel_path = folder / files["gnssvelpath"] if "gnssvelpath" in files else None
    write_gnss(folder / files["gnsspath"], gnss, week, vel_path)

    def sow(t_ns: int) -> float:
        return (t_ns - week * WEEK_NS) / NS

    def vec(values, scale=1.0) -> list[float]:
        return [float(x) * scale for x in values]

    dt_s = np.median(np.diff(imu.t_ns)) / NS
    imunoise: dict[str, float | list[float]] = {
        "arw": [noise.arw * SQRT_H / D2R] * 3,
        "vrw": [noise.vrw * SQRT_H] * 3,
        "gbstd": [noise.gyro_bias_std / DEG_PER_H] * 3,
        "abstd": [noise.accel_bias_std / MGAL] * 3,
        "gsstd": [noise.gyro_scale_std / PPM] * 3,
        "asstd": [noise.accel_scale_std / PPM] * 3,
        "corrtime": noise.gyro_bias_tau / 3600.0,
    }
    if noise.accel_bias_tau != noise.gyro_bias_tau:
        imunoise["acccorrtime"] = noise.accel_bias_tau / 3600.0
    config: dict[str, object] = {
        **files,
        "outputpath": ".",
        "imudatalen": 7,
        "imudatarate": int(round(1.0 / dt_s)),
        "starttime": sow(init.t_ns),
        "endtime": -1 if cfg.end_t_ns is None else sow(cfg.end_t_ns),
        "initpos": [math.degrees(init.llh[0]), math.degrees(init.llh[1]), float(init.llh[2])],
        "initvel": vec(init.v_n),
        "initatt": vec(np.rad2deg(init.euler)),
        "initgyrbias": vec(init.gyro_bias, 1.0 / DEG_PER_H),
        "initaccbias": vec(init.accel_bias, 1.0 / MGAL),
        "initgyrscale": vec(init.gyro_scale, 1.0 / PPM),
        "initaccscale": vec(init.accel_scale, 1.0 / PPM),
        "initposstd": vec(init.std_pos_ned),
        "initvelstd": vec(init.std_v_n),
        "initattstd": vec(np.rad2deg(init.std_euler)),
        "imunoise": imunoise,
        "antlever": vec(cfg.lever_arm_b),
    }
    if init.std_gyro_bias is not None:
        config["initbgstd"] = vec(init.std_gyro_bias, 1.0 / DEG_PER_H)
    if init.std_accel_bias is not None:
        config["initbastd"] = vec(init.std_accel_bias, 1.0 / MGAL)
    if init.std_gyro_scale is not None:
        config["initsgstd"] = vec(init.std_gyro_scale, 1.0 / PPM)
    if init.std_accel_scale is not None:
        config["initsastd"] = vec(init.std_accel_scale, 1.0 / PPM)
    truth = dataset.truth
    if truth is not None:
        truth_file = config["truthpath"] = f"{name}_truth.nav"
        zeros = np.zeros((len(truth.t_ns), 3))
        write_nav(
            folder / truth_file,
            week,
            truth.t_ns,
            truth.llh,
            truth.v_n if truth.v_n is not None else zeros,
            truth.euler if truth.euler is not None else zeros,
        )
        fields = ["pos"] + (["vel"] if truth.v_n is not None else []) + (["att"] if truth.euler is not None else [])
        config["truthinfo"] = {"fields": fields, "source": truth.source, "at_antenna": bool(truth.at_antenna)}
    yaml_path = folder / f"{name}.yaml"
    header = f"# KF-GINS configuration written by zennav from '{dataset.name}'; times: seconds of GPS week {week}\n"
    body = yaml.safe_dump(config, sort_keys=False, default_flow_style=None, width=1000)
    yaml_path.write_text(header + body, encoding="utf-8")
    return yaml_path


# ----------------------------------------------------------------------------------------------- YAML


class _Config:
    """A parsed YAML file with line numbers for error messages."""

    def __init__(self, path: Path):
        self.path = path
        text = read_text(path)
        try:
            self.data, self.root = load_with_nodes(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise DataError(path, f"invalid YAML: {problem}", mark.line + 1 if mark else None) from None
        if not isinstance(self.data, dict):
            raise DataError(path, "expected a mapping of KF-GINS keys (imupath, gnsspath, ...)")
        self.notes: list[str] = []

    def line(self, *keys) -> int | None:
        """1-based line of the value at keys (of the deepest existing parent if absent)."""
        node, line = self.root, None
        for key in keys:
            if not isinstance(node, yaml.MappingNode):
                break
            match = [(k, v) for k, v in node.value if k.value == key]
            if not match:
                break
            node, line = match[0][1], match[0][0].start_mark.line + 1
        return line

    def error(self, keys, message: str) -> DataError:
        return DataError(self.path, f"{'.'.join(keys)}: {message}", self.line(*keys))

    def get(self, *keys, required: bool = True):
        value = self.data
        for key in keys:
            if not isinstance(value, dict) or key not in value:
                if required:
                    raise DataError(self.path, f"missing required key '{'.'.join(keys)}'", self.line(*keys[:-1]))
                return None
            value = value[key]
        return value

    @overload
    def number(self, *keys: str, required: Literal[True] = ...) -> float: ...
    @overload
    def number(self, *keys: str, required: bool) -> float | None: ...

    def number(self, *keys: str, required: bool = True) -> float | None:
        value = self.get(*keys, required=required)
        if value is None and not required:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(keys, f"expected a finite number, got {value!r}")
        return float(value)

    @overload
    def vector(self, *keys: str, required: Literal[True] = ..., positive: bool = ...) -> np.ndarray: ...
    @overload
    def vector(self, *keys: str, required: bool, positive: bool = ...) -> np.ndarray | None: ...

    def vector(self, *keys: str, required: bool = True, positive: bool = False) -> np.ndarray | None:
        value = self.get(*keys, required=required)
        if value is None and not required:
            return None
        ok = isinstance(value, list) and len(value) == 3
        ok = ok and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)
        if not ok:
            raise self.error(keys, f"expected a list of 3 finite numbers, got {value!r}")
        vec = np.array(value, dtype=float)
        if positive and (vec <= 0).any():
            raise self.error(keys, f"standard deviations must be positive, got {value!r}")
        return vec

    def per_sensor(self, *keys) -> float:
        """One value for the three axes (zennav keeps one noise value per sensor): the largest."""
        vec = self.vector(*keys, positive=keys[-1] in ("arw", "vrw"))
        if (vec < 0).any():
            raise self.error(keys, f"must not be negative, got {vec.tolist()}")
        if np.ptp(vec) > 0:
            self.notes.append(f"{'.'.join(keys)} differs per axis; zennav uses the largest, {vec.max()}")
        return float(vec.max())

    @overload
    def file(self, key: str, required: Literal[True] = ...) -> Path: ...
    @overload
    def file(self, key: str, required: bool) -> Path | None: ...

    def file(self, key: str, required: bool = True) -> Path | None:
        """A file path; relative paths as KF-GINS (current directory), else relative to the YAML's folder, else to the
        folder above it (KF-GINS's own layout: `dataset/kf-gins.yaml` names `./dataset/X.txt`, relative to the
        repository's root, from which KF-GINS is run)."""
        value = self.get(key, required=required)
        if value is None and not required:
            return None
        if not isinstance(value, str) or not value:
            raise self.error((key,), f"expected a file path, got {value!r}")
        path = Path(value)
        bases = [] if path.is_absolute() else self._bases()
        for candidate in [base / path for base in bases] or [path]:
            if candidate.is_file():
                return candidate
        where = f" (looked in {', '.join(map(str, bases))})" if bases else ""
        raise self.error((key,), f"file '{value}' not found{where}")

    def folder(self, key: str) -> Path:
        """An output folder (default "."): relative ones as KF-GINS (current directory) when it exists there, else the
        first existing one relative to the YAML's folder or the folder above it (as file()), else the current
        directory's (created when written)."""
        value = self.get(key, required=False) or "."
        if not isinstance(value, str):
            raise self.error((key,), f"expected a folder path, got {value!r}")
        path = Path(value)
        if path.is_absolute():
            return path
        return next((base / path for base in self._bases() if (base / path).is_dir()), Path.cwd() / path)

    def _bases(self) -> list[Path]:
        """Where a relative path is looked for, in order: the current directory (KF-GINS), the YAML's folder and the
        folder above it."""
        return [Path.cwd(), self.path.parent, self.path.parent.parent]


def load_config(yaml_path, defer_truth: bool = False, stream_imu: bool = False) -> Dataset:
    """KF-GINS YAML configuration -> Dataset, everything converted once to SI. defer_truth: leave the truth file
    (as large as the IMU file) unread, described in notes["truth_file"], for load_deferred_truth after the run.
    stream_imu: an IMU file longer than IMU_HEAD_BYTES comes as a StreamedImu (zennav replay: the run starts on its
    head; the rest, its defects and remarks when it is first used; the GNSS epochs after its last sample left out
    then).

    KF-GINS units: initpos [deg, deg, m], initatt/initattstd [deg], initgyrbias/initbgstd/gbstd [deg/h],
    initaccbias/initbastd/abstd [mGal], initgyrscale/initaccscale/initsgstd/initsastd/gsstd/asstd [ppm], arw
    [deg/sqrt(h)], vrw [m/s/sqrt(h)], corrtime [h] (of the biases and the scale factors), antlever [m, FRD].
    Nonzero scale-factor uncertainties make the filter estimate them (21 states, as KF-GINS; NavConfig.scale_factors
    turns that off); absent or zero ones leave it at 15 states. zennav extensions: gnssvelpath,
    truthpath (.nav), truthinfo {fields, source, at_antenna}, imunoise.acccorrtime [h].
    The time window keeps IMU samples in [starttime, endtime] and GNSS epochs in (starttime, endtime], as KF-GINS;
    the initial state is at the first IMU sample of the window; config.end_t_ns is endtime (None for -1: to the last
    sample).
    """
    yaml_path = Path(yaml_path)
    cfg = _Config(yaml_path)
    # The whole configuration is checked before any data file is read.
    columns = cfg.number("imudatalen")
    if columns < 7 or columns != int(columns):
        raise cfg.error(("imudatalen",), f"expected an integer >= 7, got {cfg.get('imudatalen')!r}")
    rate_hz = cfg.number("imudatarate")
    if rate_hz <= 0:
        raise cfg.error(("imudatarate",), "must be positive")
    start_ns = int(_t_ns(cfg.number("starttime")))
    endtime = cfg.number("endtime")
    tau_g = cfg.number("imunoise", "corrtime") * 3600.0
    acc_tau_h = cfg.number("imunoise", "acccorrtime", required=False)
    noise = ImuNoise(
        arw=cfg.per_sensor("imunoise", "arw") * D2R / SQRT_H,
        vrw=cfg.per_sensor("imunoise", "vrw") / SQRT_H,
        gyro_bias_std=cfg.per_sensor("imunoise", "gbstd") * DEG_PER_H,
        accel_bias_std=cfg.per_sensor("imunoise", "abstd") * MGAL,
        gyro_bias_tau=tau_g,
        accel_bias_tau=tau_g if acc_tau_h is None else acc_tau_h * 3600.0,
        gyro_scale_std=_optional_per_sensor(cfg, "gsstd") * PPM,
        accel_scale_std=_optional_per_sensor(cfg, "asstd") * PPM,
        gyro_scale_tau=tau_g,
        accel_scale_tau=tau_g if acc_tau_h is None else acc_tau_h * 3600.0,
    )
    if tau_g <= 0 or noise.accel_bias_tau <= 0:
        raise cfg.error(("imunoise", "corrtime"), "correlation time must be positive")
    bg_std = cfg.vector("initbgstd", required=False, positive=True)
    ba_std = cfg.vector("initbastd", required=False, positive=True)
    # KF-GINS: without initbgstd/initbastd the initial bias std is the bias instability (gbstd/abstd), per axis.
    bg_std = cfg.vector("imunoise", "gbstd") if bg_std is None else bg_std
    ba_std = cfg.vector("imunoise", "abstd") if ba_std is None else ba_std
    sg_std = cfg.vector("initsgstd", required=False)
    sa_std = cfg.vector("initsastd", required=False)
    for key, v in (("initsgstd", sg_std), ("initsastd", sa_std)):
        if v is not None and (v < 0).any():
            raise cfg.error((key,), f"must not be negative, got {v.tolist()}")
    pos = cfg.vector("initpos")
    initial_at = partial(  # the initial state, at the first IMU sample of the window
        InitialState,
        llh=np.array([pos[0] * D2R, pos[1] * D2R, pos[2]]),
        v_n=cfg.vector("initvel"),
        euler=cfg.vector("initatt") * D2R,
        std_pos_ned=cfg.vector("initposstd", positive=True),
        std_v_n=cfg.vector("initvelstd", positive=True),
        std_euler=cfg.vector("initattstd", positive=True) * D2R,
        gyro_bias=cfg.vector("initgyrbias") * DEG_PER_H,
        accel_bias=cfg.vector("initaccbias") * MGAL,
        std_gyro_bias=bg_std * DEG_PER_H,
        std_accel_bias=ba_std * MGAL,
        gyro_scale=_optional_vector(cfg, "initgyrscale") * PPM,
        accel_scale=_optional_vector(cfg, "initaccscale") * PPM,
        std_gyro_scale=None if sg_std is None else sg_std * PPM,
        std_accel_scale=None if sa_std is None else sa_std * PPM,
    )
    lever_arm_b = cfg.vector("antlever")
    info = cfg.get("truthinfo", required=False) or {}
    fields = info.get("fields", list(TRUTH_FIELDS)) if isinstance(info, dict) else None
    if not isinstance(fields, list) or "pos" not in fields or not set(fields) <= set(TRUTH_FIELDS):
        raise cfg.error(("truthinfo",), f"expected {{fields: list of {TRUTH_FIELDS} with 'pos', source, at_antenna}}")
    imu_path, gnss_path = cfg.file("imupath"), cfg.file("gnsspath")
    vel_path, truth_path = cfg.file("gnssvelpath", required=False), cfg.file("truthpath", required=False)

    raw = load_imu(imu_path, int(columns), remarks=cfg.notes, head_bytes=IMU_HEAD_BYTES if stream_imu else 0)
    gnss = load_gnss(gnss_path, vel_path, remarks=cfg.notes)
    end_ns = None if endtime < 0 else int(_t_ns(endtime))

    def trim_gnss(imu_whole: ImuData) -> None:  # endtime -1: the GNSS epochs up to the last IMU sample
        ds.gnss = ds.gnss.slice(ds.gnss.t_ns <= imu_whole.t_ns[-1])

    def read_rest(raw: StreamedImu) -> ImuData:  # the whole IMU file's samples in the window; then a deferred truth
        whole = _in_window(cfg, raw.whole(), start_ns, end_ns)
        if "truth_file" in ds.notes:  # read beside the run too (it is as large as the IMU file)
            ds.notes["truth_file"]["reading"] = in_background(partial(_load_truth_file, dict(truth_file)))
        return whole

    imu: ImuData
    if isinstance(raw, StreamedImu) and np.count_nonzero(_window_keep(raw.head.t_ns, start_ns, end_ns)) >= 2:
        head = _in_window(cfg, raw.head, start_ns, end_ns)
        span_s = raw.span_s - (int(head.t_ns[0]) - int(raw.head.t_ns[0])) / NS
        imu = StreamedImu(head, partial(read_rest, raw), raw.source, trim_gnss if end_ns is None else None,
                          span_s if end_ns is None else min(span_s, (end_ns - int(head.t_ns[0])) / NS))
        first_ns = int(imu.head.t_ns[0])
    else:  # the whole now
        imu = _in_window(cfg, raw, start_ns, end_ns)
        first_ns = int(imu.t_ns[0])
    gnss_keep = gnss.t_ns > start_ns
    if end_ns is not None or not isinstance(imu, StreamedImu):  # else trim_gnss, once the last IMU time is known
        gnss_keep &= gnss.t_ns <= (imu.t_ns[-1] if end_ns is None else end_ns)
    gnss = gnss.slice(gnss_keep)
    initial = initial_at(t_ns=first_ns)
    config = NavConfig(imu_noise=noise, lever_arm_b=lever_arm_b, start_t_ns=initial.t_ns, end_t_ns=end_ns)
    truth = None
    truth_file = {"path": str(truth_path), "source": str(info.get("source", "")), "fields": list(fields),
                  "at_antenna": bool(info.get("at_antenna", False))}
    if truth_path is not None and not defer_truth:
        truth = _load_truth_file(truth_file)
    notes: dict = {
        "format": "KF-GINS",
        "config": str(yaml_path),
        "time": "GPS seconds of week",
        "imu_rate_hz": rate_hz,
        "outputpath": str(cfg.folder("outputpath")),
        "gnss_fix": "the KF-GINS GNSS format has no fix type: every epoch is FixType.SINGLE, num_sats -1",
        "remarks": cfg.notes,
    }
    if truth_path is not None and defer_truth:
        notes["truth_file"] = truth_file
    ds = Dataset(yaml_path.stem, imu, gnss, config, initial, truth, notes)
    return ds


def _window_keep(t_ns: np.ndarray, start_ns: int, end_ns: int | None) -> np.ndarray:
    """Which of the IMU times t_ns [ns] are in [start_ns, end_ns] (end None: to the last)."""
    keep = t_ns >= start_ns
    return keep if end_ns is None else keep & (t_ns <= end_ns)


def _in_window(cfg: _Config, imu: ImuData, start_ns: int, end_ns: int | None) -> ImuData:
    """The IMU samples in the configuration's time window [start_ns, end_ns] (end None: to the last); a DataError for
    a start before the first sample or fewer than two samples in it."""
    if start_ns < imu.t_ns[0]:
        raise cfg.error(("starttime",), f"{start_ns / NS:.9f} s is before the first IMU time {imu.t_ns[0] / NS:.9f} s")
    keep = _window_keep(imu.t_ns, start_ns, end_ns)
    if keep.sum() < 2:
        raise cfg.error(("starttime",), "fewer than two IMU samples between starttime and endtime")
    return imu.slice(keep)


def load_deferred_truth(ds: Dataset) -> None:
    """Read the truth file that load_config(defer_truth=True) left unread into ds.truth (nothing to do otherwise); with
    a streamed IMU file it has been reading in the background since the IMU file was read: its result then."""
    truth_file = ds.notes.pop("truth_file", None)
    if truth_file is not None:
        reading = truth_file.pop("reading", None)
        ds.truth = _load_truth_file(truth_file) if reading is None else reading.result()


def _load_truth_file(truth_file: dict) -> Truth:
    """load_nav of a configuration's truth file described as {path, source, fields, at_antenna}."""
    return load_nav(truth_file["path"], truth_file["source"], truth_file["fields"], truth_file["at_antenna"])


def _optional_vector(cfg: _Config, key: str) -> np.ndarray:
    """A 3-vector that KF-GINS configurations may leave out (zeros then)."""
    v = cfg.vector(key, required=False)
    return np.zeros(3) if v is None else v


def _optional_per_sensor(cfg: _Config, key: str) -> float:
    """An imunoise scale-factor value that may be left out (0: no scale-factor states)."""
    return 0.0 if cfg.get("imunoise", key, required=False) is None else cfg.per_sensor("imunoise", key)
