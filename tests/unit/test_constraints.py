"""The non-holonomic constraint as an aiding source (zennav.nav.aid.constraints) on the simulated car, whose
body frame has no lateral and vertical velocity: it bounds the outage drift, reports on nav/aid/nhc, and is off
by default."""
from __future__ import annotations

import numpy as np
import pytest

from zennav.datasets.registry import load_dataset
from zennav.metrics import evaluate
from zennav.nav.navigator import Navigator
from zennav.replay import run_replay


@pytest.fixture(scope="module")
def car():
    return load_dataset("sim:car", duration_s=240.0)


def test_nhc_lowers_the_outage_drift_of_a_car(car):
    outages = [(150.0, 60.0)]
    plain = evaluate(car, run_replay(car, outages=outages))["outages"][0]["max_horizontal_m"]
    car_nhc = load_dataset("sim:car", duration_s=240.0)
    car_nhc.config = car_nhc.config.with_(nhc=True)
    res = run_replay(car_nhc, outages=outages)
    nhc = evaluate(car_nhc, res)["outages"][0]["max_horizontal_m"]
    assert nhc < 0.5 * plain, (nhc, plain)
    reports = [r for r in res.reports if r.source == "nhc"]
    assert len(reports) > 2000 and sum(r.fused for r in reports) > 0.95 * len(reports)
    r = reports[-1]
    assert len(r.innovation) == 2 and len(r.innovation_var) == 2 and r.last_fused_t_ns > 0
    assert res.status["counters"]["nhc_fused"] == sum(r.fused for r in reports)


def test_nhc_is_off_by_default_and_takes_its_settings(car):
    assert "nhc" not in Navigator(car.config, car.initial).sources
    nav = Navigator(car.config.with_(nhc=True), car.initial)
    assert nav.sources["nhc"].every_ns == int(car.config.nhc_every_s * 1e9)
    rho = np.exp(-0.1 / 0.5)  # nhc_every_s over nhc_corr_s: the AR(1) inflation of the violation's variance
    np.testing.assert_allclose(nav.sources["nhc"].R, np.diag([0.1**2, 0.1**2]) * (1 + rho) / (1 - rho), rtol=1e-12)
    white = Navigator(car.config.with_(nhc=True, nhc_corr_s=0.0), car.initial)
    np.testing.assert_array_equal(white.sources["nhc"].R, np.diag([0.1**2, 0.1**2]))


def test_ar1_factor_gives_the_variance_of_a_mean_of_correlated_errors():
    """n samples of a first-order Gauss-Markov error every dt: the variance of their mean is about
    correlated_variance(std, dt, tau) / n (the variance a filter taking them as independent must give each)."""
    from zennav.nav.aid.base import correlated_variance

    rng = np.random.default_rng(0)
    std, dt, tau, n, trials = 0.1, 0.1, 0.5, 200, 4000
    rho = np.exp(-dt / tau)
    e = np.empty((trials, n))
    e[:, 0] = rng.normal(0.0, std, trials)
    for k in range(1, n):
        e[:, k] = rho * e[:, k - 1] + rng.normal(0.0, std * np.sqrt(1 - rho**2), trials)
    ratio = np.var(e.mean(axis=1)) / (correlated_variance(std, dt, tau) / n)
    assert 0.85 < ratio < 1.1, ratio
    assert correlated_variance(std, dt, 0.0) == std**2
