"""Filter consistency on simulated drives: over 10 seeded runs, the RMS of estimation error divided by
the filter's own 1-sigma lies between 0.5 and 1.5 for every state group (1.0 is a perfectly consistent
filter; below 0.5 it is over-cautious, above 1.5 over-confident)."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.nav import earth
from zennav.nav.navigator import Navigator
from zennav.nav.rotation import euler_to_dcm
from zennav.sim.scenarios import make_dataset, true_biases

GROUPS = {"position": slice(0, 3), "velocity": slice(3, 6), "attitude": slice(6, 9), "gyro bias": slice(9, 12),
          "accel bias": slice(12, 15)}


def normalized_errors(seed: int) -> np.ndarray:
    """(epochs, 15) error / sigma once per second of a 300 s, 100 Hz simulated car drive with 1 Hz GNSS."""
    ds = make_dataset("car", duration_s=300.0, imu_rate_hz=100.0, gnss_rate_hz=1.0, seed=seed)
    # The filter's GNSS model must match the simulated one: no floors on the reported sigmas.
    cfg = ds.config.with_(pos_std_floor_m=0.0, vel_std_floor_mps=0.0)
    nav = Navigator(cfg, ds.initial)
    bias = true_biases(ds)
    imu, gnss, truth = ds.imu, ds.gnss, ds.truth
    out = []
    j = 0
    for k in range(1, len(imu)):
        t = int(imu.t_ns[k])
        while j < len(gnss) and gnss.t_ns[j] <= t:
            nav.on_gnss(gnss.fix_at(j))
            j += 1
        nav.on_imu(t, imu.dtheta[k], imu.dvel[k])
        if k % 100:
            continue
        s = nav.state
        err = np.empty(15)
        err[0:3] = earth.llh_to_ned(s.llh, truth.llh[k])
        err[3:6] = s.v_n - truth.v_n[k]
        A = euler_to_dcm(truth.euler[k]) @ s.C_nb.T  # = I + [phi x]
        err[6:9] = 0.5 * np.array([A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1]])
        err[9:12] = np.asarray(nav.gyro_bias) - bias.gyro_bias[k]
        err[12:15] = np.asarray(nav.accel_bias) - bias.accel_bias[k]
        out.append(err / np.sqrt(np.diag(nav.P)))
    return np.array(out)


@pytest.fixture(scope="module")
def runs():
    return np.concatenate([normalized_errors(seed) for seed in range(10)])


@pytest.mark.parametrize("group", list(GROUPS))
def test_normalized_error_rms_per_state_group(runs, group):
    rms = float(np.sqrt(np.mean(runs[:, GROUPS[group]] ** 2)))
    print(f"{group}: rms(error/sigma) = {rms:.3f}")
    assert 0.5 <= rms <= 1.5, f"{group}: rms(error/sigma) = {rms:.3f}"
