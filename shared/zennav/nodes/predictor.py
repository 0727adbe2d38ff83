"""The predictor service's core, transport-free: zennav.learn.predictor_core.PredictorCore (validate, swap, answer
or refuse) over model_params and learn_query messages, with the swap latencies; answers go to ``publish(msg)``
(see zennav.services.predictor for the wiring and the atomic-swap argument, ARCHITECTURE.md section 3 for the
loop). numpy only: this module never imports torch."""
from __future__ import annotations

import sys
import time
from collections import deque

import numpy as np

from .. import messages as M
from ..learn.predictor_core import PredictorCore
from ..learn.signing import Verifier
from ..messages.learn import refusal_msg
from ..nav.learning import FEATURES


def _pct(values, q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else 0.0


class PredictorNode:
    """The transport-free part of the predictor: ``on_model(key, msg, recv_ns)`` with bus-valid model_params
    messages (``reject(key, reason)`` for bus-invalid ones), ``on_query(msg)`` with learn_query messages; answers
    go to ``publish(msg)``. on_model may run concurrently with on_query (see the module docstring)."""

    def __init__(self, publish, log, bus_reject=None, on_change=None, max_domain_excess: float = 0.5,
                 lockstep_timeout_s: float = 0.0, verifier: Verifier | None = None,
                 max_version_step: int | None = None):
        self.publish = publish
        self.log = log
        self.core = PredictorCore(max_domain_excess, verifier, max_version_step)
        self.wait_s = float(lockstep_timeout_s)  # > 0: lockstep
        self.bus_reject = bus_reject or (lambda key, reason: None)
        self.on_change = on_change or (lambda detail: None)
        self.swap_latency_ns: deque = deque(maxlen=10_000)  # publisher put -> live (same-host clocks)
        self.validate_ns: deque = deque(maxlen=10_000)  # received -> live
        self.gnss_state = "unknown"

    @property
    def live(self):
        return self.core.live

    # ------------------------------------------------------------------ parameter sets
    def reject(self, key: str, reason: str, bus_counted: bool = True) -> None:
        """Count and log a set rejected by the bus's check; reason 'code: detail'."""
        self.core.count_rejection(key.rsplit("/", 1)[-1], reason)
        self._rejected(key, reason, bus_counted)

    def _rejected(self, key: str, reason: str, bus_counted: bool) -> None:
        self.log.warning("parameter set on %s rejected (%s); the live set stays: %s", key, reason.split(":", 1)[0],
                         self.core.describe())
        if not bus_counted:
            self.bus_reject(key, reason)
        self.on_change(self.detail())

    def on_model(self, key: str, msg: dict, recv_ns: int, latency: bool = True) -> bool:
        """Validate a model_params message and swap it in; False when rejected (or a duplicate)."""
        name = key.rsplit("/", 1)[-1]
        target = (msg.get("metrics") or {}).get("target")
        cur = self.core.live.get(target) if isinstance(target, str) else None
        try:
            ps = M.paramset_of(msg)
        except Exception as e:  # a map paramset_of cannot read
            self.core.count_rejection(name, f"model_schema: {type(e).__name__}: {e}")
            self._rejected(key, f"model_schema: {type(e).__name__}: {e}", False)
            return False
        new, reason = self.core.offer(name, ps, msg.get("signature"))
        if new is None:
            if reason != "duplicate":
                self._rejected(key, reason, False)
            return False
        now = time.time_ns()
        if latency:
            self.swap_latency_ns.append(now - msg["pub_ns"])
            self.validate_ns.append(now - recv_ns)
        self.log.info("live %s: %s v%d through %d samples (was %s), 1-sigma %s", new.target, name, new.version,
                      new.samples_seen, "none" if cur is None else f"v{cur.version}", [round(s, 4) for s in new.std])
        self.on_change(self.detail())
        return True

    # ------------------------------------------------------------------ queries
    def on_query(self, msg: dict) -> dict:
        """Answer one learn_query: the correction, or the refusal with its reason (counted); published and
        returned."""
        out = self.core.answer(msg["target"], msg["features"], msg.get("n_samples"), self.wait_s)
        if isinstance(out, str):
            ans = refusal_msg(msg, out)
        else:
            y, std, model = out
            ans = M.correction_msg(msg, y, std, model.name, model.version)
        self.publish(ans)
        return ans

    def on_trainer_status(self, msg: dict) -> None:
        """The trainer's status: its progress per target (lockstep, zennav.learn.predictor_core)."""
        c = msg["counters"]
        for t in FEATURES:
            if f"through_{t}" in c:
                self.core.trainer_progress(t, c.get(f"min_samples_{t}", 0), c.get(f"set_through_{t}", 0),
                                           c[f"through_{t}"])

    def on_nav_status(self, msg: dict) -> None:
        self.gnss_state = msg["gnss_state"]

    # ------------------------------------------------------------------ status
    def detail(self) -> str:
        v = self.core.verifier
        d = (f"live {self.core.describe()}; GNSS {self.gnss_state}" + ("; lockstep" if self.wait_s > 0 else "")
             + (f"; sets signed by {v.key_id}" if v else "; UNSIGNED SETS ACCEPTED"))
        last = self.core.last_rejection
        return d + (f"; last rejected {last}" if last else "")

    def counters(self) -> dict:
        lat = list(self.swap_latency_ns)
        val = list(self.validate_ns)
        return {**self.core.counters(), "swaps": len(lat), "swap_p50_us": round(_pct(lat, 50) / 1e3, 1),
                "swap_p99_us": round(_pct(lat, 99) / 1e3, 1), "swap_max_us": round(max(lat, default=0) / 1e3, 1),
                "validate_p99_us": round(_pct(val, 99) / 1e3, 1), "torch_imported": int("torch" in sys.modules)}
