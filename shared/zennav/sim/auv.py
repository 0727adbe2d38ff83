"""Simulated AUV (``zennav replay sim:auv``): a mission that starts at the surface with GNSS and then dives, with a
Janus DVL and a pressure depth sensor, exact truth, seeded.

Everything the DVL and the depth sensor inject is a loader option (``-o key=value``) and is written to the dataset's
notes (``notes["injected"]``, human units): beam biases, scale factor, white noise, dropouts, outliers, bottom loss,
noise bursts and a bias jump. The last three are zennav.datasets.dvl_anomalies events at the given times (the one
injector of DVL anomalies; ``notes["dvl_anomalies"]``): bottom loss "lostall", a noise burst "noise" on all four beams
(added noise of dvl_noise_mps sqrt(dvl_burst_factor^2 - 1): the beam noise times dvl_burst_factor in all), the bias
jump "bias" from its start to the end. GNSS fixes exist only while the IMU is at most gnss_max_depth_m below the
surface (the antenna above the water). The DVL sees the bottom throughout except in the bottom-loss windows (a flat sea
floor within range). Frames and units as zennav.sim.sensors.
"""
from __future__ import annotations

import math

import numpy as np

from ..datasets import dvl_anomalies
from ..nav.beams import janus_directions
from ..nav.rotation import euler_to_dcm
from ..nav.types import NS, Dataset, DvlData
from .scenarios import _gnss_times, make_dataset
from .sensors import DvlErrors, simulate_depth, simulate_dvl

DVL_LEVER_B = (0.8, 0.0, 0.3)  # IMU -> DVL, body FRD [m]
DVL_MOUNT_EULER = (0.0, 0.0, 0.0)  # roll, pitch, yaw of the DVL frame in the body frame [rad]


def parse_windows(text: str) -> tuple[tuple[float, float], ...]:
    """'START:DURATION[,START:DURATION...]' [s] -> ((start_s, end_s), ...); '' -> (); ValueError when malformed."""
    out = []
    for part in filter(None, str(text).split(",")):
        try:
            start, dur = (float(x) for x in part.split(":"))
        except ValueError:
            raise ValueError(f"expected START:DURATION[,START:DURATION] in seconds, got {text!r}") from None
        if not (start >= 0 and dur > 0 and math.isfinite(start + dur)):
            raise ValueError(f"START must be >= 0 and DURATION > 0, got {text!r}")
        out.append((start, start + dur))
    return tuple(out)


def parse_angles(text) -> np.ndarray:
    """'ROLL,PITCH,YAW' [deg] (or three numbers) -> (3,) [rad]; ValueError when malformed."""
    try:
        out = np.radians([float(x) for x in (str(text).split(",") if isinstance(text, str) else text)])
    except (TypeError, ValueError):
        raise ValueError(f"expected ROLL,PITCH,YAW in degrees, got {text!r}") from None
    if out.shape != (3,) or not np.all(np.isfinite(out)):
        raise ValueError(f"expected three finite angles ROLL,PITCH,YAW in degrees, got {text!r}")
    return out


def parse_bias_jump(text: str) -> tuple[float, int, float] | None:
    """'START:BEAM:SIZE' (s, beam 1..4, m/s) -> (start_s, beam index 0..3, size_mps); '' -> None."""
    if not text:
        return None
    try:
        start, beam, size = str(text).split(":")
        out = (float(start), int(beam) - 1, float(size))
    except ValueError:
        raise ValueError(f"expected START:BEAM:SIZE (s, 1..4, m/s), got {text!r}") from None
    if not (out[0] >= 0 and 0 <= out[1] <= 3 and math.isfinite(out[2])):
        raise ValueError(f"expected START >= 0, BEAM 1..4 and a finite SIZE, got {text!r}")
    return out


