"""What a replay writes beside nav.txt, nav.csv and metrics.json for `zennav report` and Foxglove, collected
while it runs (``RunRecorder.on_epoch``, zennav.replay.run_replay's hook, which never changes the engine):

- ``aid.csv``: every aiding attempt (time from the run start [s], source, fused, reason, test ratio, observation
  and innovation components);
- ``run.json``: the dataset spec the run loaded and its loader options (``zennav report`` loads the truth again
  from it);
- ``biases.csv``: once per second of data, the estimated gyro [deg/h] and accelerometer [mg] biases (body FRD)
  with their 1-sigma from the filter covariance;
- ``--mcap FILE``: every solution (nav_solution), GNSS fix, DVL and depth sample fed (gnss, dvl, depth) and aid
  report (aid_report) as zennav messages with their Foxglove views (zennav.recording.McapRecorder), log time =
  sample time.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from . import messages as M
from .nav.eskf import BA, BG
from .nav.types import NS

DEG_PER_H = math.degrees(1.0) * 3600.0  # [deg/h] per [rad/s]
MG = 1000.0 / 9.80665  # [mg] per [m/s^2]


class RunRecorder:
    """Collects biases each second of data and, with an MCAP path, the solutions; write() after the run."""

    def __init__(self, t0_ns: int, mcap: Path | None = None, vehicle: str = "replay"):
        self.t0_ns = t0_ns
        self.keys = M.Keys(vehicle)
        self.next_bias_ns = t0_ns
        self.biases: list[list[float]] = []
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
            self.biases.append([(t - self.t0_ns) / NS, *(np.asarray(nav.gyro_bias) * DEG_PER_H),
                                *(std[BG] * DEG_PER_H), *(np.asarray(nav.accel_bias) * MG), *(std[BA] * MG)])
        if self.rec is not None:
            self._add(self.keys.nav_solution(), M.nav_solution_msg_of(nav))

    def _add(self, key: str, msg: dict) -> None:
        msg.update(src="replay", seq=self._seq, pub_ns=0)
        self._seq += 1
        assert self.rec is not None
        self.rec.add_message(key, msg)

    def finish(self, ds, events: list, reports: list) -> None:
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
        np.savetxt(out / "biases.csv", np.array(self.biases).reshape(-1, 13), delimiter=",", header=header,
                   comments="", fmt="%.6g")
