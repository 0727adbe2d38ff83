"""GNSS aiding sources: the antenna position (input quality gates, jump test, gate-trap / reacquire recovery,
outage declaration and recovery; during coarse alignment it hands the fix to the alignment) and the antenna
velocity. Models in zennav.nav.aiding; the fix is fused at its own time (the engine splits the IMU interval).

Faults, each rejection counted under its reason and reported:
- initial state (init_state_reset_pos_vel, init_state_rejected): while a configured initial state is under test
  (its first fixes, and its first fixes after a velocity change), each fix is first tested against it
  (zennav.nav.alignment, Alignment.check_initial); two contradicting fixes in a row reset position and velocity
  from the second one (which is then not fused) or, once the state was consistent, send the engine back to coarse
  alignment, the second one tracked;
- input: gnss_malformed, gnss_duplicate, gnss_out_of_order, gnss_fix_quality, gnss_few_satellites, gnss_std,
  gnss_stale (older than MAX_FIX_AGE_S behind the IMU);
- jump (gnss_pos_jump): further than max_jump_m horizontally from the INS prediction and outside the chi-square
  gate of the horizontal innovation with the reported R (not the adapted one, so that an inflated R cannot let
  a jump in); kept out of the adaptive R estimate; in coarse alignment: further than max_jump_m from the
  dead-reckoned position, at most reacquire_fixes times in a row;
- gate (gnss_pos_gate, gnss_vel_gate): the chi-square gate of the update;
- gate trapped: position fixes keep arriving but are all rejected for gate_reset_s, or reacquire_fixes of them
  after a loss of GNSS: the INS (not the GNSS) is taken to be wrong, position and velocity covariance are reset
  from the innovation and the fix is fused ungated. With the consistency monitor, which keeps the INS's covariance
  honest, a run of rejected fixes blames the INS after gate_reset_s only while their horizontal innovation is
  steady (it changes by at most gate_reset_max_rate_mps from one rejected fix to the next: an INS that is off, not
  fixes dragged away from it), and after gate_reset_unsteady_s whatever it does (by innovations alone a drag that
  long cannot be told from a diverging INS); a run that starts within gate_reset_unsteady_s of an outage recovery
  or a reset, when the INS itself is suspect, after gate_reset_s whatever it does.
- overconfidence (with config.consistency): each source's consistency monitor (zennav.nav.consistency) scales the
  covariance before an update when its NIS window says the filter is overconfident on small, steady innovations,
  so good fixes pass the gate instead of trapping it; counted {source}_inflated, fault "inflated".
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from ..adaptive_r import AdaptiveR
from ..aiding import antenna_velocity, position_model, velocity_model
from ..consistency import ConsistencyMonitor
from ..eskf import POS, VEL
from ..types import NS, GnssFix, GnssState, NavConfig
from ..vbkf import variational_r
from .base import AidSource, Measurement

log = logging.getLogger("zennav.nav")

MAX_FIX_AGE_S = 1.0  # a fix older than this behind the IMU time is stale and not fused
_VALID = GnssState.VALID  # (an enum member lookup costs a tenth of a microsecond in the per-sample outage check)


@dataclass
class FixContext:
    """A GNSS fix at the engine's time: age_s = IMU time minus fix time [s] (> 0 only for a fix that arrived
    after the IMU passed its time), omega_ib_b [rad/s] the bias-corrected body rate of the last IMU interval,
    coarse: the engine was in coarse alignment when the fix came; position_fused: set by the position source;
    reset: the position source reset position and velocity from the fix (the velocity source leaves it)."""

    fix: GnssFix
    age_s: float
    omega_ib_b: np.ndarray
    coarse: bool
    position_fused: bool = False
    reset: bool = False


def adaptive_r(config: NavConfig, dim: int = 3) -> AdaptiveR | None:
    """The configured adaptive-R estimator of a GNSS source, None when adaptive R is off."""
    if not config.adaptive_r:
        return None
    return AdaptiveR(dim, config.adaptive_window, config.adaptive_forgetting, config.adaptive_test_probability,
                     config.adaptive_floor, config.adaptive_ceiling)


def consistency_monitor(config: NavConfig, max_innovation: float, dim: int = 3) -> ConsistencyMonitor | None:
    """The configured consistency monitor of a GNSS source (max_innovation in its unit), None when it is off."""
    if not config.consistency:
        return None
    return ConsistencyMonitor(dim, config.consistency_window, config.consistency_test_probability, max_innovation,
                              config.consistency_max_factor)


def floored_noise(std, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The reported 1-sigma std (3,) floored at floor, and the diagonal R of its squares [unit, unit^2]."""
    sx, sy, sz = (max(float(x), floor) for x in std)
    R = np.zeros((3, 3))
    R[0, 0], R[1, 1], R[2, 2] = sx * sx, sy * sy, sz * sz
    return np.array([sx, sy, sz]), R


