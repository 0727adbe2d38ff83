"""The tight DVL source with learned beam-error compensation (seed 003 steps 2, 4 and 5): one implementation for the
ins service (answers over the bus, zennav.learn.link) and the in-process loop of ``zennav replay --target dvl_beam
--compensation ...`` (zennav.learn.loop); both hand the predictor's answers to Navigator.on_correction and its
refusals to Navigator.on_refusal.

At the surface (GNSS valid, learning started): each DVL sample's features (DvlTight.trial: innovation_i, lambda, VB
R_ii) become one training sample per measured beam (zennav.nav.learning "dvl_beam") with the beam's error as the
target: the measured beam minus the beam the filter predicts before this sample is fused, (1 + k_hat) b_i' (I -
[mu_hat x]) v_d_hat + bias_hat_i, i.e. minus the beam's innovation. The seed takes the reference from a PHINS aided by
GPS; here the GNSS-aided filter is the reference, and its calibration states (beam biases, scale factor, mounting)
are part of it: the model learns only the error those states do not model, so that the compensation under water
(subtracted from a beam that fuse again predicts with the same states) does not correct their part twice. While
GNSS holds the INS velocity, that target is the beam's own error; the model maps the innovation-side features to it.
The sample is then fused as measured.

Under water (GNSS lost): the sample is held, one query per measured beam goes out (one model for the four beams, the
seed's three inputs; the queries carry the beam index); when every queried beam is answered or refused, or when
dvl_answer_timeout_s of data time passed since the sample (checked after every IMU sample), the anomaly
discrimination (zennav.nav.dvl_anomaly) decides per beam and the sample is fused with the compensated beams
(DvlTight.fuse evaluates the model at the engine's state of that moment). A new sample releases a held one first.
Decisions are counted (dvl_learned_<decision>: compensated, normal, no_answer, refused, invalid) and carried in the
status record of the fused sample (faults "learned_<decision>_<beam 1-4>").
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..dvl_anomaly import N_BEAMS, AnomalyRule, BeamDiscriminator
from ..learning import LearnQuery, LearnSample
from ..types import NS, DvlSample, NavConfig
from .base import AidSource
from .dvl import BeamFeatures, DvlTight

TARGET = "dvl_beam"


@dataclass
class _Held:
    """A DVL sample waiting for the predicted errors of its queried beams."""

    sample: DvlSample
    features: BeamFeatures
    queried: np.ndarray  # (4,) bool
    deadline_ns: int
    predicted: np.ndarray = field(default_factory=lambda: np.full(N_BEAMS, np.nan))
    state: list = field(default_factory=lambda: ["no_answer"] * N_BEAMS)  # per beam: answered / refused / no_answer


class LearnedDvl(DvlTight):
    """DvlTight (name "dvl") that learns its beam errors at the surface and compensates anomalous beams under water
    (module docstring)."""

    def __init__(self, config: NavConfig):
        super().__init__(config)
        self.timeout_ns = int(round(config.dvl_answer_timeout_s * NS))
        self.discriminator = BeamDiscriminator(AnomalyRule.of(config))
        self.held: _Held | None = None
        self._faults: tuple = ()  # the decisions, for the status record of the sample being fused

    def on_input(self, nav, sample: DvlSample) -> bool:
        if self.held is not None:
            self.release(nav)
        features = self.trial(nav, sample)
        if features is None:  # coarse alignment: fuse counts it
            return self.fuse(nav, sample)
        under_water = nav.gnss_state != "valid"
        if nav.tap is None or not under_water:
            if nav.tap is not None and nav.learning_started(int(sample.t_ns)):
                self._samples(nav, features)
            return self.fuse(nav, sample)
        measured = np.array([k == "measured" for k in features.kind])
        if not measured.any():
            return self.fuse(nav, sample)
        self.held = _Held(sample, features, measured, int(sample.t_ns) + self.timeout_ns)
        for i in np.flatnonzero(measured).tolist():
            nav.tap.queries.append(LearnQuery(int(sample.t_ns), TARGET, _features(features, i), 0.0, int(i)))
        return False

    def _samples(self, nav, f: BeamFeatures) -> None:
        """One training sample per measured beam: features and the beam's error against the filter's predicted beam
        (its calibration states included: module docstring)."""
        error = f.observed - f.predicted
        for i in np.flatnonzero(np.array([k == "measured" for k in f.kind])).tolist():
            nav.tap.samples.append(LearnSample(int(f.t_ns), TARGET, _features(f, i), np.array([error[i]])))

    def answer(self, nav, query: LearnQuery, value, std) -> bool:
        """The predicted error [m/s] of a held beam (Navigator.on_correction through DvlAnswers); releases the sample
        once every queried beam is settled; returns whether the sample was fused now."""
        return self._settle(nav, query, "answered", value)

    def refused(self, nav, query: LearnQuery, reason: str) -> bool:
        """The predictor refused a held beam's query (reason kept in its counters)."""
        return self._settle(nav, query, "refused", None)

    def _settle(self, nav, query: LearnQuery, how: str, value) -> bool:
        h = self.held
        if h is None or query.t_ns != int(h.sample.t_ns) or not 0 <= query.beam < N_BEAMS or not h.queried[query.beam]:
            nav.counters["dvl_learned_unmatched"] += 1
            return False
        if how == "answered":
            v = np.asarray(value, dtype=float).ravel()
            if v.shape != (1,) or not np.isfinite(v[0]):
                nav.count_rejection("correction_malformed", query.t_ns, "")
                how = "refused"
            else:
                h.predicted[query.beam] = v[0]
        h.state[query.beam] = how
        if all(h.state[i] != "no_answer" for i in np.flatnonzero(h.queried)):
            return self.release(nav)
        return False

    def on_step(self, nav) -> None:
        if self.held is not None and nav.t_ns > self.held.deadline_ns:
            self.release(nav)

    def release(self, nav) -> bool:
        """Decide per beam (zennav.nav.dvl_anomaly) and fuse the held sample; returns whether it was fused."""
        h, self.held = self.held, None
        assert h is not None  # called only with a held sample
        f = h.features
        answered = np.array([s == "answered" for s in h.state])
        missing = tuple("refused" if s == "refused" else "no_answer" for s in h.state)
        corrections, decisions = self.discriminator.decide(h.predicted, answered, h.queried, f.mahalanobis,
                                                           f.R_diag, int(h.queried.sum()), missing)
        for d in decisions:
            nav.counters[f"dvl_learned_{d}"] += 1
        self._faults = tuple(f"learned_{d}_{i + 1}" for i, d in enumerate(decisions))
        try:
            return self.fuse(nav, h.sample, corrections if np.any(corrections) else None)
        finally:
            self._faults = ()

    def report(self, nav, t_ns: int, observation, innovation, innovation_var, test_ratio: float, fused: bool,
               reason: str = "", faults=()) -> None:
        super().report(nav, t_ns, observation, innovation, innovation_var, test_ratio, fused, reason,
                       tuple(faults) + self._faults)

    def status(self) -> dict:
        return {**super().status(), "learned": dict(self.discriminator.counts)}

    def get_state(self) -> dict:
        h = self.held
        held = None if h is None else {
            "t_ns": int(h.sample.t_ns), "beams": None if h.sample.beams is None else h.sample.beams.tolist(),
            "beam_valid": None if h.sample.beam_valid is None else h.sample.beam_valid.tolist(),
            "velocity_d": None if h.sample.velocity_d is None else h.sample.velocity_d.tolist(),
            "velocity_valid": h.sample.velocity_valid,
            "features": {"case": h.features.case, "valid": h.features.valid.tolist(), "kind": list(h.features.kind),
                         **{k: getattr(h.features, k).tolist() for k in ("observed", "predicted", "innovation",
                                                                          "R_diag")},
                         "mahalanobis": float(h.features.mahalanobis)},
            "queried": h.queried.tolist(), "deadline_ns": int(h.deadline_ns), "predicted_error": h.predicted.tolist(),
            "state": list(h.state)}
        return {**super().get_state(), "held": held, "discriminator": self.discriminator.get_state()}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.discriminator.set_state(state["discriminator"])
        st = state["held"]
        if st is None:
            self.held = None
            return

        def arr(v, dtype=float):
            return None if v is None else np.array(v, dtype=dtype)

        sample = DvlSample(int(st["t_ns"]), arr(st["beams"]), arr(st["beam_valid"], bool), arr(st["velocity_d"]),
                           st["velocity_valid"])
        fs = st["features"]
        features = BeamFeatures(int(st["t_ns"]), fs["case"], np.array(fs["valid"], dtype=bool), tuple(fs["kind"]),
                                arr(fs["observed"]), arr(fs["predicted"]), arr(fs["innovation"]),
                                float(fs["mahalanobis"]), arr(fs["R_diag"]))
        self.held = _Held(sample, features, np.array(st["queried"], dtype=bool), int(st["deadline_ns"]),
                          arr(st["predicted_error"]), list(st["state"]))


class DvlAnswers(AidSource):
    """The learned source of the "dvl_beam" target (name learned_dvl_beam): hands the predictor's answers and
    refusals to the LearnedDvl source holding their sample; fuses nothing itself."""

    def __init__(self, dvl: LearnedDvl):
        super().__init__(f"learned_{TARGET}")
        self.dvl = dvl

    def on_input(self, nav, answer: tuple[LearnQuery, object, object]) -> bool:
        query, value, std = answer
        return self.dvl.answer(nav, query, value, std)

    def on_refusal(self, nav, query: LearnQuery, reason: str) -> None:
        self.dvl.refused(nav, query, reason)

    def status(self) -> dict:
        return {"learned": dict(self.dvl.discriminator.counts)}


def _features(f: BeamFeatures, i: int) -> np.ndarray:
    """The seed's three features of beam i: innovation [m/s], lambda [-], VB R_ii [(m/s)^2]."""
    return np.array([f.innovation[i], f.mahalanobis, f.R_diag[i]])
