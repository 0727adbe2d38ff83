"""Learned INS-error compensation in one process: the learning loop of DESIGN.md section 5 without transport.

A compensator takes the navigation engine's LearnSamples while GNSS is good and answers its LearnQueries
while GNSS is lost with a prediction of the query's target variant and its 1-sigma (nav/learning.py). Two models:
- "anfis" (seed 000): first-order Takagi-Sugeno ANFIS, k-means rule base, trained by the hybrid
  least-squares + Fletcher-Reeves CG learner on the newest samples when a prediction is first needed after
  new samples arrived (i.e. at the start of each outage); predicts with the numpy forward pass, and only for
  features within `max_domain_excess` training standard deviations of the training range (as the predictor
  service; a first-order TS model extrapolates without bound outside it).
- "elman" (seed 002): Elman network trained online on a sliding window of the newest samples; predicts
  only while its training error is under its threshold.
The 1-sigma of an answer, per output (zennav.learn.sigma: out-of-sample residuals, their RMS inflated for their
correlation from answer to answer): ANFIS, the residuals on the newest quarter of the samples of a fit on the
rest (anfis_torch.fit_anfis_sigma); Elman, the residuals of a frozen copy running free over the following
samples (ElmanCompensator).
"""
from __future__ import annotations

from collections import deque

import numpy as np

from .learn import anfis_numpy
from .learn.elman import Elman
from .learn.elman import step as elman_step
from .learn.sigma import answer_lag, answer_sigma
from .nav.learning import ANSWER_PERIOD_S, FEATURES, OUTPUTS, TARGETS, LearnQuery, LearnSample

MODELS = ("none", "anfis", "elman")


class AnfisCompensator:
    """ANFIS (hybrid LSE + FR-CG) over the newest `window` samples; retrains lazily when new samples arrived."""

    def __init__(self, target: str = "body_velocity", n_rules: int = 8, window: int = 2000, min_samples: int = 100,
                 max_epochs: int = 30, seed: int = 0, max_domain_excess: float = 0.5, threads: int | None = 1):
        """threads: torch's thread count while training (1: the fit, whose float reductions depend on it, is the
        same on every machine; None: torch's default)."""
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}")
        self.target, self.n_rules, self.min_samples, self.max_epochs, self.seed = (
            target, n_rules, min_samples, max_epochs, seed)
        self.threads = threads
        self.max_domain_excess = max_domain_excess
        self.off_domain = 0  # queries refused: features outside the training range
        self._t: deque = deque(maxlen=window)
        self._x: deque = deque(maxlen=window)
        self._y: deque = deque(maxlen=window)
        self._stale = False
        self.model: tuple[dict, dict] | None = None
        self.sigma: np.ndarray | None = None
        self.trainings: list[dict] = []

    def add(self, samples: list[LearnSample]) -> None:
        for s in samples:
            if s.target == self.target:
                self._t.append(s.t_ns)
                self._x.append(s.features)
                self._y.append(s.value)
                self._stale = True

    def _train(self) -> None:
        import torch  # only when training in-process

        from .learn.anfis_torch import TrainConfig, fit_anfis_sigma

        x, y, t_ns = np.array(self._x), np.array(self._y), np.array(self._t)
        config = TrainConfig(max_epochs=self.max_epochs, seed=self.seed)
        threads = torch.get_num_threads()
        torch.set_num_threads(self.threads or threads)
        try:
            fit = fit_anfis_sigma(x, y, max_rules=self.n_rules, config=config, t_ns=t_ns,
                                  answer_period_s=ANSWER_PERIOD_S[self.target])
        finally:
            torch.set_num_threads(threads)
        self.model = (fit.arrays, fit.norm)
        self.sigma = np.asarray(fit.metrics["sigma"], dtype=float)
        self.trainings.append({"samples": len(x), **{k: fit.metrics[k] for k in ("epochs", "wall_s", "train_rmse",
                                                                                  "sigma")}})
        self._stale = False

    def predict(self, query: LearnQuery) -> tuple[np.ndarray, np.ndarray] | None:
        if query.target != self.target:
            return None
        if self._stale and len(self._x) >= self.min_samples:
            self._train()
        if self.model is None:
            return None
        arrays, norm = self.model
        if anfis_numpy.domain_excess(norm, query.features) > self.max_domain_excess:
            self.off_domain += 1
            return None
        return anfis_numpy.predict(arrays, norm, query.features[None, :])[0], self.sigma


