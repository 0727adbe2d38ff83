"""Doppler velocity log (DVL) aiding of an AUV (seed 003 step 1.3): tight per-beam fusion with beam-bias and
scale-factor states (name "dvl"), and a loose fusion of the DVL-frame velocity as the baseline ("dvl_loose").

Measurement model (seed step 1.3; Brokloff 1994; Wang, Xu et al., "A tightly-coupled SINS/DVL integrated navigation
using beam measurements", e.g. Sensors 2018/IEEE Access 2019): the velocity of the DVL point in its frame d is
    v_d = C_db (C_bn v_n + omega_nb_b x l_b)           (zennav.nav.aid.vehicle with C_db, l_b = NavConfig dvl_*)
and beam i (unit vector b_i in d, zennav.nav.beams) measures
    v_beam_i = (1 + k) b_i' (I - [mu x]) v_d + bias_i + noise,      noise ~ N(0, dvl_beam_std_mps^2)
with k the DVL scale-factor error, bias_i the beam's bias and mu (3,) [rad] the mounting misalignment: the small
rotation of the DVL's true frame about its own axes beyond the configured mounting (C_db,true = (I - [mu x]) C_db;
for a DVL mounted along the body axes mu is its roll, pitch and yaw). Augmented states of the engine
(Navigator.add_states "dvl_bias" (4), "dvl_scale" (1), "dvl_mount" (3, only where dvl_mount_std > 0); first-order
Gauss-Markov, NavConfig dvl_bias_* / dvl_scale_* / dvl_mount_*; values estimate minus truth as every error state).
With the vehicle-model Jacobian H_v of v_d (v_d_hat ~ v_d + H_v dx) and u = (I - [mu_hat x]) v_d_hat:
    z_i = (1 + k_hat) b_i' u + bias_hat_i - v_beam_i   (predicted minus observed)
    H_i = [(1 + k_hat) b_i' (I - [mu_hat x]) H_v,  1 in bias_i's column,  b_i' u in k's column,
           (1 + k_hat) b_i' [v_d_hat x] in mu's columns]
((I - [mu x]) v = v + [v x] mu). This is the INS/DVL alignment calibration as filter states: Groves 2013, sections
6.5 and 16.3 (Doppler sonar aiding of an INS, with boresight-misalignment and scale-factor states), and Troni &
Whitcomb 2015 ("Advances in in situ alignment calibration of Doppler and high/low-end attitude sensors for underwater
vehicle navigation", J. Field Robotics 32(5)), whose point is what limits it here too: the yaw and pitch misalignment
are observable against GNSS at the surface and in turns and speed changes (a constant beam bias is the same lateral
velocity error at a constant speed); the roll misalignment only through a lateral or vertical velocity, about zero for
a cruising AUV, so it stays near its prior.
Time offset (dvl_delay_std_s > 0: augmented state "dvl_delay" (1) [s], first-order Gauss-Markov, NavConfig
dvl_delay_*): a DVL sample stamped t measures the velocity of t - tau (processing latency, a residual clock skew).
The predicted beams use the INS velocity interpolated linearly to t - tau between the INS's v_d at the previous DVL
sample (after its update) and now, v_d(t - tau) ~ v_d_hat - tau a_d, a_d = (v_d_hat - v_d_prev) / (t - t_prev)
(a_d = 0 for the first sample or after a gap over DELAY_MAX_GAP_S), so H has -(1 + k_hat) b_i' (I - [mu_hat x]) a_d
in tau's column: the time-offset state of Li & Mourikis 2014 ("Online temporal calibration for camera-IMU
systems", IJRR 33(7)) for a velocity sensor. Observable where the DVL-frame velocity changes (speed changes, the
sideslip and heave of turns); stays at its prior on a straight, steady run.
Tight coupling fuses each VALID beam as its own row: a missing beam is simply left out of H, so three, two (adjacent
or opposite) or even one beam still aid the filter. The partial-beam case of each sample (zennav.nav.beams.beam_case:
4, 3, 2_orthogonal, 2_parallel, 1, 0 valid beams) is counted (dvl_beams_<case>) and flagged in its status record
(faults "beams_<case>" and "valid_<b1 b2 b3 b4>", e.g. valid_1101: the observation and innovation list those beams);
with none valid there is no update ("dvl_beams_0", the INS-predicted beams: no information).
The reconstruction of missing beams (beams.reconstruct_beams: exact from 3 beams; from 2 adjacent ones under the seed's
no-vertical-velocity assumption) is used where the seed needs all four beams: the learning features (``trial``).

Loose (the baseline): the DVL-frame velocity, as the DVL reports it or by least squares from the beams (>= 3 valid, or
2 adjacent with the reconstruction; 2 opposite, 1 or 0: no update), one 3-D measurement z = v_d_hat - v_d, H = H_v,
R = dvl_velocity_std_mps^2 I (reported velocity) or dvl_beam_std_mps^2 (B'B)^-1 (from beams). No DVL states: the loose
baseline is the plain velocity aid (beam biases and the scale factor stay in its error).

Input checks (admit, both): a sample with neither beams nor velocity, a non-finite valid value (dvl_nonfinite), a valid
beam or velocity component faster than dvl_max_beam_mps (dvl_malformed), one not after the last (dvl_out_of_order),
older than dvl_max_age_s behind the IMU time (dvl_stale): rejected, counted and reported, never raised. Not fused in
coarse alignment (dvl_coarse, counted). Gated like GNSS (chi-square on the rows fused); the variational-Bayes R
(zennav.nav.vbkf, NavConfig vb_dvl) per beam (tight) or per axis (loose).

Learned compensation API (seed steps 2.1 and 4-5; the predictor side lives elsewhere): ``DvlTight.trial(nav, sample)``
computes the per-beam features (innovation, Mahalanobis distance lambda, R diagonal: the VB estimate where VB is on,
else the nominal R) of a sample without fusing it or changing the VB state, and ``DvlTight.fuse(nav, sample,
correction)`` fuses it with a per-beam correction [m/s] subtracted from the beams. ``on_input`` is ``fuse`` without a
correction; a subclass that waits for a predictor overrides ``on_input`` to keep the sample (after ``trial``) and calls
``fuse`` when the answer arrives (the model is evaluated at the engine's state of that moment; admit's age check is
at arrival).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..beams import beam_case, beams_from_velocity, janus_directions, reconstruct_beams, velocity_from_beams
from ..rotation import skew
from ..types import NS, AlignState, DvlSample, NavConfig
from ..vbkf import variational_r
from .base import AidSource, Measurement
from .vehicle import VehicleFrame

DELAY_MAX_GAP_S = 2.5  # longest interval between DVL samples over which a_d is differenced [s] (a 1 Hz DVL: 2 misses)


@dataclass
class BeamFeatures:
    """The learning features of one DVL sample (DvlTight.trial), beams 1..4 in rows: case (beams.BEAM_CASES);
    valid (4,) bool; kind per beam: "measured", "reconstructed" or "predicted" (no information: observed = predicted);
    observed, predicted (4,) [m/s]: the (pseudo-)beam and the INS prediction (1 + k) b' v_d + bias; innovation (4,)
    [m/s] predicted minus observed; mahalanobis: lambda = nu' (H P H' + R)^-1 nu of the measured and reconstructed
    beams [-]; R_diag (4,) [(m/s)^2]: the VB estimate (or the nominal R) per beam."""

    t_ns: int
    case: str
    valid: np.ndarray
    kind: tuple
    observed: np.ndarray
    predicted: np.ndarray
    innovation: np.ndarray
    mahalanobis: float
    R_diag: np.ndarray


class _DvlSource(AidSource):
    """What the tight and loose DVL sources share: the geometry, the input checks and the DVL-point velocity."""

    inputs = ("dvl",)

    def __init__(self, name: str, config: NavConfig):
        super().__init__(name, vb=variational_r(config, config.vb_dvl))
        self.config = config
        self.B = janus_directions(config.dvl_tilt, config.dvl_layout)  # beam unit vectors in d (4 x 3)
        self.frame = VehicleFrame(config, config.dvl_mount_euler, config.dvl_lever_b)  # C_db, l_b
        self.max_age_ns = int(round(config.dvl_max_age_s * NS))
        self.last_t_ns = -1

    def beams_of(self, sample: DvlSample) -> tuple[np.ndarray, np.ndarray]:
        """Beam velocities (4,) [m/s] and validity (4,) of a sample; a DVL that reports only v_d gives the beams of
        that velocity (all valid when it is)."""
        if sample.beams is not None:
            valid = (np.isfinite(sample.beams) if sample.beam_valid is None
                     else np.asarray(sample.beam_valid, dtype=bool))
            return np.asarray(sample.beams, dtype=float), valid
        ok = bool(sample.velocity_valid) if sample.velocity_valid is not None else True
        return beams_from_velocity(np.asarray(sample.velocity_d, dtype=float), self.B), np.full(4, ok)

    def admit(self, nav, sample: DvlSample) -> bool:
        t_ns = int(sample.t_ns)
        values: list[float]
        reason, values = "", []
        if sample.beams is None and sample.velocity_d is None:
            reason = "dvl_malformed"
        else:
            beams, valid = self.beams_of(sample)
            values = beams[valid].tolist() if len(beams) == 4 and len(valid) == 4 else []
            if len(beams) != 4 or len(valid) != 4:
                reason = "dvl_malformed"
            elif not all(map(math.isfinite, values)):
                reason = "dvl_nonfinite"
            elif any(abs(x) > self.config.dvl_max_beam_mps for x in values):
                reason = "dvl_malformed"
            elif t_ns <= self.last_t_ns:
                reason = "dvl_out_of_order"
            elif nav.t_ns - t_ns > self.max_age_ns:
                reason = "dvl_stale"
        if reason:
            self.reject(nav, t_ns, reason, f"beams {values}", values, faults=(reason[4:],))
            return False
        self.last_t_ns = t_ns
        return True

    def measured_velocity(self, sample: DvlSample) -> tuple[str, np.ndarray | None, np.ndarray]:
        """(beam case, v_d [m/s] or None, its covariance R [(m/s)^2]): the DVL-frame velocity as the DVL reports it
        or by least squares from the beams (None: 2 opposite, 1 or 0 valid beams; module docstring, Loose)."""
        cfg = self.config
        if sample.velocity_d is not None and sample.beams is None:
            case = "4" if sample.velocity_valid is None or sample.velocity_valid else "0"
            v_meas = np.asarray(sample.velocity_d, dtype=float) if case == "4" else None
            return case, v_meas, np.eye(3) * cfg.dvl_velocity_std_mps**2
        beams, valid = self.beams_of(sample)
        used = valid if valid.sum() >= 3 else np.ones(4, dtype=bool)
        R = cfg.dvl_beam_std_mps**2 * np.linalg.inv(self.B[used].T @ self.B[used])
        return beam_case(valid), velocity_from_beams(beams, valid, self.B), 0.5 * (R + R.T)

    def coarse(self, nav, sample: DvlSample) -> bool:
        """Coarse alignment: nothing fused (counted dvl_coarse); the sample's velocity of the IMU in the body frame,
        v_b = C_bd v_d - omega_ib_b x l_b, goes to the alignment (align_in_motion dvl; the earth and transport rates
        in omega_nb_b are left out: under 1e-4 rad/s). Returns False."""
        nav.counters["dvl_coarse"] += 1
        _, v_d, R = self.measured_velocity(sample)
        if v_d is not None:
            C_bd = self.frame.C_vb.T
            v_b = C_bd @ v_d - np.cross(nav.imu_rates()[0], self.frame.lever_b)
            R_b = C_bd @ R @ C_bd.T
            nav.alignment.on_body_velocity(nav, int(sample.t_ns), v_b, float(max(R_b[0, 0], R_b[1, 1])))
        return False

    def velocity(self, nav) -> tuple[np.ndarray, np.ndarray]:
        """v_d_hat [m/s] of the DVL point and its Jacobian H_v (3 x n_states), at the engine's state (covariance
        propagated to now)."""
        nav.propagate_covariance()
        return self.frame.velocity(nav.state, nav.imu_rates()[0], nav.n_states)

    def count_case(self, nav, case: str) -> None:
        nav.counters[f"dvl_beams_{case}"] += 1

    def no_update(self, nav, t_ns: int, case: str, observation) -> bool:
        """A sample that gives no update from geometry alone: counted (dvl_beams_<case>) and reported."""
        self.report(nav, t_ns, observation, [], [], float("nan"), False, f"dvl_beams_{case}",
                    (f"beams_{case}", "predicted"))
        return False

    def get_state(self) -> dict:
        return {**super().get_state(), "last_t_ns": int(self.last_t_ns)}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.last_t_ns = int(state["last_t_ns"])


class DvlTight(_DvlSource):
    """Per-beam DVL fusion with four beam-bias states, one scale-factor state and (dvl_mount_std > 0) three
    mounting-misalignment states (module docstring); name dvl."""

    def __init__(self, config: NavConfig):
        super().__init__("dvl", config)
        self.R_beam = config.dvl_beam_std_mps**2
        self.bias: slice | None = None  # where the beam biases, the scale factor and the misalignment sit in the
        self.scale: slice | None = None  # error state (attach); mount None: not estimated
        self.mount: slice | None = None
        self.delay: slice | None = None  # the time-offset state (None: not estimated)
        self.prev: tuple[int, np.ndarray] | None = None  # (t_ns, v_d_hat after its update) of the last DVL sample

    def attach(self, nav) -> None:
        cfg = self.config
        self.bias = nav.add_states("dvl_bias", np.full(4, cfg.dvl_bias_std_mps), np.full(4, cfg.dvl_bias_psd),
                                   cfg.dvl_bias_tau_s)
        self.scale = nav.add_states("dvl_scale", np.array([cfg.dvl_scale_std]), np.array([cfg.dvl_scale_psd]),
                                    cfg.dvl_scale_tau_s)
        if cfg.dvl_mount_std > 0.0:
            self.mount = nav.add_states("dvl_mount", np.full(3, cfg.dvl_mount_std), np.full(3, cfg.dvl_mount_psd),
                                        cfg.dvl_mount_tau_s)
        if cfg.dvl_delay_std_s > 0.0:
            self.delay = nav.add_states("dvl_delay", np.array([cfg.dvl_delay_std_s]), np.array([cfg.dvl_delay_psd]),
                                        cfg.dvl_delay_tau_s)

    def rate(self, nav, v_d: np.ndarray) -> np.ndarray:
        """a_d [m/s^2]: the INS's DVL-frame velocity change since the previous DVL sample (module docstring)."""
        if self.prev is None:
            return np.zeros(3)
        dt = (nav.t_ns - self.prev[0]) / NS
        if not 0.0 < dt <= DELAY_MAX_GAP_S:
            return np.zeros(3)
        return (v_d - self.prev[1]) / dt

    def mark(self, nav) -> None:
        """Keep the INS's v_d at this DVL sample (after its update) for the next sample's a_d."""
        if self.delay is not None:
            self.prev = (int(nav.t_ns), self.frame.velocity(nav.state, nav.imu_rates()[0], nav.n_states)[0])

    def model(self, nav) -> tuple[np.ndarray, np.ndarray]:
        """Predicted beams (4,) [m/s] (1 + k_hat) B (I - [mu_hat x]) (v_d_hat - tau_hat a_d) + bias_hat at the
        engine's state, and their Jacobian H (4 x n_states)."""
        assert self.bias is not None and self.scale is not None  # attached by Navigator.add_source
        v_d, H_v = self.velocity(nav)
        a_d = None
        if self.delay is not None:
            a_d = self.rate(nav, v_d)
            v_d = v_d - float(nav.aug_value(self.delay)[0]) * a_d
        k = float(nav.aug_value(self.scale)[0])
        bias = nav.aug_value(self.bias)
        if self.mount is None:
            B = self.B
        else:
            B = self.B @ (np.eye(3) - skew(nav.aug_value(self.mount)))  # beams of the misaligned frame, in d
        Bv = B @ v_d
        H = (1.0 + k) * (B @ H_v)
        H[:, self.bias] = np.eye(4)
        H[:, self.scale] = Bv[:, None]
        if self.mount is not None:
            H[:, self.mount] = (1.0 + k) * (self.B @ skew(v_d))
        if a_d is not None:
            H[:, self.delay] = -(1.0 + k) * (B @ a_d)[:, None]
        return (1.0 + k) * Bv + bias, H

    def on_input(self, nav, sample: DvlSample) -> bool:
        return self.fuse(nav, sample)

    def fuse(self, nav, sample: DvlSample, correction=None) -> bool:
        """Fuse the sample's valid beams, correction (4,) [m/s] (None: none) subtracted from them and its square
        added to their noise variance (the learned correction is not exact: its size bounds its error); returns
        whether it was fused."""
        if nav.align_state == AlignState.COARSE:
            return self.coarse(nav, sample)
        beams, valid = self.beams_of(sample)
        R_diag = np.full(4, self.R_beam)
        if correction is not None:
            correction = np.asarray(correction, dtype=float)
            beams = beams - correction
            R_diag = R_diag + correction**2  # the model's uncertainty: a compensated beam is as uncertain as its fix
        case = beam_case(valid)
        self.count_case(nav, case)
        if not valid.any():
            fused = self.no_update(nav, int(sample.t_ns), case, [])
        else:
            predicted, H = self.model(nav)
            rows = np.flatnonzero(valid)
            z = predicted[rows] - beams[rows]
            R = np.diag(R_diag[rows])
            faults = (f"beams_{case}", "valid_" + "".join("1" if v else "0" for v in valid)) + (
                ("corrected",) if correction is not None else ())
            fused = nav.update(self, Measurement(int(sample.t_ns), beams[rows], z, H[rows], R, faults=faults,
                                                 channels=tuple(int(r) for r in rows)))
        self.mark(nav)
        return fused

    def trial(self, nav, sample: DvlSample) -> BeamFeatures | None:
        """The sample's learning features (BeamFeatures) at the engine's state, nothing fused and the VB state
        unchanged (the covariance is propagated to now, as a fuse would); None in coarse alignment."""
        if nav.align_state == AlignState.COARSE:
            return None
        beams, valid = self.beams_of(sample)
        case = beam_case(valid)
        predicted, H = self.model(nav)
        full = reconstruct_beams(beams, valid)
        if full is None:
            observed = np.where(valid, beams, predicted)
            kind = tuple("measured" if v else "predicted" for v in valid)
        else:
            observed = full
            kind = tuple("measured" if v else "reconstructed" for v in valid)
        informed = np.array([k != "predicted" for k in kind])
        nu = predicted - observed
        R_diag = np.full(4, self.R_beam)
        lam = 0.0
        rows = np.flatnonzero(informed)
        if len(rows):
            Hr = H[rows]
            HPHt = Hr @ nav.P @ Hr.T
            R = np.eye(len(rows)) * self.R_beam
            if self.vb is not None:
                R = self.vb.solve(nu[rows], HPHt, R, tuple(int(r) for r in rows)).R
            R_diag[rows] = np.diag(R)
            S = HPHt + R
            lam = float(nu[rows] @ np.linalg.solve(S, nu[rows]))
        if self.vb is not None:
            for r in np.flatnonzero(~informed):
                R_diag[r] = self.R_beam * self.vb.ratio(int(r))
        return BeamFeatures(int(sample.t_ns), case, valid.copy(), kind, observed, predicted,
                            np.where(informed, nu, 0.0), lam, R_diag)

    def get_state(self) -> dict:
        prev = None if self.prev is None else {"t_ns": self.prev[0], "v_d": self.prev[1].tolist()}
        return {**super().get_state(), "prev": prev}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        prev = state.get("prev")
        self.prev = None if prev is None else (int(prev["t_ns"]), np.array(prev["v_d"], dtype=float))


class DvlLoose(_DvlSource):
    """DVL-frame velocity fusion without DVL states (module docstring); name dvl_loose."""

    def __init__(self, config: NavConfig):
        super().__init__("dvl_loose", config)

    def on_input(self, nav, sample: DvlSample) -> bool:
        if nav.align_state == AlignState.COARSE:
            return self.coarse(nav, sample)
        case, v_meas, R = self.measured_velocity(sample)
        self.count_case(nav, case)
        if v_meas is None:
            return self.no_update(nav, int(sample.t_ns), case, [])
        v_d, H_v = self.velocity(nav)
        return nav.update(self, Measurement(int(sample.t_ns), v_meas, v_d - v_meas, H_v, R, faults=(f"beams_{case}",)))


def dvl_source(config: NavConfig) -> AidSource | None:
    """The configured DVL source (dvl_mode tight / loose), None when off or when the data has no DVL."""
    if not config.has_dvl or config.dvl_mode == "off":
        return None
    if config.dvl_mode not in ("loose", "tight"):
        raise ValueError(f"dvl_mode {config.dvl_mode!r}: accepted off, loose, tight")
    return DvlTight(config) if config.dvl_mode == "tight" else DvlLoose(config)
