"""Learned aiding sources, one per target variant of zennav.nav.learning: a compensator's answer to one of the
engine's queries, fused as a pseudo-measurement and gated like GNSS.

- "position" / "velocity": N and E error rates [m/s, m/s^2] accrued over the query's interval dt_s;
- "drift": N and E error of the free-running INS since the last fix [m], fused into the position alone (a Schmidt
  update: velocity, attitude and biases stay as they are, as in the shadow INSs the model learned from); the
  position shift it applies is kept by the learning tap until the next fix;
- "body_velocity": the velocity in the body frame [m/s, FRD] (zennav.nav.aiding.body_velocity_model); with the
  non-holonomic constraint on and NavConfig.learn_forward_only, its forward output alone (a learned odometer: the
  constraint already gives the lateral and vertical velocity, and fusing the learned ones as well would count that
  information twice). On the rtklibexplorer drive (these figures with the constraint's noise taken as white,
  nhc_corr_s 0) it does not help: the NHC+ZUPT drift is mostly along-track (a
  forward-speed error of at most about 1.2-1.7 m/s RMS over a window), while the learned forward speed is off by
  2.5-5 m/s RMS on the held-out windows (benchmarks/constraints.py --forward-only). With
  NavConfig.learn_where_better, an output is fused only where the answer's 1-sigma is below the filter's own 1-sigma
  of it (sqrt of H P H^T): a model that claims to know less than the filter already knows adds almost nothing when
  its errors are white, and harms when they are not (its forward speed is off by a bias that holds through an
  outage, by 0.6-2.6 m/s per 60 s window on the rtklibexplorer drive, which the AR(1) inflation of
  zennav.learn.sigma does not cover);
  an answer with no such output is counted learned_body_velocity_weak. Measured there (seed 0, benchmarks/
  constraints.py --where-better): the learned rows equal NHC+ZUPT within 0.1 m at 10, 30 and 60 s windows: no
  longer worse at 30 and 60 s, and the gain of the plain fusion at 10 s is gone.
  The rule has three modes (learn_where_better): on, off and nhc, the default: on under the non-holonomic
  constraint alone, where the constrained filter's own body velocity is the answer to beat (its lateral and
  vertical outputs held by the constraint).
  There a learned answer's error holds through an outage (the ANFIS's outputs without held-out skill are the
  target's mean, the same value whatever the features: its error is the vehicle's deviation from its mean speed),
  so its answers, each weaker than the filter, add up to a confident wrong pull; without the constraint the
  filter's own lateral and vertical velocity drift freely and the many weaker answers are what holds them.
  Measured with the rules below as they stand (benchmarks/constraints.py --where-better on, learned rows on NHC +
  ZUPT, median of seeds 0-2, RMS of the per-window maximum; off -> nhc): 10 s windows, ANFIS 1.17 -> 1.17 m and
  Elman 1.18 -> 1.19 m (NHC + ZUPT 1.22 m); 30 s, ANFIS 8.06 -> 6.90 m and Elman 6.72 -> 7.07 m (7.14 m); 60 s,
  ANFIS 19.11 -> 17.01 m and Elman 20.56 -> 15.18 m (25.96 m): both lower than NHC + ZUPT at the three lengths,
  Elman 0.35 m higher than without the rule at 30 s. The ANFIS's 30 s loss was one window (the fourth: 14.51 m
  with NHC + ZUPT, 17.25 m with its answers, all three outputs its mean; seed 0, fusing all but the forward
  output 15.61 m, all but the vertical 15.75 m, where better 14.51 m). On sim:car without constraints (600 s,
  30 s outages every 120 s) mode on would raise the sum of the outage maxima from 12.30 to 15.91 m (ANFIS) and
  14.12 to 15.89 m (Elman): mode nhc leaves it as it was.
  Two rules for its error model (each a NavConfig switch):
  * held error (learn_held_fraction f > 0): the answer's error is e = b + w, b a bias held through the outage and w
    white, with variances f std^2 and (1 - f) std^2 of the answered 1-sigma std. b is an augmented random-constant
    state per output (Navigator.add_states "learned_bias"; the augmented-state treatment of coloured
    measurement noise, Bryson and Henrikson, J. Spacecraft and Rockets 5(6), 1968; Gelb, "Applied Optimal
    Estimation", 1974), restarted (0, 1-sigma sqrt(f) std, uncorrelated) at the first answer after a fused GNSS
    fix: a model's error in one outage says nothing of the next. The answers of one outage then cannot shrink the
    error below the held part however many there are (N independent answers would shrink it by sqrt(N)), and the
    first answers, while the INS velocity is still good, estimate b.
  * under the non-holonomic constraint (learn_nhc_floor): the lateral and vertical outputs answer the quantity the
    constraint fixes at zero; their 1-sigma is floored at the constraint's own, for one update per answer period
    (zennav.nav.aid.base.correlated_variance of nhc_std_mps over BODY_EVERY_S with nhc_corr_s), so that a model
    that claims to know the sideslip better than the constraint does not override it (its lateral output was
    seen overconfident, (error / sigma)^2 of 2.4-27 on the rtklibexplorer drive).
  Measured there with both (f 0.5) on NHC + ZUPT with the constraint's correlated noise (benchmarks/constraints.py
  --held-fraction 0.5 --nhc-floor; RMS of the per-window maximum drift, median of seeds 0-2): 30 s windows,
  ANFIS 9.42 m and Elman 7.87 m against 7.14 m without learning; 60 s, 24.05 and 26.59 m against 25.96 m. ANFIS
  seed 0 at 30 s: 10.26 m without the two rules, 7.53 m with them. The learned forward speed stays 3.3-6.2 m/s RMS
  off (its answers against the truth); neither rule makes the learned rows lower at 30 s, so both stay off.
  A third rule, consistency with the constrained filter (learn_consistency): each output's R is estimated from its own
    innovations against the filter (predicted minus answered, over the answers of the outages: answers are fused
    only without GNSS) by the engine's adaptive-R estimator (zennav.nav.adaptive_r, one of dimension 1 per output:
    the innovation-based covariance matching of Mehra 1972 and Mohamed and Schwarz 1999, the Sage-Husa fading
    memory, with adaptive_forgetting, adaptive_test_probability, adaptive_ceiling and learn_consistency_window
    innovations), floored at the answered variance: an output whose innovations stay larger than H P H' + R
    predicts (the learned source inconsistent with the filter that NHC and ZUPT hold) is down-weighted, one that
    agrees keeps its answered 1-sigma; counted learned_body_velocity_deweighted. The same innovation test the
    engine applies to GNSS (adaptive_r), here per output, so that a bad forward speed does not take the lateral
    output's weight with it. Measured there with the two rules above (benchmarks/constraints.py --held-fraction 0.5
    --nhc-floor --consistency; median of seeds 0-2, RMS of the per-window maximum, without -> with it): 10 s
    windows, ANFIS 1.35 -> 1.27 m and Elman 1.19 -> 1.19 m (NHC + ZUPT 1.22 m); 30 s, ANFIS 9.42 -> 7.73 m and
    Elman 7.87 -> 6.74 m (7.14 m); 60 s, ANFIS 24.05 -> 23.16 m and Elman 26.59 -> 18.37 m (25.96 m): Elman lower
    than NHC + ZUPT at all three, ANFIS at 60 s only. Alone (--consistency): 10 s, ANFIS 1.31 m,
    Elman 1.21 m; 30 s, 7.32 and 7.07 m; 60 s, 20.84 and 21.71 m. The
    forward answers stay 2.3-8 m/s RMS off the truth (ANFIS seed 0 in the worst 30 s window: answered 1-sigma
    9.1 m/s, the filter's own forward speed 2.2 m/s off at its end), so they weigh little there; at 10 and 30 s
    the differences are within the spread of the seeds (30 s: ANFIS 7.21-8.52 m, Elman 6.42-7.20 m), at 60 s
    Elman's is not (15.41-18.69 m). The first two stay off by default; the consistency rule is on (NavConfig,
    deploy/ins.yaml): its figures alone are above, and on sim:car (600 s, 30 s outages every 120 s) it takes
    the sum of the four outage maxima from 12.18 to 10.30 m (Elman) and from 7.97 to 7.72 m (ANFIS).
  The ANFIS answers an output with no held-out skill over the target's mean by that mean, with the mean's held-out
  1-sigma (zennav.learn.anfis_torch.fit_anfis_sigma): on the rtklibexplorer drive its fits mostly have no skill on
  any output (the learned forward speed 2.3-8 m/s off is then the training mean speed, its 1-sigma that of the mean),
  and its rows become 1.17, 8.06 and 19.11 m at 10, 30 and 60 s (before: 1.31, 9.30 and 22.74 m; README).

An answer is fused only if no GNSS position fix was fused after its query's time (else learned_stale: the filter
already knows better) and the query is at most NavConfig.learn_answer_max_age_s of data time old (else
learned_late); a wrong-size or non-finite answer is correction_malformed. Each is counted; stale and late are
reported.
"""
from __future__ import annotations

