"""The engine's block loop (zennav.nav.kernels.run_block through Navigator.run_imu) gives the step-wise engine's
floats: run as Python bit for bit (outage declaration and recovery, rejected samples, the non-holonomic constraint,
the 21-state scale factors), compiled by numba to 1e-9 relative (one compile per process: the kernels' on-disk
cache is empty in a clean clone)."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.nav import kernels
from zennav.nav.eskf import discretize
from zennav.nav.navigator import Navigator
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset

OUTAGES = [(40.0, 30.0)]


def _drive(case: str):
    ds = make_dataset("car", duration_s=90.0, seed=4, scale_ppm=(5000.0, 5000.0) if case == "scale" else 0.0)
    if case == "nhc":
        ds.config = ds.config.with_(nhc=True)
    if case == "bad":  # a non-finite sample and a repeated time: rejected, counted, the run goes on
        ds.imu.dtheta[3000, 1] = np.nan
        ds.imu.t_ns[7000] = ds.imu.t_ns[6999]
    return ds


def _fields(res) -> list:
    return [res.t_ns, res.llh, res.v_n, res.q_nb, res.std_pos_ned, res.outage]


@pytest.mark.parametrize("case", ["outage", "bad", "nhc", "scale"])
def test_block_loop_gives_the_step_wise_floats(case):
    ds = _drive(case)
    step = run_replay(ds, outages=OUTAGES, loop="step")
    block = run_replay(ds, outages=OUTAGES, loop="python")
    for a, b in zip(_fields(step), _fields(block)):
        assert np.array_equal(a, b)
    assert repr(step.status) == repr(block.status)  # counters, alignment, noise: all equal
    assert [vars(r) for r in step.reports] == [vars(r) for r in block.reports]
    assert step.status["counters"]["outage_declared"] == 1
    if case == "bad":
        assert step.status["counters"]["imu_nonfinite"] == step.status["counters"]["imu_duplicate"] == 1
    if case == "nhc":
        assert step.status["counters"]["nhc_fused"] > 800  # every 0.1 s
    if case == "scale":
        assert set(Navigator(ds.config, ds.initial).aug_blocks) == {"gyro_scale", "accel_scale"}  # 21 states


def test_compiled_loop_gives_the_python_floats():
    for case in ("outage", "scale"):
        ds = _drive(case)
        step = run_replay(ds, outages=OUTAGES, loop="step")
        jit = run_replay(ds, outages=OUTAGES, loop="compiled")
        for a, b in zip(_fields(step), _fields(jit)):
            np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)
        assert step.status["counters"] == jit.status["counters"]


def test_propagation_folds_the_trapezoidal_process_noise_in():
    """kernels.propagate: Phi (P + Q dt/2) Phi' + Q dt/2 is discretize's Phi P Phi' + Qd (one triple product)."""
    rng = np.random.default_rng(7)
    A = rng.normal(size=(21, 21))
    P = A @ A.T
    F = rng.normal(size=(21, 21))
    q = rng.uniform(0.0, 1.0, 21)
    Phi, Qd = discretize(F, q, 0.05)
    P1 = kernels.propagate(P, Phi, q, 0.05)
    np.testing.assert_allclose(P1, Phi @ P @ Phi.T + Qd, rtol=1e-12, atol=1e-12 * np.abs(P1).max())
    assert np.array_equal(P1, P1.T)
    np.testing.assert_array_equal(Phi, kernels.transition_matrix(F, 0.05))
