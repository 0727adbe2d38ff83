"""Particle swarm optimisation with an inertia weight (numpy only).

J. Kennedy, R. Eberhart, "Particle swarm optimization", Proc. ICNN 1995; inertia weight: Y. Shi, R. Eberhart,
"A modified particle swarm optimizer", Proc. IEEE ICEC 1998 (linearly decreasing w: 0.9 -> 0.4); default
coefficients w = 0.7298, c1 = c2 = 1.49618 from M. Clerc, J. Kennedy, IEEE TEC 6(1) 2002 (constriction):
  v <- w v + c1 r1 (pbest - x) + c2 r2 (gbest - x),  x <- x + v,   r1, r2 ~ U(0, 1) per dimension,
with |v| <= vmax_frac * (upper - lower) per dimension and positions clipped to the bounds (the velocity
component that hits a bound is zeroed). Seed 003 uses it to tune the ANFIS premises.

Seed 003's "improved PSO" names no schedule; IMPROVED is the usual pair of schedules over the iterations
t = 0 .. max_iter - 1 (fraction s = t / (max_iter - 1)): linearly decreasing inertia w = 0.9 -> 0.4 (Shi and
Eberhart 1998) and time-varying acceleration coefficients c1 = 2.5 -> 0.5, c2 = 0.5 -> 2.5 (A. Ratnaweera,
S. K. Halgamuge, H. C. Watson, "Self-organizing hierarchical particle swarm optimizer with time-varying
acceleration coefficients", IEEE TEC 8(3) 2004): first each particle explores around its own best, later the
swarm converges on the global best.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PSOConfig:
    """Swarm size, coefficients and schedule. inertia_end=None keeps the inertia constant; otherwise it
    moves linearly from `inertia` to `inertia_end` over `max_iter` iterations; likewise cognitive_end and
    social_end for c1 and c2 (time-varying acceleration coefficients)."""

    n_particles: int = 20
    max_iter: int = 100
    inertia: float = 0.7298
    inertia_end: float | None = None
    cognitive: float = 1.49618
    social: float = 1.49618
    cognitive_end: float | None = None
    social_end: float | None = None
    vmax_frac: float = 0.2
    init_spread: float = 0.25  # with x0: the swarm starts uniformly within x0 +- init_spread * (upper - lower)


# seed 003's improved PSO (module docstring): w 0.9 -> 0.4, c1 2.5 -> 0.5, c2 0.5 -> 2.5
IMPROVED = PSOConfig(inertia=0.9, inertia_end=0.4, cognitive=2.5, cognitive_end=0.5, social=0.5, social_end=2.5)


@dataclass
class PSOResult:
    x: np.ndarray
    f: float
    n_iter: int
    history: list[float] = field(default_factory=list)  # best f after each iteration, [0] = initial swarm


class Swarm:
    """A swarm over the box [lower, upper]; fun maps positions (P, d) to costs (P,). Seeded, deterministic.

    With x0 one particle starts at x0 (so the best never gets worse than x0) and the others around it.
    """

    def __init__(self, fun: Callable[[np.ndarray], np.ndarray], lower, upper, config: PSOConfig = PSOConfig(),
                 *, x0=None, seed: int = 0):
        self.fun, self.cfg = fun, config
        self.lower, self.upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        if self.lower.shape != self.upper.shape or np.any(self.upper <= self.lower):
            raise ValueError("bounds must have equal shapes and upper > lower")
        self.rng = np.random.default_rng(seed)
        width = self.upper - self.lower
        shape = (config.n_particles, self.lower.size)
        if x0 is None:
            self.x = self.lower + width * self.rng.random(shape)
        else:
            x0 = np.clip(np.asarray(x0, dtype=float), self.lower, self.upper)
            self.x = np.clip(x0 + config.init_spread * width * self.rng.uniform(-1.0, 1.0, shape),
                             self.lower, self.upper)
            self.x[0] = x0
        self.vmax = config.vmax_frac * width
        self.v = self.vmax * self.rng.uniform(-1.0, 1.0, shape)
        self.f = np.asarray(fun(self.x), dtype=float)
        self.pbest_x, self.pbest_f = self.x.copy(), self.f.copy()
        self.iteration = 0
        self.history = [self.best_f]

    @property
    def best_f(self) -> float:
        return float(np.min(self.pbest_f))

    @property
    def best_x(self) -> np.ndarray:
        return self.pbest_x[int(np.argmin(self.pbest_f))].copy()

    def _scheduled(self, start: float, end: float | None) -> float:
        """start moved linearly to end over the iterations (constant when end is None)."""
        if end is None:
            return start
        t = min(self.iteration / max(self.cfg.max_iter - 1, 1), 1.0)
        return start + t * (end - start)

    def inertia(self) -> float:
        return self._scheduled(self.cfg.inertia, self.cfg.inertia_end)

    def coefficients(self) -> tuple[float, float, float]:
        """(w, c1, c2) of the next step."""
        c = self.cfg
        return self.inertia(), self._scheduled(c.cognitive, c.cognitive_end), self._scheduled(c.social, c.social_end)

    def step(self) -> float:
        """One velocity/position update and evaluation of the whole swarm; returns the best cost."""
        w, c1, c2 = self.coefficients()
        r1, r2 = self.rng.random(self.x.shape), self.rng.random(self.x.shape)
        gbest = self.best_x
        self.v = w * self.v + c1 * r1 * (self.pbest_x - self.x) + c2 * r2 * (gbest - self.x)
        self.v = np.clip(self.v, -self.vmax, self.vmax)
        x = self.x + self.v
        hit = (x < self.lower) | (x > self.upper)
        self.x = np.clip(x, self.lower, self.upper)
        self.v[hit] = 0.0
        self.f = np.asarray(self.fun(self.x), dtype=float)
        better = self.f < self.pbest_f
        self.pbest_x[better], self.pbest_f[better] = self.x[better], self.f[better]
        self.iteration += 1
        self.history.append(self.best_f)
        return self.best_f


def pso_minimize(fun, lower, upper, config: PSOConfig = PSOConfig(), *, x0=None, seed: int = 0,
                 goal: float = -np.inf) -> PSOResult:
    """Run a Swarm for config.max_iter iterations or until the best cost is <= goal."""
    swarm = Swarm(fun, lower, upper, config, x0=x0, seed=seed)
    while swarm.iteration < config.max_iter and swarm.best_f > goal:
        swarm.step()
    return PSOResult(swarm.best_x, swarm.best_f, swarm.iteration, swarm.history)
