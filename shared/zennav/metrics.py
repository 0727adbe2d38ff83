"""Accuracy of a replay against the dataset's truth (and of the 21-state filter's scale factors against a
simulation's), and the reports written by `zennav replay --out`.

Errors are computed only at truth epochs inside the solution's time span. Position errors are NED
metres of the same physical point as the truth (the IMU, or the GNSS antenna when the truth is the
RTK antenna position, in which case the solution is moved by the lever arm with its own attitude).
"""
from __future__ import annotations

import json
import math
from functools import partial
from pathlib import Path

import numpy as np

from .nav import earth
from .nav.navigator import Navigator
from .nav.rotation import quat_to_dcm, wrap_angle
from .nav.types import NS, Dataset
from .replay import ReplayResult


def antenna_llh(llh: np.ndarray, q_nb: np.ndarray, lever_arm_b) -> np.ndarray:
    """Move IMU positions (N, 3) to the antenna at lever_arm_b [m, FRD] using the attitude q_nb (N, 4)."""
    lever_n = quat_to_dcm(q_nb) @ np.asarray(lever_arm_b, dtype=float)
    return llh + np.stack(earth.ned_to_dllh(lever_n.T, llh[:, 0], llh[:, 2]), -1)


def ned_errors(llh_est: np.ndarray, llh_ref: np.ndarray) -> np.ndarray:
    """NED error [m] of estimated minus reference positions (N, 3), small-offset approximation."""
    return np.stack(earth.dllh_to_ned((llh_est - llh_ref).T, llh_ref[:, 0], llh_ref[:, 2]), -1)


def _interp(t_query: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    tq = (t_query - t[0]).astype(np.float64)
    tt = (t - t[0]).astype(np.float64)
    return np.stack([np.interp(tq, tt, y[:, i]) for i in range(y.shape[1])], -1)


def _rms(x) -> float | None:
    x = np.asarray(x, dtype=float)
    return float(math.sqrt(np.mean(x * x))) if x.size else None


def evaluate(ds: Dataset, res: ReplayResult) -> dict:
    """metrics.json content: whole-run RMS errors, per-outage horizontal drift and, for a vehicle with a DVL or a
    depth sensor, each stretch under water with its drift (dives; see module docstring)."""
    duration = (res.t_ns[-1] - res.t_ns[0]) / NS if len(res.t_ns) > 1 else 0.0
    m: dict = {
        "dataset": ds.name,
        "duration_s": duration,
        "imu_rate_hz": (len(res.t_ns) - 1) / duration if duration > 0 else None,
        "wall_s": res.wall_s,
        "realtime_factor": duration / res.wall_s if res.wall_s > 0 else None,
        "epochs_per_s": len(res.t_ns) / res.wall_s if res.wall_s > 0 else None,
        "truth_source": ds.truth.source if ds.truth is not None else None,
        "horizontal_rms_m": None,
        "vertical_rms_m": None,
        "velocity_rms_mps": None,
        "attitude_rms_deg": None,
        "outages": [],
        "outage_max_horizontal_rms_m": None,
        "outage_max_horizontal_max_m": None,
        "engine": res.status,
    }
    truth = ds.truth
    if truth is None or len(res.t_ns) < 2:
        return m
    sel = (truth.t_ns >= res.t_ns[0]) & (truth.t_ns <= res.t_ns[-1])
    t_ref = truth.t_ns[sel]
    llh_sol = res.llh
    if truth.at_antenna:
        llh_sol = antenna_llh(res.llh, res.q_nb, ds.config.lever_arm_b)
    est = _interp(t_ref, res.t_ns, llh_sol)
    err = ned_errors(est, truth.llh[sel])
    horiz = np.hypot(err[:, 0], err[:, 1])
    m["horizontal_rms_m"] = _rms(horiz)
    m["vertical_rms_m"] = _rms(err[:, 2])
    if truth.v_n is not None:
        v_est = _interp(t_ref, res.t_ns, res.v_n)
        m["velocity_rms_mps"] = _rms(np.linalg.norm(v_est - truth.v_n[sel], axis=1))
    if truth.euler is not None:
        e_est = res.euler
        idx = np.clip(np.searchsorted(res.t_ns, t_ref), 0, len(res.t_ns) - 1)
        d = wrap_angle(e_est[idx] - truth.euler[sel])
        rms_rad = {k: _rms(d[:, i]) for i, k in enumerate(("roll", "pitch", "yaw"))}  # None: no truth in the run
        m["attitude_rms_deg"] = {k: None if r is None else math.degrees(r) for k, r in rms_rad.items()}
    for a, b in res.windows:
        inside = (t_ref >= a) & (t_ref < b)
        if not inside.any():
            continue
        h = horiz[inside]
        m["outages"].append(
            {
                "start_s": (a - ds.initial.t_ns) / NS,
                "duration_s": (b - a) / NS,
                "max_horizontal_m": float(h.max()),
                "final_horizontal_m": float(h[-1]),
            }
        )
    if m["outages"]:
        peaks = [o["max_horizontal_m"] for o in m["outages"]]
        m["outage_max_horizontal_rms_m"] = _rms(peaks)
        m["outage_max_horizontal_max_m"] = float(max(peaks))
    if ds.dvl is not None or ds.depth is not None:
        m["dives"] = dives(ds, res)
    return m


def format_table(m: dict) -> str:
    """Human-readable accuracy table of a metrics dict."""

    def f(x, unit=""):
        return "n/a" if x is None else f"{x:.3f}{unit}"

    rows = [
        ("dataset", m["dataset"]),
        ("duration", f(m["duration_s"], " s")),
        ("IMU rate", f(m["imu_rate_hz"], " Hz")),
        ("real-time factor", f(m["realtime_factor"], "x")),
        ("truth", m.get("truth_source") or "none"),
        ("horizontal RMS", f(m["horizontal_rms_m"], " m")),
        ("vertical RMS", f(m["vertical_rms_m"], " m")),
        ("velocity RMS", f(m["velocity_rms_mps"], " m/s")),
    ]
    att = m["attitude_rms_deg"]
    rows.append(("attitude RMS r/p/y", "n/a" if att is None else "/".join(f"{att[k]:.3f}" for k in att) + " deg"))
    for o in m["outages"]:
        rows.append(
            (f"outage {o['start_s']:.0f}s+{o['duration_s']:.0f}s",
             f"max {o['max_horizontal_m']:.2f} m, final {o['final_horizontal_m']:.2f} m")
        )
    if m["outages"]:
        rows.append(("outage max drift RMS", f(m["outage_max_horizontal_rms_m"], " m")))
        rows.append(("outage max drift max", f(m["outage_max_horizontal_max_m"], " m")))
    for d in m.get("dives", []):
        rows.append((f"under water {d['start_s']:.0f}s..{d['end_s']:.0f}s",
                     f"{dive_text(d)} of {d['distance_m']:.0f} m"))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def write_outputs(out_dir: Path, ds: Dataset, res: ReplayResult, metrics: dict) -> None:
    """nav.txt (KF-GINS .nav format), nav.csv and metrics.json in out_dir."""
    write_solution(out_dir, res)
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))


