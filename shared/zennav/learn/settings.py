"""The one set of learning-loop settings, shared by the trainer service (its CLI flags default from it) and the
in-process loop of ``zennav replay --compensation`` and the demo (zennav.learn.loop). numpy-free, torch-free.

Models: "anfis" (first-order Takagi-Sugeno ANFIS, k-means rule base, seed 000) whose premises are trained by the
hybrid least squares + Fletcher-Reeves CG learner (optimizer "cg", seed 000) or by particle swarm with least-squares
consequents (optimizer "pso", seed 003); "elman" (seed 002): an Elman network learning online from every sample.

Schedule (all in data terms, never wall-clock; zennav.learn.learner): a fit is due every `retrain_samples`
samples of a target once `min_samples` are held (at min_samples, min_samples + retrain_samples, ...) and at the
first query after new samples arrived (through the query's sample count).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

MODELS = ("anfis", "elman")
# anfis premises: hybrid LSE + FR-CG (seed 000), PSO (constant coefficients) or seed 003's improved PSO
# (inertia 0.9 -> 0.4, c1 2.5 -> 0.5, c2 0.5 -> 2.5; zennav.learn.pso.IMPROVED)
OPTIMIZERS = ("cg", "pso", "ipso")
METHODS = {"cg": "hybrid_cg", "pso": "pso", "ipso": "ipso"}  # optimizer -> zennav.learn.anfis_torch.TrainConfig.method
# per model: samples a fit (anfis) or the sliding training window (elman) uses, samples before the first fit
WINDOW = {"anfis": 2000, "elman": 500}
MIN_SAMPLES = {"anfis": 100, "elman": 200}
# `zennav replay --compensation` choices -> (model, optimizer)
COMPENSATIONS = {"anfis": ("anfis", "cg"), "anfis-pso": ("anfis", "pso"), "anfis-ipso": ("anfis", "ipso"),
                 "elman": ("elman", "cg")}


@dataclass(frozen=True)
class LearnSettings:
    """Settings of one learner (one target variant). window / min_samples None: the model's default (WINDOW,
    MIN_SAMPLES). retrain_samples: samples between two scheduled fits. n_rules, max_epochs: ANFIS rules (fewer
    while samples are few) and most epochs per fit (one LSE + FR-CG pass, or one swarm iteration); val_patience:
    the epochs are chosen by early stopping on a validation split, val_patience epochs past the best (0:
    max_epochs always; zennav.learn.anfis_torch.select_epochs; the cg optimizer only, not the swarms).
    n_hidden, threshold, free_run_s: the Elman's hidden units, training RMSE (normalised) under which it
    publishes, and period [s of sample time] of its free-running copies (its 1-sigma). max_domain_excess: queries
    further than this many training standard deviations outside the training range are refused. torch_threads:
    torch's threads during a fit (1: the fit is the same, bit for bit, wherever it runs on a CPU; 0: torch's
    default)."""

    model: str = "anfis"
    optimizer: str = "cg"
    window: int | None = None
    min_samples: int | None = None
    retrain_samples: int = 1000
    n_rules: int = 8
    max_epochs: int = 30
    val_patience: int = 3
    n_hidden: int = 12
    threshold: float = 0.8
    free_run_s: float = 30.0
    max_domain_excess: float = 0.5
    seed: int = 0
    torch_threads: int = 1

    def __post_init__(self):
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, not {self.model!r}")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"optimizer must be one of {OPTIMIZERS}, not {self.optimizer!r}")
        if self.window is None:
            object.__setattr__(self, "window", WINDOW[self.model])
        if self.min_samples is None:
            object.__setattr__(self, "min_samples", MIN_SAMPLES[self.model])
        if not 1 <= self.min_samples <= self.window:
            raise ValueError("min_samples must be within 1 .. window")
        if self.retrain_samples < 1:
            raise ValueError("retrain_samples must be >= 1")

    @property
    def method(self) -> str:
        """The ANFIS training method (zennav.learn.anfis_torch.TrainConfig.method)."""
        return METHODS[self.optimizer]

    @property
    def label(self) -> str:
        """anfis-cg, anfis-pso, anfis-ipso or elman."""
        return f"anfis-{self.optimizer}" if self.model == "anfis" else self.model

    def with_(self, **kw) -> LearnSettings:
        """A copy with fields changed; window / min_samples follow a changed model unless given."""
        if "model" in kw:
            kw.setdefault("window", None)
            kw.setdefault("min_samples", None)
        return replace(self, **kw)


def compensation_settings(compensation: str, seed: int = 0) -> LearnSettings:
    """`--compensation` choice (COMPENSATIONS) -> the default settings of that model and optimizer."""
    if compensation not in COMPENSATIONS:
        raise ValueError(f"unknown compensation {compensation!r}; choose from {tuple(COMPENSATIONS)}")
    model, optimizer = COMPENSATIONS[compensation]
    return LearnSettings(model=model, optimizer=optimizer, seed=seed)