import math

import numpy as np

from ..adaptive_r import AdaptiveR
from ..aiding import body_velocity_model
from ..eskf import N_STATES, POS
from ..learning import BODY_EVERY_S, OUTPUTS, LearnQuery
from ..types import NS, NavConfig
from .base import AidSource, Measurement, correlated_variance


class LearnedSource(AidSource):
    """The learned pseudo-measurement of one target variant (see the module docstring); name learned_<target>."""

    inputs = ()  # Navigator.on_correction hands each answer to the source of its query's target

    def __init__(self, config: NavConfig, target: str):
        super().__init__(f"learned_{target}")
        self.target = target
        self.max_age_ns = int(config.learn_answer_max_age_s * NS)
        # rows of the body-velocity answer that are fused (FRD)
        self.body_rows = [0] if config.nhc and config.learn_forward_only else [0, 1, 2]
        self.where_better = config.learn_where_better == "on" or (config.learn_where_better == "nhc" and config.nhc)
        body = target == "body_velocity"
        self.held = config.learn_held_fraction if body else 0.0
        self.bias: slice | None = None  # the held-error states (attach), FRD
        self.bias_fix_ns = -1  # the last fused GNSS fix time when the held-error states were restarted
        # floor of the lateral and vertical 1-sigma [m/s] under the non-holonomic constraint (0: none)
        self.nhc_floor = (math.sqrt(correlated_variance(config.nhc_std_mps, BODY_EVERY_S, config.nhc_corr_s))
                          if body and config.nhc and config.learn_nhc_floor else 0.0)
        # the consistency rule (learn_consistency): one adaptive-R estimator per output, FRD
        self.matching = ([AdaptiveR(1, config.learn_consistency_window, config.adaptive_forgetting,
                                    config.adaptive_test_probability, 1.0, config.adaptive_ceiling)
                          for _ in range(3)] if body and config.learn_consistency else None)

    def attach(self, nav) -> None:
        if self.held > 0.0:
            self.bias = nav.add_states("learned_bias", np.zeros(3), np.zeros(3), math.inf)

    def on_input(self, nav, answer: tuple[LearnQuery, object, object]) -> bool:
        """answer: (query, value, std) with value and its 1-sigma std in the units of the target."""
        query, value, std = answer
        value, std = np.asarray(value, dtype=float), np.asarray(std, dtype=float)
        shape = (len(OUTPUTS[self.target]),)
        if value.shape != shape or std.shape != shape or not (np.all(np.isfinite(value)) and np.all(std > 0)):
            nav.count_rejection("correction_malformed", query.t_ns, "")
            return False
        if nav.last_fused_t_ns > query.t_ns:
            self.reject(nav, query.t_ns, "learned_stale", "a GNSS fix was fused after the query", value.tolist(),
                        faults=("stale",))
            return False
        if nav.t_ns - query.t_ns > self.max_age_ns:
            self.reject(nav, query.t_ns, "learned_late", f"query {(nav.t_ns - query.t_ns) / NS:.3f} s old",
                        value.tolist(), faults=("late",))
            return False
        nav.propagate_covariance()
        if self.target == "body_velocity":
            return self._body_velocity(nav, query, value, std)
        H = np.zeros((2, N_STATES))
        first = 3 if self.target == "velocity" else 0
        H[0, first], H[1, first + 1] = 1.0, 1.0
        if self.target == "drift":
            fused = nav.update(self, Measurement(query.t_ns, value, value - nav.tap.shift_ne, H,
                                                np.diag(np.square(std)), gain_states=POS))
            if fused:
                nav.tap.shift_ne += nav.last_dx[0:2]
            return fused
        return nav.update(self, Measurement(query.t_ns, value, value * query.dt_s, H,
                                            np.diag(np.square(std * query.dt_s))))

    def _body_velocity(self, nav, query: LearnQuery, value: np.ndarray, std: np.ndarray) -> bool:
        """Fuse a body-velocity answer with the rules of the module docstring (held error, NHC floor)."""
        z, H = body_velocity_model(nav.state, value)
        if self.nhc_floor > 0.0:
            std = std.copy()
            std[1:3] = np.maximum(std[1:3], self.nhc_floor)
        var = np.square(std)
        if self.bias is not None:
            if nav.last_fused_t_ns != self.bias_fix_ns:  # the first answer of an outage: a new draw of the bias
                self.bias_fix_ns = nav.last_fused_t_ns
                nav.reset_states(self.bias, np.sqrt(self.held * var))
            H = np.hstack([H, np.zeros((3, nav.n_states - N_STATES))])
            H[:, self.bias] = np.eye(3)
            z = z + nav.aug_value(self.bias)
            var = (1.0 - self.held) * var
        rows = self.body_rows
        if self.where_better:
            P = nav.kf.P[:N_STATES, :N_STATES]
            rows = [r for r in rows if std[r] ** 2 < float(H[r, :N_STATES] @ P @ H[r, :N_STATES])]
            if not rows:
                nav.counters[f"{self.name}_weak"] += 1
                return False
        R = np.diag(var[rows])
        if self.matching is not None:
            R = self._matched(nav, self.matching, z, H, var, rows)
        return nav.update(self, Measurement(query.t_ns, value, z[rows], H[rows], R))

    def _matched(self, nav, matching: list[AdaptiveR], z: np.ndarray, H: np.ndarray, var: np.ndarray,
                 rows: list[int]) -> np.ndarray:
        """The diagonal R [(m/s)^2] of the fused rows from their adaptive-R estimators matching (one per output; the
        consistency rule of the module docstring): each row's innovation z [m/s] against H P H' and its answered
        variance var; counted {name}_deweighted when a row's R is above the answered one."""
        k = H.shape[1]  # a model of the first k states (the engine pads it with zeros, see Navigator.update)
        HPHt = H @ nav.P[:k, :k] @ H.T
        R = np.array([matching[r].update(z[r:r + 1], HPHt[r:r + 1, r:r + 1], np.array([[var[r]]]))[0, 0]
                      for r in rows])
        if np.any(R > var[rows] * (1.0 + 1e-9)):
            nav.counters[f"{self.name}_deweighted"] += 1
        return np.diag(R)

    def get_state(self) -> dict:
        return {**super().get_state(), "bias_fix_ns": int(self.bias_fix_ns),
                **({} if self.matching is None else {"matching": [m.get_state() for m in self.matching]})}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.bias_fix_ns = int(state["bias_fix_ns"])
        if self.matching is not None:
            for m, st in zip(self.matching, state["matching"]):
                m.set_state(st)
