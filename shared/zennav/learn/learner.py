"""The learner: the transport-free core of the trainer service and of the in-process loop (zennav.learn.loop).

One Learner per target variant. It takes the target's samples in order (``add``) and the sample counts that
queries need a model through (``request``); ``due()`` names the next fit point and ``fit(n)`` consumes the
samples up to the n-th, fits and returns the parameter set (zennav.learn.paramset.build) trained through exactly
n samples, or None (counted) when none can be made. Fit points, all in data terms (LearnSettings): min_samples,
min_samples + retrain_samples, ... and every requested count above the last fit point, in increasing order. The
same samples and requests give the same fit points and, with torch on one thread, the same sets bit for bit,
whether the learner is driven by the trainer's threads or by the replay loop.

Models (settings.model):
- anfis: fit on the newest `window` of the first n samples, by zennav.learn.anfis_torch.fit_anfis_sigma with the
  hybrid LSE + Fletcher-Reeves CG premises (optimizer cg, seed 000) or PSO premises (optimizer pso, seed 003; the
  swarm of zennav.learn.pso with a constant inertia 0.7298 and c1 = c2 = 1.49618, Clerc and Kennedy, IEEE TEC
  6(1) 2002; the seed gives the PSO update but no coefficient values) or the improved swarm (optimizer ipso, seed
  003 step 3.3: zennav.learn.pso.IMPROVED). Inputs are z-scored, those of MINMAX_FEATURES min-max scaled.
  1-sigma: the residuals on the newest quarter of the samples of a fit on the rest (zennav.learn.sigma); an output
  whose ANFIS predicts that quarter no better than the target's mean is answered by the mean (metrics skill). Epochs
  (cg): chosen by early stopping within the other three quarters (settings.val_patience;
  zennav.learn.anfis_torch.select_epochs), at most max_epochs. torch is
  imported only inside the fit, or not at all with a ``fitter`` (the trainer's zennav.learn.fit_worker.FitWorker:
  the same fit in a child process).
- elman (seed 002): ElmanOnline learns every sample in order; its set at n is its state after n samples (weights,
  context, normalisation, the range of the learned features, 1-sigma of its free-running copies); no set while
  its training error is above its threshold.

Every set's metrics carry samples_seen (= n), the target, the model and method, and sigma (1-sigma per output,
physical units). created_t_ns is the time of the n-th sample (data time), so a set depends on its data only.
"""
from __future__ import annotations

import threading
from collections import Counter, deque

import numpy as np

from ..nav.learning import ANSWER_PERIOD_S, FEATURES, MINMAX_FEATURES, OUTPUTS, TARGETS
from . import anfis_numpy, paramset
from .elman import Elman
from .elman import step as elman_step
from .settings import LearnSettings
from .sigma import answer_lag, answer_sigma


class ElmanOnline:
    """Online Elman network (seed 002) on a sliding window of `window` samples. Learning starts once
    `min_samples` samples are in, with the input/output normalisation of those; every `min_samples` samples after
    that the normalisation is refit from the window's samples and the network takes it without changing what it
    computes (Elman.renormalize), so that the first samples do not fix the scale for good.

    Its 1-sigma comes from free-running residuals, as the network is used in an outage: every `free_run_s` of
    sample time a copy of the network is frozen (weights and context) and predicts the following samples,
    advancing only its context, without learning; the residuals of those predictions (not the one-step-ahead
    ones of the learning network, which keeps adapting) go through answer_sigma."""

    def __init__(self, target: str, settings: LearnSettings):
        self.target, self.s = target, settings
        # LearnSettings.__post_init__ resolves window and min_samples (None: the model's default)
        assert settings.window is not None and settings.min_samples is not None
        self.window, self.min_samples = settings.window, settings.min_samples
        self.net: Elman | None = None
        self._first: list[tuple[int, np.ndarray, np.ndarray]] = []
        self._residuals: deque = deque(maxlen=self.window)  # of the frozen copy
        self._residual_t: deque = deque(maxlen=self.window)  # their times [ns]
        self.free_run_ns = int(settings.free_run_s * 1e9)
        self._frozen: tuple[int, dict, dict] | None = None  # (start t_ns, arrays and normalisation of the copy)
        self._x_min: np.ndarray | None = None  # range of the learned features
        self._x_max: np.ndarray | None = None
        self.learned = 0

    def _learn(self, t_ns: int, x: np.ndarray, y: np.ndarray) -> None:
        net = self.net
        assert net is not None  # add() learns only once the network is made
        if net.ready:
            net.predict(x)  # the one-step answer (advances the context the window stores)
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

    def add(self, t_ns: int, x: np.ndarray, y: np.ndarray) -> None:
        """Learn one sample (physical units), in time order."""
        if self.net is not None:
            self._learn(t_ns, x, y)
            return
        self._first.append((t_ns, x, y))
        if len(self._first) == self.min_samples:
            xs, ys = (np.array(v) for v in list(zip(*self._first))[1:])
            s = self.s
            self.net = Elman(len(FEATURES[self.target]), s.n_hidden, len(OUTPUTS[self.target]), window=self.window,
                             min_samples=self.min_samples, threshold=s.threshold,
                             norm=anfis_numpy.fit_normalization(xs, ys), seed=s.seed)
            self.net.set_aligned()  # samples only come from a converged filter
            for ti, xi, yi in self._first:
                self._learn(ti, xi, yi)
            self._first = []

    @property
    def ready(self) -> bool:
        return self.net is not None and self.net.ready and len(self._residuals) >= 10

    def norm(self) -> dict[str, np.ndarray]:
        """The network's normalisation plus the range of the learned features (x_min, x_max); once ready."""
        # ready: the network is made and has learned samples, so the range is set
        assert self.net is not None and self._x_min is not None and self._x_max is not None
        return {**self.net.norm(), "x_min": self._x_min, "x_max": self._x_max}

    def std(self) -> np.ndarray:
        """1-sigma per output (physical units): answer_sigma of the free-running residuals (class docstring)."""
        lag = answer_lag(np.array(self._residual_t), ANSWER_PERIOD_S[self.target])
        return answer_sigma(np.array(self._residuals), lag=lag)[0]


