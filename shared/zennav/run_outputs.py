"""What a replay writes beside nav.txt, nav.csv and metrics.json for `zennav report` and Foxglove, collected
while it runs (``RunRecorder.on_epoch``, zennav.replay.run_replay's hook, which never changes the engine):

- ``aid.csv``: every aiding attempt (time from the run start [s], source, fused, reason, test ratio, observation
  and innovation components);
- ``run.json``: the dataset spec the run loaded and its loader options (``zennav report`` loads the truth again
  from it);
- ``biases.csv``: once per second of data, the estimated gyro [deg/h] and accelerometer [mg] biases (body FRD)
  with their 1-sigma from the filter covariance;
- for a KF-GINS configuration, KF-GINS's two other files at the same times (``write_kf_gins``), in its units and its
  text format (``%-15.9f `` per value): ``KF_GINS_IMU_ERR.txt`` (seconds of week, gyro bias [deg/h], accelerometer
  bias [mGal], gyro and accelerometer scale factors [ppm]) and ``KF_GINS_STD.txt`` (seconds of week, the 1-sigma of
  position [m, NED], velocity [m/s, NED], attitude [deg], then of the same IMU errors); the scale factors and their
  1-sigma are 0 where the filter does not estimate them (15 states);
- ``--mcap FILE``: every solution (nav_solution), GNSS fix, DVL and depth sample fed (gnss, dvl, depth) and aid
  report (aid_report) as zennav messages with their Foxglove views (zennav.recording.McapRecorder), log time =
  sample time.
"""
from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from . import messages as M
from .gpstime import WEEK_NS
from .nav.eskf import BA, BG
from .nav.types import NS

DEG_PER_H = math.degrees(1.0) * 3600.0  # [deg/h] per [rad/s]
MG = 1000.0 / 9.80665  # [mg] per [m/s^2]
MGAL = 1e5  # [mGal] per [m/s^2]
PPM = 1e6  # [ppm] per [1]
KF_GINS_IMU_ERR, KF_GINS_STD = "KF_GINS_IMU_ERR.txt", "KF_GINS_STD.txt"
# the columns of RunRecorder.states (SI): biases, scale factors, then the 1-sigma of position, velocity, attitude
# error and of the same IMU errors
S_BG, S_BA, S_SCALE = slice(0, 3), slice(3, 6), slice(6, 12)
S_STD_PV, S_STD_ATT, S_STD_BG, S_STD_BA, S_STD_SCALE = (slice(12, 18), slice(18, 21), slice(21, 24), slice(24, 27),
                                                          slice(27, 33))