def make_auv_dataset(duration_s: float = 900.0, seed: int = 0, imu_grade: str = "tactical",
                     imu_rate_hz: float = 100.0, surface_s: float = 120.0, max_depth_m: float = 50.0,
                     gnss_max_depth_m: float = 0.2, dvl_rate_hz: float = 5.0, dvl_noise_mps: float = 0.02,
                     dvl_bias_mps: float = 0.01, dvl_scale_error: float = 0.004, dvl_dropout: float = 0.01,
                     dvl_outlier_prob: float = 0.002, dvl_outlier_mps: float = 0.5, dvl_bottom_loss: str = "600:20",
                     dvl_burst: str = "", dvl_burst_factor: float = 10.0, dvl_bias_jump: str = "",
                     dvl_tilt_deg: float = 30.0, dvl_layout: str = "x", dvl_misalignment_deg: str = "0,0,0",
                     depth_rate_hz: float = 5.0,
                     depth_bias_m: float = 0.2, depth_noise_m: float = 0.02, **kw) -> Dataset:
    """The simulated AUV (module docstring). duration_s [s], seed (everything random), imu_grade / imu_rate_hz [Hz]
    (zennav.sim.scenarios IMU_GRADES: navigation, tactical, ...); surface_s [s] at the surface before the dive,
    max_depth_m [m] (zennav.sim.trajectory.auv_trajectory); DVL at dvl_rate_hz [Hz]: per-beam white noise
    dvl_noise_mps, constant beam biases drawn with 1-sigma dvl_bias_mps, scale-factor error dvl_scale_error [ratio],
    per-beam dropout probability dvl_dropout, outliers with probability dvl_outlier_prob of 1-2 x dvl_outlier_mps,
    bottom-loss windows dvl_bottom_loss and noise bursts dvl_burst ('START:DURATION[,...]' s from the start, noise
    x dvl_burst_factor), a bias jump dvl_bias_jump ('START:BEAM:SIZE', s, 1..4, m/s); beam tilt dvl_tilt_deg [deg]
    and layout ("+" / "x"); a mounting misalignment dvl_misalignment_deg ('ROLL,PITCH,YAW' [deg]: the DVL's true
    frame rotated by these Euler angles from the mounting the filter is told, DVL_MOUNT_EULER); depth at
    depth_rate_hz [Hz] with bias depth_bias_m and noise depth_noise_m [m].
    kw go to zennav.sim.scenarios.make_dataset (gnss_rate_hz, gnss_std_ned, start_llh_deg: its height is the water
    surface, ...)."""
    kw.setdefault("start_llh_deg", (30.53, 114.36, 0.0))
    ds = make_dataset("auv", duration_s, imu_rate_hz, seed=seed, imu_grade=imu_grade, surface_s=surface_s,
                      max_depth_m=max_depth_m, **kw)
    traj = ds.notes["trajectory"]
    t0_ns = int(ds.imu.t_ns[0])
    t_end_ns = int(ds.imu.t_ns[-1])
    h_surface = float(kw["start_llh_deg"][2])
    at_surface = h_surface - traj.llh((ds.gnss.t_ns - t0_ns) / NS)[:, 2] <= gnss_max_depth_m
    ds.gnss = ds.gnss.slice(at_surface)

    ss_dvl, ss_depth, ss_bias, ss_events = np.random.SeedSequence([seed, 3]).spawn(4)
    errors = DvlErrors(
        bias_mps=dvl_bias_mps * np.random.default_rng(ss_bias).standard_normal(4), scale_error=dvl_scale_error,
        noise_mps=dvl_noise_mps, dropout_prob=dvl_dropout, outlier_prob=dvl_outlier_prob, outlier_mps=dvl_outlier_mps)
    bottom_loss, bursts, jump = parse_windows(dvl_bottom_loss), parse_windows(dvl_burst), parse_bias_jump(dvl_bias_jump)
    if not dvl_burst_factor >= 1.0:
        raise ValueError(f"dvl_burst_factor must be >= 1 (the noise of a burst over the DVL's), got {dvl_burst_factor}")
    tilt = math.radians(dvl_tilt_deg)
    B = janus_directions(tilt, dvl_layout)
    misalignment = parse_angles(dvl_misalignment_deg)
    C_db = euler_to_dcm(misalignment).T @ euler_to_dcm(np.asarray(DVL_MOUNT_EULER, dtype=float)).T
    dvl, true_beams = simulate_dvl(traj, _gnss_times(t0_ns, t_end_ns, dvl_rate_hz), t0_ns, B, C_db,
                                   DVL_LEVER_B, errors, np.random.default_rng(ss_dvl))
    t_s = (dvl.t_ns - t0_ns) / NS
    timed = ([_event("noise", (0, 1, 2, 3), dvl.t_ns, (t_s >= a) & (t_s < b),
                     dvl_noise_mps * math.sqrt(dvl_burst_factor**2 - 1.0)) for a, b in bursts]
             + ([] if jump is None else [_event("bias", (jump[1],), dvl.t_ns, t_s >= jump[0], jump[2])])
             + [_event("lostall", (0, 1, 2, 3), dvl.t_ns, (t_s >= a) & (t_s < b), 0.0) for a, b in bottom_loss])
    events = [e for e in timed if e is not None]
    dvl = dvl_anomalies.apply_events(dvl, events, B, np.random.default_rng(ss_events))
    assert dvl.beams is not None and dvl.beam_valid is not None
    ds.dvl = DvlData(dvl.t_ns, np.where(dvl.beam_valid, dvl.beams, np.nan), dvl.beam_valid)
    ds.depth = simulate_depth(traj, _gnss_times(t0_ns, t_end_ns, depth_rate_hz), t0_ns, h_surface, depth_bias_m,
                              depth_noise_m, np.random.default_rng(ss_depth))
    ds.config = ds.config.with_(has_dvl=True, has_depth=True, dvl_tilt=tilt, dvl_layout=dvl_layout,
                                dvl_mount_euler=DVL_MOUNT_EULER, dvl_lever_b=DVL_LEVER_B, depth_surface_h_m=h_surface)
    ds.name = f"sim-auv-{imu_grade}-seed{seed}"
    ds.notes.update(
        dvl_true_beams=true_beams,  # exact beam velocities (N, 4) [m/s] at ds.dvl.t_ns
        dvl_anomalies=[e.as_dict() for e in events],
        injected={
            "gnss": f"fixes only while the IMU is at most {gnss_max_depth_m} m deep ({int(at_surface.sum())} fixes)",
            "dvl_rate_hz": dvl_rate_hz, "dvl_bias_mps": errors.bias_mps.tolist(), "dvl_scale_error": dvl_scale_error,
            "dvl_noise_mps": dvl_noise_mps, "dvl_dropout": dvl_dropout, "dvl_outlier_prob": dvl_outlier_prob,
            "dvl_outlier_mps": dvl_outlier_mps, "dvl_bottom_loss_s": [list(w) for w in bottom_loss],
            "dvl_burst_s": [list(w) for w in bursts], "dvl_burst_factor": dvl_burst_factor,
            "dvl_bias_jump": dvl_bias_jump or None, "dvl_tilt_deg": dvl_tilt_deg, "dvl_layout": dvl_layout,
            "dvl_misalignment_deg": np.degrees(misalignment).tolist(),
            "dvl_lever_b_m": list(DVL_LEVER_B), "depth_rate_hz": depth_rate_hz, "depth_bias_m": depth_bias_m,
            "depth_noise_m": depth_noise_m, "surface_s": surface_s, "max_depth_m": max_depth_m,
        })
    return ds


def _event(kind: str, beams: tuple, t_ns: np.ndarray, rows: np.ndarray,
           magnitude_mps: float) -> dvl_anomalies.AnomalyEvent | None:
    """The anomaly event of kind on these beams over the DVL samples where rows holds (None: no sample)."""
    k = np.flatnonzero(rows)
    if not len(k):
        return None
    return dvl_anomalies.AnomalyEvent(kind, beams, int(t_ns[k[0]]), int(t_ns[k[-1]]), float(magnitude_mps), len(k))
