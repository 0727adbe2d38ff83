"""The learning loop in one process (ARCHITECTURE.md section 3, without transport): the trainer's Learner and the
predictor's PredictorCore wired directly, with the same settings (LearnSettings), the same fit points and the same
answers as trainer + predictor over the bus in lockstep. What ``zennav replay --compensation`` and the demo use.

The replay hands over the engine's samples (``add``) and queries (``predict`` -> (value, 1-sigma) or None). A query
carries the count n of its target's samples so far: the learner fits through n if no set is through n yet (the
first query of an outage, so the model includes the newest data), the core swaps the set in and answers with it.
The scheduled fits (every retrain_samples samples) are the trainer's; they are made when their sets may first be
used, before the next query is answered (``settle``: before an answer, ``status`` and ``save_model``), in the
trainer's order, so every answer, set and counter is the trainer's; a set that no query could use (the fits after
a replay's last query) is never made unless asked for.

A model trained on other runs (e.g. other trajectories of a vehicle: seed 003 trains at the surface, the A-KIT
benchmark on other dives) goes from one loop to another as a parameter-set file (``save_model`` writes the last set,
msgpack as on the bus; ``load_model`` validates it as the predictor does): a loop with a loaded model is frozen, it
answers with that set and learns nothing more (its samples are counted, not learned).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..nav.learning import TARGETS, LearnQuery, LearnSample
from . import paramset
from .learner import Learner
from .predictor_core import PredictorCore
from .settings import COMPENSATIONS, LearnSettings, compensation_settings

CHOICES = ("none", *COMPENSATIONS)  # `zennav replay --compensation`
DEFAULTS = LearnSettings()


class InProcessLoop:
    """Learner + PredictorCore of one target variant (module docstring); counts as the services do."""

    def __init__(self, target: str = "body_velocity", settings: LearnSettings = DEFAULTS, fitter=None):
        self.target, self.settings = target, settings
        self.fitter = fitter  # the learner's ANFIS fits: None in this process, or a FitWorker (close() stops it)
        self.learner = Learner(target, settings, fitter=fitter)
        self.core = PredictorCore(settings.max_domain_excess)
        self.version = 0  # of the last set made
        self.queries = 0  # queries received for the target
        self.last_refusal = ""  # the reason the last query was refused ("": answered, or not this loop's target)
        self.last_set: dict | None = None  # the last parameter-set message made or loaded
        self.frozen = False  # a loaded model: no learning
        self.ignored = 0  # samples not learned by a frozen loop

    def settle(self) -> None:
        """Make every fit due so far (the trainer makes them as the samples arrive): version, last_set, core and
        the learner's counters are then the trainer's."""
        while not self.frozen and (n := self.learner.due()) is not None:
            msg = self.learner.fit(n, self.version + 1)
            if msg is None:
                continue
            self.version += 1
            self.core.offer(msg["name"], msg)
            self.last_set = msg

    def save_model(self, path) -> None:
        """Write a parameter set trained through every sample received (fitted now where newer samples arrived
        since the last set, as a query would; msgpack, zennav.learn.paramset.encode); ValueError when none can be
        made."""
        if not self.frozen and self.learner.received >= self.learner.min_samples:
            self.learner.request(self.learner.received)
            self.settle()
        if self.last_set is None:
            raise ValueError(f"no {self.target} model was trained: nothing to save")
        Path(path).write_bytes(paramset.encode(self.last_set))

    def load_model(self, path) -> None:
        """Serve the parameter set in path (validated as the predictor does: schema, checksum, shapes, target) and
        freeze the loop; ValueError with the reason when it is not a set of this loop's target."""
        msg = paramset.decode(Path(path).read_bytes())
        if (msg.get("metrics") or {}).get("target") != self.target:
            raise ValueError(f"{path}: not a {self.target} model")
        live, reason = self.core.offer(str(msg.get("name")), msg)
        if live is None:
            raise ValueError(f"{path}: {reason}")
        self.last_set, self.frozen, self.version = msg, True, live.version

    def add(self, samples: list[LearnSample]) -> None:
        """The engine's new training samples (other targets are ignored; a frozen loop counts them only)."""
        for s in samples:
            if s.target == self.target:
                if self.frozen:
                    self.ignored += 1
                else:
                    self.learner.add(s.t_ns, s.features, s.value)

    def predict(self, query: LearnQuery) -> tuple[np.ndarray, tuple] | None:
        """The answer (value, 1-sigma per output) to a query, through the model trained through every sample so
        far; None when refused (counted by reason in core.queries; the reason in last_refusal)."""
        self.last_refusal = ""
        if query.target != self.target:
            return None
        self.queries += 1
        if not self.frozen:
            self.learner.request(self.learner.received)
            self.settle()
        out = self.core.answer(query.target, query.features, None if self.frozen else self.learner.received)
        if isinstance(out, str):
            self.last_refusal = out
            return None
        return out[:2]

    def status(self) -> dict[str, dict[str, int]]:
        """The counters the services put in their status messages: "trainer" (zennav.services.trainer: per target
        received, through, sets, fit_points, version, ...), "predictor" (PredictorCore: sets accepted / rejected,
        queries answered, refused per reason, late_model, live version) and "link" (queries sent; whether an
        answer was fused is the engine's: its learned_<target>_fused / rejection counters)."""
        self.settle()
        return {"trainer": {**self.learner.counters(), f"version_{self.target}": self.version,
                            **({"frozen": 1, "ignored": self.ignored} if self.frozen else {})},
                "predictor": self.core.counters(), "link": {"queries": self.queries}}

    def close(self) -> None:
        """Stop the fit worker, if the loop has one (fits asked for later raise, counted fit_errors)."""
        if self.fitter is not None:
            self.fitter.close()


def make_compensator(compensation: str, target: str = "body_velocity", seed: int = 0,
                     fit_worker: bool = False) -> InProcessLoop | None:
    """'none' -> None; 'anfis' (CG), 'anfis-pso' or 'elman' -> the in-process loop with the default settings.
    fit_worker: the ANFIS fits in a child process started now (zennav.learn.fit_worker: the same sets bit for bit;
    torch imports there beside the run, not in it: a command that runs one replay; close() the loop after it)."""
    if compensation == "none":
        return None
    if target not in TARGETS:
        raise ValueError(f"target must be one of {TARGETS}")
    settings = compensation_settings(compensation, seed)
    if not (fit_worker and settings.model == "anfis"):
        return InProcessLoop(target, settings)
    from .fit_worker import FitWorker

    return InProcessLoop(target, settings, FitWorker(settings.torch_threads).start())


def training_set(ds, target: str = "body_velocity", navigator=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features (N, n_features), targets (N, n_outputs) and times t_ns (N,) of the learning samples of one target
    variant that the engine emits over the whole of ds with full GNSS (the set the trainer would see).
    navigator: the engine to run (its config must have learning on); default: ds's config with learning."""
    from ..nav.navigator import Navigator
    from ..replay import run_replay

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