def write_solution(out_dir: Path, res: ReplayResult) -> None:
    """A replay's rows as nav.txt (KF-GINS .nav format) and nav.csv in out_dir (nav.txt in the I/O thread, beside
    nav.csv: numpy formats them without the GIL)."""
    from .datasets import kfgins
    from .datasets.fasttext import in_background, write_table

    out_dir.mkdir(parents=True, exist_ok=True)
    euler = res.euler
    week = int(res.t_ns[0] // kfgins.WEEK_NS)  # 0 for data timed in seconds of week
    nav_txt = in_background(partial(kfgins.write_nav, out_dir / "nav.txt", week, res.t_ns, res.llh, res.v_n, euler))
    header = "t_s,lat_deg,lon_deg,h_m,vn_mps,ve_mps,vd_mps,roll_deg,pitch_deg,yaw_deg,std_n_m,std_e_m,std_d_m,outage\n"
    cols = [res.t_ns / NS, np.degrees(res.llh[:, 0]), np.degrees(res.llh[:, 1]), res.llh[:, 2], *res.v_n.T,
            *np.degrees(euler).T, *res.std_pos_ned.T, res.outage.astype(float)]
    fmts = ["%.9f", "%.10f", "%.10f", "%.4f"] + ["%.5f"] * 3 + ["%.5f"] * 3 + ["%.4f"] * 3 + ["%.0f"]
    write_table(out_dir / "nav.csv", cols, fmts, ",", header=header)  # beside nav.txt
    nav_txt.result()


def dive_text(d: dict) -> str:
    """A dive of metrics.json's "dives" (see dives) in words: its end and largest horizontal error and its drift."""
    pct = "n/a" if d["drift_pct"] is None else f"{d['drift_pct']:.3f} %"
    return f"end {d['end_horizontal_m']:.2f} m, max {d['max_horizontal_m']:.2f} m, drift {pct}"


def drift(ref_llh: np.ndarray, end_error_m: float) -> tuple[float, float | None]:
    """Drift of a stretch: the horizontal distance travelled along its reference rows ref_llh (N, 3) [rad, rad, m]
    [m], and end_error_m (the horizontal error at its last row [m]) as a percentage of it (None for no distance),
    the figure dead reckoning (INS/DVL, odometry) is quoted in."""
    step = ned_errors(ref_llh[1:], ref_llh[:-1])
    dist = float(np.hypot(step[:, 0], step[:, 1]).sum())
    return dist, (100.0 * float(end_error_m) / dist if dist > 0 else None)


UNDERWATER_DEPTH_M = 0.5  # [m] the truth deeper than this below the water surface is under water (no GNSS)


def dives(ds: Dataset, res: ReplayResult, min_depth_m: float = UNDERWATER_DEPTH_M) -> list[dict]:
    """Each stretch of the truth under water (depth = config.depth_surface_h_m - truth height > min_depth_m [m])
    inside the solution's span, from the dataset's last GNSS fix in it where it has one (A-KIT's derived fixes of
    the first gnss_s seconds: the drift counts from the last fix, as benchmarks/akit_dvl.py); stretches with no
    GNSS fix between them are one (a vehicle bobbing at the threshold without a fix still dead-reckons): its start
    and end [s from the initial time], the horizontal distance travelled [m] (the truth's path), the horizontal error at
    its end and the largest within it [m], and the drift at its end as a percentage of that distance (the figure
    INS/DVL navigation is quoted in)."""
    truth = ds.truth
    if truth is None or len(res.t_ns) < 2:
        return []
    sel = np.flatnonzero((truth.t_ns >= res.t_ns[0]) & (truth.t_ns <= res.t_ns[-1]))
    deep = ds.config.depth_surface_h_m - truth.llh[sel, 2] > min_depth_m
    edges = np.flatnonzero(np.diff(np.concatenate([[0], deep.astype(np.int8), [0]])))
    stretches: list[list[int]] = []
    for a, b in zip(edges[0::2].tolist(), edges[1::2].tolist()):
        if stretches and not np.any((ds.gnss.t_ns > truth.t_ns[sel[stretches[-1][1] - 1]])
                                    & (ds.gnss.t_ns < truth.t_ns[sel[a]])):
            stretches[-1][1] = b  # no fix at the surface in between: the same stretch
        else:
            stretches.append([a, b])
    t0 = int(ds.initial.t_ns)
    out = []
    for a, b in stretches:
        idx = sel[a:b]
        fixes = ds.gnss.t_ns[(ds.gnss.t_ns >= truth.t_ns[idx[0]]) & (ds.gnss.t_ns <= truth.t_ns[idx[-1]])]
        if fixes.size:
            idx = idx[truth.t_ns[idx] >= fixes[-1]]
        if len(idx) < 2:
            continue
        ref = truth.llh[idx]
        e = ned_errors(_interp(truth.t_ns[idx], res.t_ns, res.llh), ref)
        err = np.hypot(e[:, 0], e[:, 1])
        dist, pct = drift(ref, float(err[-1]))
        out.append({"start_s": (int(truth.t_ns[idx[0]]) - t0) / NS, "end_s": (int(truth.t_ns[idx[-1]]) - t0) / NS,
                    "distance_m": dist, "end_horizontal_m": float(err[-1]), "max_horizontal_m": float(err.max()),
                    "drift_pct": pct})
    return out


class ScaleFactorErrors:
    """A replay's on_epoch recorder (run_replay(on_epoch=...)) of the 21-state filter's IMU scale factors against a
    simulated dataset's (zennav.sim.scenarios: notes["gyro_scale"], notes["accel_scale"], (N, 3) at the IMU samples):
    every every_s [s] of the run, per state (gyro x, y, z, accelerometer x, y, z) a row of error / sigma in ``z``,
    sigma / prior sigma in ``ratio`` and truth / prior sigma in ``draw`` (prior: the ImuNoise 1-sigma)."""

    def __init__(self, ds: Dataset, every_s: float = 30.0):
        self.t_ns = ds.imu.t_ns
        self.truth = np.hstack([ds.notes["gyro_scale"], ds.notes["accel_scale"]])
        noise = ds.config.imu_noise
        self.prior = np.repeat([noise.gyro_scale_std, noise.accel_scale_std], 3)
        self.every_ns = int(round(every_s * NS))
        self.z: list[np.ndarray] = []
        self.ratio: list[np.ndarray] = []
        self.draw: list[np.ndarray] = []

    def __call__(self, nav: Navigator) -> None:
        t0_ns = int(self.t_ns[0])
        if nav.t_ns <= t0_ns or (nav.t_ns - t0_ns) % self.every_ns:
            return
        sl = slice(nav.aug_blocks["gyro_scale"].start, nav.aug_blocks["accel_scale"].stop)
        truth = self.truth[int(np.searchsorted(self.t_ns, nav.t_ns))]
        sd = np.sqrt(np.diag(nav.P)[sl])
        self.z.append((nav.aug_value(sl) - truth) / sd)
        self.ratio.append(sd / self.prior)
        self.draw.append(truth / self.prior)