class ElmanCompensator:
    """Online Elman network (seed 002) on a sliding window; silent until its training error is acceptable.
    Learning starts once `min_samples` samples are in, with the input/output normalisation of those; every
    `min_samples` samples after that the normalisation is refit from the window's samples and the network takes
    it without changing what it computes (Elman.renormalize), so that the first samples (e.g. the first seconds
    of one flight) do not fix the scale for good. Like the ANFIS, it answers only features within
    `max_domain_excess` training standard deviations of the range of the features it has learned from.

    Its 1-sigma comes from free-running residuals, as the network is used in an outage: every `free_run_s` of
    sample time a copy of the network is frozen (weights and context) and predicts the following samples,
    advancing only its context, without learning; the residuals of those predictions (not the one-step-ahead
    ones of the learning network, which keeps adapting) go through answer_sigma."""

    def __init__(self, target: str = "body_velocity", n_hidden: int = 12, window: int = 500, threshold: float = 0.8,
                 seed: int = 0, max_domain_excess: float = 0.5, free_run_s: float = 30.0, min_samples: int = 200):
        """window: samples in the sliding window (500: about 2 min of the car drive's 4 Hz fixes); threshold:
        training RMSE (normalised) under which it answers; free_run_s: period of the frozen copies [s];
        min_samples: samples before learning starts, and between two refits of the normalisation."""
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}")
        if not 1 <= min_samples <= window:
            raise ValueError("min_samples must be within 1 .. window")
        self.target, self.n_hidden, self.window, self.threshold, self.seed = target, n_hidden, window, threshold, seed
        self.min_samples = min_samples
        self.max_domain_excess = max_domain_excess
        self.net: Elman | None = None
        self._first: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._residuals: deque = deque(maxlen=window)  # of the frozen copy
        self._residual_t: deque = deque(maxlen=window)  # their times [ns]
        self.free_run_ns = int(free_run_s * 1e9)
        self._frozen: tuple[int, dict, dict] | None = None  # (start t_ns, arrays and normalisation of the frozen copy)
        self._x_min = self._x_max = None  # range of the learned features
        self.learned = 0
        self.off_domain = 0

    def _learn(self, t_ns: int, x: np.ndarray, y: np.ndarray) -> None:
        net = self.net
        if net.ready:
            net.predict(x)  # the one-step answer (advances the context the window stores, as in service)
            if self._frozen is None or t_ns - self._frozen[0] >= self.free_run_ns:
                self._frozen = (t_ns, {k: v.copy() for k, v in net.arrays().items()}, net.norm())
            _, arrays, norm = self._frozen
            y_free, arrays["context"] = elman_step(arrays, norm, x, arrays["context"], net.context_gain)
            self._residuals.append(y_free - y)
            self._residual_t.append(t_ns)
        net.learn(x, y)
        self.learned += 1
        if self.learned % self.min_samples == 0:  # the window's samples back in physical units
            net.renormalize(anfis_numpy.fit_normalization(net.win_x * net.x_std + net.x_mean,
                                                          net.win_y * net.y_std + net.y_mean))
        self._x_min = x.copy() if self._x_min is None else np.minimum(self._x_min, x)
        self._x_max = x.copy() if self._x_max is None else np.maximum(self._x_max, x)

    def add(self, samples: list[LearnSample]) -> None:
        for s in samples:
            if s.target != self.target:
                continue
            x, y = np.asarray(s.features, dtype=float), np.asarray(s.value, dtype=float)
            if self.net is not None:
                self._learn(s.t_ns, x, y)
                continue
            self._first.append((s.t_ns, x, y))
            if len(self._first) == self.min_samples:
                xs, ys = (np.array(v) for v in list(zip(*self._first))[1:])
                self.net = Elman(len(FEATURES[self.target]), self.n_hidden, len(OUTPUTS[self.target]),
                                 window=self.window, min_samples=self.min_samples, threshold=self.threshold,
                                 norm=anfis_numpy.fit_normalization(xs, ys), seed=self.seed)
                self.net.set_aligned()  # samples only come from a converged filter
                for ti, xi, yi in self._first:
                    self._learn(ti, xi, yi)
                self._first = []

    @property
    def ready(self) -> bool:
        return self.net is not None and self.net.ready and len(self._residuals) >= 10

    def norm(self) -> dict[str, np.ndarray]:
        """The network's normalisation plus the range of the learned features (x_min, x_max)."""
        return {**self.net.norm(), "x_min": self._x_min, "x_max": self._x_max}

    def std(self) -> np.ndarray:
        """1-sigma per output (physical units): answer_sigma of the free-running residuals (class docstring)."""
        lag = answer_lag(np.array(self._residual_t), ANSWER_PERIOD_S[self.target])
        return answer_sigma(np.array(self._residuals), lag=lag)[0]

    def predict(self, query: LearnQuery) -> tuple[np.ndarray, np.ndarray] | None:
        if query.target != self.target or not self.ready:
            return None
        if anfis_numpy.domain_excess(self.norm(), query.features) > self.max_domain_excess:
            self.off_domain += 1
            return None
        return self.net.predict(query.features), self.std()


def make_compensator(model: str, target: str = "body_velocity", seed: int = 0):
    """'none' -> None, 'anfis' or 'elman' -> a compensator for the given target variant."""
    if model == "none":
        return None
    if model == "anfis":
        return AnfisCompensator(target, seed=seed)
    if model == "elman":
        return ElmanCompensator(target, seed=seed)
    raise ValueError(f"unknown compensation model {model!r}; choose from {MODELS}")


def training_set(ds, target: str = "body_velocity", navigator=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features (N, n_features), targets (N, n_outputs) and times t_ns (N,) of the learning samples of one target
    variant that the engine emits over the whole of ds with full GNSS (the set the trainer would see).
    navigator: the engine to run (its config must have learning on); default: ds's config with learning."""
    from .nav.navigator import Navigator
    from .replay import run_replay

    if target not in TARGETS:
        raise ValueError(f"target must be one of {TARGETS}")
    collected: list[LearnSample] = []

    class _Collector:
        def add(self, samples):
            collected.extend(s for s in samples if s.target == target)

        def predict(self, query):
            return None

    nav = navigator or Navigator(ds.config.with_(learning=True), ds.initial)
    run_replay(ds, navigator=nav, compensator=_Collector())
    return (np.array([s.features for s in collected]), np.array([s.value for s in collected]),
            np.array([s.t_ns for s in collected], dtype=np.int64))
