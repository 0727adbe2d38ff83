"""Particle swarm optimisation."""
import numpy as np
import pytest

from zennav.learn.pso import PSOConfig, Swarm, pso_minimize


def _shifted_sphere(x):
    return np.sum((x - 0.7) ** 2, axis=1)


def _rastrigin(x):
    return 10.0 * x.shape[1] + np.sum(x**2 - 10.0 * np.cos(2.0 * np.pi * x), axis=1)


def test_converges_on_a_shifted_sphere():
    res = pso_minimize(_shifted_sphere, -5.0 * np.ones(5), 5.0 * np.ones(5), PSOConfig(max_iter=200), seed=1)
    assert res.f < 1e-6
    np.testing.assert_allclose(res.x, 0.7, atol=1e-3)
    assert all(b <= a for a, b in zip(res.history, res.history[1:]))  # the best never gets worse


def test_finds_the_global_basin_of_rastrigin_with_decreasing_inertia():
    cfg = PSOConfig(n_particles=40, max_iter=300, inertia=0.9, inertia_end=0.4, cognitive=2.0, social=2.0)
    res = pso_minimize(_rastrigin, -5.12 * np.ones(2), 5.12 * np.ones(2), cfg, seed=0)
    assert res.f < 1e-3


def test_seeded_bounded_and_x0_kept():
    lo, hi = np.zeros(3), np.ones(3)
    runs = [pso_minimize(_shifted_sphere, lo, hi, PSOConfig(max_iter=5), seed=7).x for _ in range(2)]
    np.testing.assert_array_equal(*runs)
    other = pso_minimize(_shifted_sphere, lo, hi, PSOConfig(max_iter=5), seed=8).x
    assert not np.array_equal(runs[0], other)
    seen = []

    def cost(x):
        seen.append(x.copy())
        return _shifted_sphere(x) + 1.0  # the optimum lies at 0.7, inside; x0 is the best start
    swarm = Swarm(cost, lo, hi, PSOConfig(n_particles=6, vmax_frac=1.0), x0=np.full(3, 0.7), seed=0)
    assert swarm.best_f == pytest.approx(1.0)
    for _ in range(10):
        swarm.step()
    assert all(np.all((x >= lo) & (x <= hi)) for x in seen)
    assert swarm.best_f == pytest.approx(1.0)


def test_inertia_schedule():
    sw = Swarm(_shifted_sphere, -np.ones(2), np.ones(2), PSOConfig(max_iter=11, inertia=0.9, inertia_end=0.4))
    ws = []
    for _ in range(11):
        ws.append(sw.inertia())
        sw.step()
    np.testing.assert_allclose(ws, np.linspace(0.9, 0.4, 11))
    assert Swarm(_shifted_sphere, -np.ones(2), np.ones(2)).inertia() == PSOConfig().inertia
    with pytest.raises(ValueError):
        Swarm(_shifted_sphere, np.ones(2), np.ones(2))
