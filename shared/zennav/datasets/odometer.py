"""Odometer (wheel-speed) files: KF-GINS-Matlab's ODO file (i2Nav-WHU/KF-GINS-Matlab README, "ODO file format":
column 1 GNSS time of week [s], column 2 ODO velocity [m/s], forward speed of the vehicle), read into OdometerData
with times in nanoseconds of the week as the KF-GINS loaders keep them (zennav.datasets.kfgins). comma2k19's CAN
speed is read by zennav.datasets.comma2k19."""
from __future__ import annotations

import numpy as np

from zennav.datasets.errors import read_table
from zennav.nav.types import OdometerData


def load_kfgins_odometer(path) -> OdometerData:
    """A KF-GINS-Matlab ODO file -> OdometerData (t_ns: seconds of week in ns; speed [m/s]). DataError (file:line)
    for a malformed row, a non-finite value or a time that is not after the previous one."""
    table = read_table(path, 2, commas_as_space=True)
    table.require_finite()
    t_ns = np.round(table.data[:, 0] * 1e9).astype(np.int64)
    table.require_increasing(t_ns)
    return OdometerData(t_ns, table.data[:, 1].copy())


def write_kfgins_odometer(path, odometer: OdometerData) -> None:
    """OdometerData -> a KF-GINS-Matlab ODO file (t_ns taken as seconds of week)."""
    rows = [f"{t / 1e9:.9f} {v:.6f}" for t, v in zip(odometer.t_ns.tolist(), odometer.speed_mps.tolist())]
    with open(path, "w") as f:
        f.write("\n".join(rows) + "\n")