class GnssPosition(AidSource):
    """GNSS antenna position [rad, rad, m] with its reported NED 1-sigma floored at pos_std_floor_m.

    gnss_state: valid / outage; valid_t_ns: time of the last fused (or, in coarse alignment, tracked) fix, the
    engine's start time before any: the outage clock; interval_s: time between the last two fused fixes [s]."""

    inputs = ("gnss",)

    def __init__(self, config: NavConfig, t0_ns: int):
        super().__init__("gnss_pos", adaptive_r(config), consistency_monitor(config, config.consistency_max_pos_m),
                         variational_r(config, config.vb_gnss))
        self.config = config
        self.gnss_state = GnssState.VALID
        self.valid_t_ns = int(t0_ns)
        self.interval_s: float | None = None
        self.last_fix_t_ns = -1  # last fix that passed the input checks
        self.streak_start_t_ns: int | None = None  # first of the current run of rejected position fixes
        self.streak_fixes = 0
        self.streak_after_loss = False
        self.streak_prev: tuple[int, float, float] | None = None  # (t_ns, north, east [m]) of its last innovation
        self.suspect_until_t_ns = int(t0_ns)  # the INS is suspect until then (after a recovery or a reset)

    # ------------------------------------------------------------------ input checks
    def admit(self, nav, fix: GnssFix) -> bool:
        """Input quality gates of a fix as it arrives (the whole fix, velocity included); rejected ones are
        counted and reported. Starts the streak bookkeeping of the gate-trap recovery."""
        reason = self._input_error(nav, fix)
        if reason:
            self.reject(nav, fix.t_ns, reason, "", np.asarray(fix.llh, float).tolist(), faults=(reason[5:],))
            return False
        gap_s = (fix.t_ns - self.last_fix_t_ns) / NS if self.last_fix_t_ns >= 0 else 0.0
        if self.streak_start_t_ns is None:
            self.streak_after_loss = gap_s > self.config.outage_timeout_s
        self.last_fix_t_ns = fix.t_ns
        return True

    def _input_error(self, nav, fix: GnssFix) -> str:
        cfg = self.config
        arrays = [fix.llh, fix.std_ned]
        if fix.v_n is not None:
            if fix.std_v_n is None:
                return "gnss_malformed"
            arrays += [fix.v_n, fix.std_v_n]
        if any(np.shape(a) != (3,) for a in arrays) or not np.isfinite(np.concatenate(arrays)).all():
            return "gnss_malformed"
        if fix.t_ns == self.last_fix_t_ns:
            return "gnss_duplicate"
        if fix.t_ns < self.last_fix_t_ns:
            return "gnss_out_of_order"
        if fix.fix < cfg.min_fix:
            return "gnss_fix_quality"
        if 0 <= fix.num_sats < cfg.min_sats:
            return "gnss_few_satellites"
        std = np.asarray(fix.std_ned, dtype=float).tolist()
        if min(std) <= 0.0 or max(std) > cfg.max_std_m:
            return "gnss_std"
        if (nav.t_ns - fix.t_ns) / NS > MAX_FIX_AGE_S:
            return "gnss_stale"
        return ""

    # ------------------------------------------------------------------ fusion
    def on_input(self, nav, ctx: FixContext) -> bool:
        fix = ctx.fix
        fix_llh = np.asarray(fix.llh, dtype=float)
        v_ant_n = antenna_velocity(nav.state, nav.lever_b, ctx.omega_ib_b)
        z, H = position_model(nav.state, nav.lever_b, fix_llh, v_ant_n, ctx.age_s)
        std_pos, R = floored_noise(fix.std_ned, self.config.pos_std_floor_m)
        checking = not ctx.coarse and nav.alignment.checking
        verdict = nav.alignment.check_initial(nav, ctx, z, H, R) if checking else ""
        if ctx.coarse or verdict == "rejected":
            self._coarse_fix(nav, ctx, fix_llh, z)
            return False
        if verdict == "reset":  # position and velocity now at this fix: used, not fused
            ctx.reset = True
            self.report(nav, fix.t_ns, fix_llh.tolist(), z.tolist(), [], float("nan"), False,
                        "init_state_reset_pos_vel")
            nav.alignment.check_fused(nav, ctx, std_pos, True)
            self._fix_used(nav, fix.t_ns)
            return False
        m = Measurement(fix.t_ns, fix_llh, z, H, R)
        if self._gate_trapped(fix.t_ns, z):
            self._reset_position_velocity(nav, z, R, fix.t_ns)
            m.gated, m.faults = False, ("gate_trapped",)
            fused = nav.update(self, m)
        else:
            fused = not self._is_jump(nav, m) and nav.update(self, m)
        if checking and nav.alignment.checking:  # the configured initial state is still under test
            nav.alignment.check_fused(nav, ctx, std_pos, fused)
        if fused:
            self._fix_used(nav, fix.t_ns)
        else:
            if self.streak_start_t_ns is None:
                self.streak_start_t_ns = fix.t_ns
            self.streak_fixes += 1
            self.streak_prev = (fix.t_ns, float(z[0]), float(z[1]))
        ctx.position_fused = fused
        return fused

    def _fix_used(self, nav, t_ns: int) -> None:
        """A fix at t_ns was fused (or reset the INS to it): the outage clock, the run of rejected fixes, a recovery."""
        if 0 < (t_ns - self.valid_t_ns) / NS < 5.0:
            self.interval_s = (t_ns - self.valid_t_ns) / NS
        self.valid_t_ns = t_ns
        self.streak_start_t_ns, self.streak_fixes, self.streak_prev = None, 0, None
        if self.gnss_state != GnssState.VALID:
            nav.hold_learning(t_ns)
            self._suspect_ins(t_ns)
            log.warning("GNSS recovered at t=%.3f s after outage", t_ns / NS)
            nav.counters["outage_recovered"] += 1
        self.gnss_state = GnssState.VALID

    def on_step(self, nav) -> None:
        """Declare an outage when no fix has been fused for outage_timeout_s."""
        if self.gnss_state is _VALID and (nav.t_ns - self.valid_t_ns) / NS > self.config.outage_timeout_s:
            self.gnss_state = GnssState.OUTAGE
            nav.counters["outage_declared"] += 1
            log.warning("GNSS outage declared at t=%.3f s (no valid fix for %.1f s)", nav.t_ns / NS,
                        self.config.outage_timeout_s)

    def _is_jump(self, nav, m: Measurement) -> bool:
        """Jump test of a position fix before its update (see the module docstring)."""
        gate2, z = nav.gate_threshold(2), m.z
        if gate2 is None or math.hypot(z[0], z[1]) <= self.config.max_jump_m:
            return False
        k = m.H.shape[1]  # a model of the first k states (the engine pads it with zeros, see Navigator.update)
        S = m.H @ nav.P[:k, :k] @ m.H.T + m.R
        if float(z[:2] @ np.linalg.solve(S[:2, :2], z[:2])) <= gate2:
            return False
        ratio = float(z @ np.linalg.solve(S, z)) / nav.gate_threshold(3)
        self.reject(nav, m.t_ns, "gnss_pos_jump", f"test ratio {ratio:.1f}, innovation {np.round(z, 2)}",
                    m.observation.tolist(), z.tolist(), np.diag(S).tolist(), ratio, ("jump",))
        return True

    def _gate_trapped(self, t_ns: int, z: np.ndarray) -> bool:
        """True when the current run of rejected position fixes says the INS has left its own uncertainty (z: this
        fix's innovation [m, NED])."""
        if self.streak_start_t_ns is None:
            return False
        cfg = self.config
        if self.streak_after_loss and self.streak_fixes >= cfg.reacquire_fixes:
            return True
        streak_s = (t_ns - self.streak_start_t_ns) / NS
        if streak_s < cfg.gate_reset_s:
            return False
        if self.consistency is None or self.streak_prev is None or streak_s >= cfg.gate_reset_unsteady_s \
                or self.streak_start_t_ns < self.suspect_until_t_ns:
            return True
        t_prev, north, east = self.streak_prev
        rate = math.hypot(z[0] - north, z[1] - east) / max((t_ns - t_prev) / NS, 1e-9)
        return rate <= cfg.gate_reset_max_rate_mps

    def _reset_position_velocity(self, nav, z: np.ndarray, R: np.ndarray, t_ns: int) -> None:
        """Decorrelate position and velocity and widen their variances to cover the innovation z [m] and the
        velocity error that would explain it since the last fused fix; keeps P positive definite."""
        P = nav.P
        since_s = max((t_ns - self.valid_t_ns) / NS, 1.0)
        var_pos = np.maximum(np.diag(P)[POS], z * z + np.diag(R))
        var_vel = np.maximum(np.diag(P)[VEL], (z / since_s) ** 2)
        P[0:6, :] = 0.0
        P[:, 0:6] = 0.0
        P[POS, POS] = np.diag(var_pos)
        P[VEL, VEL] = np.diag(var_vel)
        nav.counters["gate_reset"] += 1
        nav.hold_learning(t_ns)
        self._suspect_ins(t_ns)
        log.warning("t=%.3f s: %d GNSS fixes rejected in a row, INS taken as wrong: covariance reset, fix fused",
                    t_ns / NS, self.streak_fixes)

    def _suspect_ins(self, t_ns: int) -> None:
        """After an outage or a covariance reset the INS is suspect for gate_reset_unsteady_s: a run of rejected fixes
        starting then resets after gate_reset_s whatever its innovation does."""
        self.suspect_until_t_ns = t_ns + int(self.config.gate_reset_unsteady_s * NS)

    def _coarse_fix(self, nav, ctx: FixContext, fix_llh: np.ndarray, z: np.ndarray) -> None:
        """Coarse alignment (z: INS antenna minus fix [m, NED]): reject a jump from the dead-reckoned position,
        else the fix counts as fused for the outage logic and the alignment tracks it or aligns on it."""
        t = ctx.fix.t_ns
        dist = math.hypot(z[0], z[1])
        if (nav.alignment.prev_track is not None and dist > self.config.max_jump_m
                and self.streak_fixes < self.config.reacquire_fixes):
            self.streak_fixes += 1
            self.reject(nav, t, "gnss_pos_jump", f"coarse alignment, {dist:.1f} m from the dead-reckoned position",
                        fix_llh.tolist(), z.tolist(), faults=("jump",))
            return
        self.streak_fixes = 0
        if self.gnss_state != GnssState.VALID:
            nav.counters["outage_recovered"] += 1
        self.gnss_state, self.valid_t_ns, self.last_fused_t_ns = GnssState.VALID, t, t
        reason = nav.alignment.on_fix(nav, ctx.fix, ctx.omega_ib_b)
        if reason == "align_coarse":
            nav.counters["gnss_align_coarse"] += 1
            self.report(nav, t, fix_llh.tolist(), z.tolist(), [], float("nan"), False, reason)
        else:
            self.report(nav, t, fix_llh.tolist(), [], [], float("nan"), False, reason)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict:
        return {**super().get_state(), "gnss_state": str(self.gnss_state), "valid_t_ns": int(self.valid_t_ns),
                "interval_s": self.interval_s, "last_fix_t_ns": int(self.last_fix_t_ns),
                "streak_start_t_ns": self.streak_start_t_ns, "streak_fixes": int(self.streak_fixes),
                "streak_after_loss": bool(self.streak_after_loss),
                "streak_prev": None if self.streak_prev is None else list(self.streak_prev),
                "suspect_until_t_ns": int(self.suspect_until_t_ns)}

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        self.gnss_state = GnssState(state["gnss_state"])
        self.valid_t_ns, self.interval_s = int(state["valid_t_ns"]), state["interval_s"]
        self.last_fix_t_ns = int(state["last_fix_t_ns"])
        self.streak_start_t_ns = state["streak_start_t_ns"]
        self.streak_fixes, self.streak_after_loss = int(state["streak_fixes"]), bool(state["streak_after_loss"])
        prev = state["streak_prev"]
        self.streak_prev = None if prev is None else (int(prev[0]), float(prev[1]), float(prev[2]))
        self.suspect_until_t_ns = int(state["suspect_until_t_ns"])


class GnssVelocity(AidSource):
    """GNSS antenna velocity [m/s, NED] with its reported 1-sigma floored at vel_std_floor_mps (use_gnss_velocity)."""

    inputs = ("gnss",)

    def __init__(self, config: NavConfig, t0_ns: int):
        super().__init__("gnss_vel", adaptive_r(config), consistency_monitor(config, config.consistency_max_vel_mps),
                         variational_r(config, config.vb_gnss))
        self.config = config

    def on_input(self, nav, ctx: FixContext) -> bool:
        fix = ctx.fix
        if ctx.coarse or ctx.reset or fix.v_n is None or not self.config.use_gnss_velocity:
            return False
        fix_v_n = np.asarray(fix.v_n, dtype=float)
        assert fix.std_v_n is not None  # the input check rejects a velocity without its std (gnss_malformed)
        z, H = velocity_model(nav.state, nav.lever_b, ctx.omega_ib_b, fix_v_n)
        R = floored_noise(fix.std_v_n, self.config.vel_std_floor_mps)[1]
        return nav.update(self, Measurement(fix.t_ns, fix_v_n, z, H, R))