class Learner:
    """Samples, schedule and fits of one target variant (module docstring). Thread use: ``add`` and ``request``
    from one thread (e.g. the bus's), ``due`` / ``fit`` from another (e.g. a training thread) is safe; ``fit``
    runs without the lock, so samples keep arriving while it trains."""

    def __init__(self, target: str, settings: LearnSettings, name: str | None = None, device=None, fitter=None):
        if target not in TARGETS:
            raise ValueError(f"target must be one of {TARGETS}")
        self.target, self.s, self.device = target, settings, device
        self.fitter = fitter  # None: fit_anfis_sigma in this process (torch threads set per fit)
        self.name = name or f"{settings.model}-{target}"
        # LearnSettings.__post_init__ resolves window and min_samples (None: the model's default)
        assert settings.window is not None and settings.min_samples is not None
        self.window, self.min_samples = settings.window, settings.min_samples
        self.lock = threading.Lock()
        self.received = 0  # samples added (the count n of the newest)
        self.through = 0  # samples consumed: the last fit point
        self.done = 0  # the last fit point whose fit is over (its set, if any, made)
        self._pending: deque = deque()  # (t_ns, x, y) added, not yet consumed
        self._requests: set[int] = set()
        self._rows: deque = deque(maxlen=self.window)  # anfis: the newest consumed samples
        self.elman = ElmanOnline(target, settings) if settings.model == "elman" else None
        self._last_t_ns = 0
        self.counts: Counter[str] = Counter()
        self.last: dict = {}  # metrics of the last set
        self.last_error = ""  # of the last failed fit

    # ------------------------------------------------------------------ input
    def add(self, t_ns: int, x, y) -> None:
        """The next sample of the target (features, value; physical units)."""
        with self.lock:
            self._pending.append((int(t_ns), np.asarray(x, dtype=float), np.asarray(y, dtype=float)))
            self.received += 1

    def request(self, n: int) -> None:
        """A query needs a set trained through the first n samples (counted 'behind' when the last fit point
        is already past n, 'early' below min_samples: no set can be made for it)."""
        with self.lock:
            if n < self.min_samples:
                self.counts["requests_early"] += 1
            elif n < self.through:
                self.counts["requests_behind"] += 1
            elif n > self.through:
                self._requests.add(int(n))

    # ------------------------------------------------------------------ schedule
    def _next_scheduled(self) -> int:
        m, r = self.min_samples, self.s.retrain_samples
        return m if self.through < m else m + (-(-(self.through + 1 - m) // r)) * r

    def due(self) -> int | None:
        """The next fit point once its samples are all in, else None."""
        with self.lock:
            p = min([self._next_scheduled(), *self._requests])
            return p if p <= self.received else None

    def counters(self) -> dict[str, int]:
        """<count>_<target>: received, through (the last fit point done), set_through (samples_seen of the last set),
        min_samples, sets, fit_points, outputs_by_mean (anfis: outputs of its sets answered by the target's mean),
        elman_not_ready, fit_errors, requests_early, requests_behind (the trainer's status counters; a lockstep
        predictor stops waiting for a set through n when min_samples > n or set_through < n <= through: none will
        come)."""
        t = self.target
        with self.lock:
            c = {f"received_{t}": self.received, f"through_{t}": self.done,
                 f"set_through_{t}": int(self.last.get("samples_seen", 0)), f"min_samples_{t}": self.min_samples}
            c.update({f"{k}_{t}": v for k, v in self.counts.items()})
        return c

    # ------------------------------------------------------------------ fit
    def _consume(self, n: int) -> None:
        with self.lock:
            take = [self._pending.popleft() for _ in range(n - self.through)]
            self.through = n
            self._requests = {r for r in self._requests if r > n}
        for t_ns, x, y in take:
            if self.elman is not None:
                self.elman.add(t_ns, x, y)
            else:
                self._rows.append((t_ns, x, y))
            self._last_t_ns = t_ns

    def fit(self, n: int, version: int) -> dict | None:
        """Consume the samples up to the n-th (n: a due() point) and return the set through them as version, or
        None (counted: elman_not_ready, fit_errors)."""
        self._consume(n)
        self.counts["fit_points"] += 1
        try:
            return self._elman_set(n, version) if self.elman is not None else self._anfis_set(n, version)
        finally:
            self.done = n

    def _build(self, n: int, version: int, arrays, norm, metrics: dict, kind: str) -> dict:
        metrics = {**metrics, "target": self.target, "samples_seen": n, "model": self.s.model}
        msg = paramset.build(self.name, version, arrays, norm, metrics, kind=kind, created_t_ns=self._last_t_ns)
        self.counts["sets"] += 1
        # anfis: outputs answered by the target's mean (no held-out skill, zennav.learn.anfis_torch.fit_anfis_sigma)
        if "skill" in metrics:
            self.counts["outputs_by_mean"] += metrics["skill"].count(0)
        self.last = {"version": version, "samples_seen": n, "sigma": [round(float(v), 4) for v in metrics["sigma"]]}
        return msg

    def _elman_set(self, n: int, version: int) -> dict | None:
        comp = self.elman
        assert comp is not None  # fit() calls this for the elman model only
        if not comp.ready:
            self.counts["elman_not_ready"] += 1
            return None
        net = comp.net
        assert net is not None  # ready: the network is made
        metrics = {"method": "elman_online", "sigma": comp.std().tolist(), "samples": comp.learned,
                   "window": net.window, "n_hidden": net.n_hidden, "context_gain": float(net.context_gain),
                   "window_rmse_normalised": float(net.train_rmse)}
        arrays = {k: v.copy() for k, v in net.arrays().items()}
        return self._build(n, version, arrays, comp.norm(), metrics, "elman")

    def _fit_here(self, x, y, *, config: dict, **kw):
        """fit_anfis_sigma in this process (config: TrainConfig's fields), torch on settings.torch_threads threads
        during the fit."""
        import torch  # the fit only (module docstring)

        from .anfis_torch import TrainConfig, fit_anfis_sigma

        threads = torch.get_num_threads()
        torch.set_num_threads(self.s.torch_threads or threads)
        try:
            return fit_anfis_sigma(x, y, config=TrainConfig(**config), **kw)
        finally:
            torch.set_num_threads(threads)

    def _anfis_set(self, n: int, version: int) -> dict | None:
        rows = list(self._rows)
        t_ns = np.array([r[0] for r in rows], dtype=np.int64)
        x, y = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
        minmax = {"minmax": MINMAX_FEATURES[self.target]} if self.target in MINMAX_FEATURES else {}
        try:
            fit = (self.fitter or self._fit_here)(
                x, y, max_rules=self.s.n_rules, device=self.device, t_ns=t_ns,
                answer_period_s=ANSWER_PERIOD_S[self.target],
                config={"method": self.s.method, "max_epochs": self.s.max_epochs,
                        "val_patience": self.s.val_patience, "seed": self.s.seed}, **minmax)
        except Exception as e:  # a degenerate window must not stop the learner: no set, counted, reason kept
            self.counts["fit_errors"] += 1
            self.last_error = f"{type(e).__name__}: {e}"[:300]
            return None
        metrics = {**fit.metrics, "samples": int(len(x)), "t_first_ns": int(t_ns.min()), "t_last_ns": int(t_ns.max()),
                   "device": str(self.device or "cpu"), "n_rules": int(len(fit.arrays["rules"]))}
        return self._build(n, version, fit.arrays, fit.norm, metrics, "anfis")
