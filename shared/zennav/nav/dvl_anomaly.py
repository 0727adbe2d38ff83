"""Anomaly discrimination of DVL beams from their learned predicted errors (seed 003, step 5). numpy only.

Under water the predictor answers each beam's predicted error e_i [m/s] (zennav.nav.learning "dvl_beam"). The
seed compensates a beam "selectively": only when the features of the prediction say the measurement is
anomalous; a clean beam is fused as measured, so that a model's small errors (and the INS velocity error the
innovation feature carries under water) do not leak into a good measurement. The rule, per beam i at a DVL
sample with innovation Mahalanobis distance lambda_k = v' S^-1 v over its m used beams and VB estimate R_ii:

  large_i     = |e_i| > k_sigma * sqrt(R_ii)                 the predicted error stands out of the beam's noise
  anomalous_i = large_i and (lambda_k > chi2_p(m)             the innovation as a whole fails the chi-square test
                             or count(large_i over the beam's last `window` samples) >= min_count)
                                                              or the predicted error persists (a bias jump that
                                                              the VB R has partly absorbed, lowering lambda)

Compensated beam: measured - e_i. Thresholds in NavConfig (dvl_anomaly_*; deploy/ins.yaml, learning section).
Decisions: "compensated", "normal" (answered, not anomalous), "no_answer" (no answer within the hold time),
"refused" (the predictor refused the beam's query: no model, off its domain, ...), "invalid" (the beam was not
valid in the sample, or not queried). Chi-square test: Mahalanobis
1936; its use for fault detection in Kalman filters: R. K. Mehra, J. Peschon, Automatica 7 (1971) 637-640.
"""
from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from .eskf import chi2_quantile

N_BEAMS = 4
DECISIONS = ("compensated", "normal", "no_answer", "refused", "invalid")


@dataclass(frozen=True)
class AnomalyRule:
    """The rule's thresholds (module docstring): k_sigma, chi-square probability p, persistence window and count."""

    k_sigma: float = 3.0
    probability: float = 0.99
    window: int = 5
    min_count: int = 3

    def __post_init__(self):
        if not (self.k_sigma > 0 and 0 < self.probability < 1 and 1 <= self.min_count <= self.window):
            raise ValueError("anomaly rule: k_sigma > 0, 0 < probability < 1, 1 <= min_count <= window")

    @classmethod
    def of(cls, config) -> AnomalyRule:
        """From NavConfig's dvl_anomaly_* fields."""
        return cls(config.dvl_anomaly_k_sigma, config.dvl_anomaly_probability, config.dvl_anomaly_window,
                   config.dvl_anomaly_min_count)


class BeamDiscriminator:
    """The rule's per-beam memory and its decision counts (``counts``: decision -> beams)."""

    def __init__(self, rule: AnomalyRule = AnomalyRule()):
        self.rule = rule
        # large_i flags of each beam's answered samples
        self.recent: list[deque[bool]] = [deque(maxlen=rule.window) for _ in range(N_BEAMS)]
        self.counts: Counter[str] = Counter()
        self._chi2: dict[int, float] = {}

    def decide(self, predicted, answered, valid, lam: float, R_diag, n_used: int,
               missing=("no_answer",) * N_BEAMS) -> tuple[np.ndarray, list[str]]:
        """Corrections [m/s] (4,) to subtract from the measured beams and the decision per beam.

        predicted: (4,) predicted errors [m/s] (ignored where not answered); answered, valid: (4,) bool;
        lam: lambda_k of the sample; R_diag: (4,) VB R_ii [(m/s)^2]; n_used: beams in the innovation (chi2 dof);
        missing: the decision of a valid beam without an answer ("no_answer" or "refused")."""
        predicted, R_diag = np.asarray(predicted, dtype=float), np.asarray(R_diag, dtype=float)
        r = self.rule
        dof = max(int(n_used), 1)
        if dof not in self._chi2:
            self._chi2[dof] = chi2_quantile(r.probability, dof)
        chi2_fail = lam > self._chi2[dof]
        corrections, decisions = np.zeros(N_BEAMS), []
        for i in range(N_BEAMS):
            if not valid[i]:
                decisions.append("invalid")
            elif not answered[i] or not (np.isfinite(predicted[i]) and np.isfinite(R_diag[i]) and R_diag[i] > 0):
                decisions.append(missing[i])
            else:
                large = abs(predicted[i]) > r.k_sigma * float(np.sqrt(R_diag[i]))
                self.recent[i].append(large)
                if large and (chi2_fail or sum(self.recent[i]) >= r.min_count):
                    corrections[i] = predicted[i]
                    decisions.append("compensated")
                else:
                    decisions.append("normal")
        self.counts.update(decisions)
        return corrections, decisions

    def get_state(self) -> dict:
        return {"recent": [[bool(x) for x in d] for d in self.recent], "counts": dict(self.counts)}

    def set_state(self, st: dict) -> None:
        self.recent = [deque((bool(x) for x in d), maxlen=self.rule.window) for d in st["recent"]]
        self.counts = Counter({str(k): int(v) for k, v in st["counts"].items()})