class RunRecorder:
    """Collects the IMU errors and 1-sigma each second of data and, with an MCAP path, the solutions; write() (and
    write_kf_gins) after the run."""

    def __init__(self, t0_ns: int, mcap: Path | None = None, vehicle: str = "replay"):
        self.t0_ns = t0_ns
        self.keys = M.Keys(vehicle)
        self.next_bias_ns = t0_ns
        self.times: list[int] = []  # [ns] of the rows of states
        self.states: list[np.ndarray] = []  # columns S_* above
        self.rec = None
        self._seq = 0
        if mcap is not None:
            from .recording import McapRecorder

            self.rec = McapRecorder(mcap, "json")

    def due_ns(self) -> int | None:
        """The first IMU time [ns] whose epoch on_epoch must see (run_replay's epoch_due); None: every epoch (MCAP)."""
        return self.next_bias_ns if self.rec is None else None

    def on_epoch(self, nav) -> None:
        t = nav.t_ns
        if t >= self.next_bias_ns:
            self.next_bias_ns = t + NS
            std = np.sqrt(np.diag(nav.P))
            scale = [nav.aug_blocks.get(name) for name in ("gyro_scale", "accel_scale")]
            zero = np.zeros(3)
            self.times.append(t)
            self.states.append(np.concatenate(
                [nav.gyro_bias, nav.accel_bias, *(zero if sl is None else nav.aug_value(sl) for sl in scale),
                 std[:9], std[BG], std[BA], *(zero if sl is None else std[sl] for sl in scale)]))
        if self.rec is not None:
            self._add(self.keys.nav_solution(), M.nav_solution_msg_of(nav))

    def _add(self, key: str, msg: dict) -> None:
        msg.update(src="replay", seq=self._seq, pub_ns=0)
        self._seq += 1
        assert self.rec is not None
        self.rec.add_message(key, msg)

    def finish(self, ds, events: Iterable[tuple[str, int]], reports: list) -> None:
        """The GNSS fixes, DVL and depth samples fed and the aid reports into the MCAP (after the solutions), and
        close it."""
        if self.rec is None:
            return
        for cseq, (kind, k) in enumerate(events, 1):
            if kind == "gnss":
                self._add(self.keys.gnss("0"), M.gnss_msg(ds.gnss.fix_at(k), cseq))
            elif kind in M.AID_STREAMS:
                key = self.keys.dvl("0") if kind == "dvl" else self.keys.depth("0")
                self._add(key, M.aid_msg(kind, getattr(ds, kind).sample(k), cseq))
        for r in reports:
            self._add(self.keys.nav_aid(r.source), M.aid_report_msg(r))
        self.rec.close()

    def write(self, out: Path, reports: list, spec: str, options: dict | None = None) -> None:
        """aid.csv, biases.csv and run.json in out; spec and options: the dataset spec of the run and its loader
        options."""
        (out / "run.json").write_text(json.dumps({"dataset_spec": spec, "loader_options": options or {}}) + "\n")
        with open(out / "aid.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["t_s", "source", "fused", "reason", "test_ratio", "obs_0", "obs_1", "obs_2", "innov_0",
                        "innov_1", "innov_2"])
            for r in reports:
                obs = (list(r.observation) + [""] * 3)[:3]
                inn = (list(r.innovation) + [""] * 3)[:3]
                tr = float(r.test_ratio)
                w.writerow([f"{(r.t_ns - self.t0_ns) / NS:.3f}", r.source, int(bool(r.fused)), r.reason,
                            f"{tr:.4g}" if math.isfinite(tr) else "", *obs, *inn])
        header = ("t_s,bg_x_dph,bg_y_dph,bg_z_dph,bg_std_x_dph,bg_std_y_dph,bg_std_z_dph,ba_x_mg,ba_y_mg,ba_z_mg,"
                  "ba_std_x_mg,ba_std_y_mg,ba_std_z_mg")
        t_ns, x = self._table()
        t_s = (t_ns - self.t0_ns) / NS
        biases = np.column_stack([t_s, x[:, S_BG] * DEG_PER_H, x[:, S_STD_BG] * DEG_PER_H, x[:, S_BA] * MG,
                                  x[:, S_STD_BA] * MG])
        np.savetxt(out / "biases.csv", biases, delimiter=",", header=header, comments="", fmt="%.6g")

    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        """The times [ns] (N,) and the rows (N, 33: columns S_*) collected."""
        return np.array(self.times, dtype=np.int64), np.array(self.states).reshape(-1, 33)

    def write_kf_gins(self, out: Path, week: int) -> None:
        """KF_GINS_IMU_ERR.txt and KF_GINS_STD.txt in out (module docstring), times in seconds of GPS week week."""
        t_ns, x = self._table()
        sow = (t_ns - week * WEEK_NS) / NS
        err = np.column_stack([sow, x[:, S_BG] * DEG_PER_H, x[:, S_BA] * MGAL, x[:, S_SCALE] * PPM])
        std = np.column_stack([sow, x[:, S_STD_PV], np.degrees(x[:, S_STD_ATT]),
                               x[:, S_STD_BG] * DEG_PER_H, x[:, S_STD_BA] * MGAL, x[:, S_STD_SCALE] * PPM])
        for name, table in ((KF_GINS_IMU_ERR, err), (KF_GINS_STD, std)):
            # KF-GINS's FileSaver: "%-15.9lf " per value
            (out / name).write_text("".join("".join(f"{v:<15.9f} " for v in row) + "\n" for row in table.tolist()))
