"""The monitor's core, transport-free: what it knows of one vehicle's key space (``MonitorState``, fed every
sample's raw payload and the liveliness changes) and how it prints it (``format_table``).

Per key: message count and rate, lag publish->receive (wall clock, from the message's pub_ns), drops (sequence
gaps per publisher), rejections by reason (this monitor's own validator). Per service: alive or not, state and
detail from its status heartbeat, its own rejection counters. Navigation: GNSS state, counts, stream progress,
alignment (state, method, heading 1-sigma, when each state began) and the live measurement noise R per GNSS
source (diagonal, ratio to the reported R, adaptive branch; adaptive on/off); an AUV's DVL and depth samples
consumed and the engine's dvl*/depth* counters (beam cases, rejections); innovation test ratios per aid source;
attitude (roll/pitch/yaw, gyro bias, rejection weight, whether the earth and transport rate is applied); the
live model version per model name. A second ins publishing under a nav prefix (``zennav-ins --nav-prefix
plain``: <base>/nav/plain/...) is kept apart: its status under ``navs[prefix]``, its
aid sources as '<prefix>/<source>'.

Health (``services[s]["health"]`` and ``["why"]``), judged here from what the monitor sees, not from what a service
says of itself: "down" (no liveliness token), "error" (its state), "degraded" when alive but not progressing:
no status for ``stale_s`` (a hung process keeps its token until the session's lease ends), or its input flowing
on the bus for ``stall_s`` while the counter of its work did not move (PROGRESS: an ins not joined to the live
stream, or stalled; a trainer not taking samples; a predictor not answering), else "running".
"""
from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque

from .. import messages as M

DEG_PER_H = 180.0 / math.pi * 3600.0  # [deg/h] per [rad/s]
# what feeds a service (key prefixes under the vehicle's base) and the status counters of its work (exact name, or
# a prefix ending in "_": their sum); a service is judged by the first rule whose counters it publishes
PROGRESS = ((("sensor/imu",), ("imu",)),  # ins (any nav prefix), attitude: IMU samples processed
            (("learn/samples",), ("received_",)),  # trainer: samples taken per target
            (("learn/query",), ("queries_",)))  # predictor: queries answered or refused
UNDERWATER = ("dvl", "depth")  # prefixes of the engine counters of the AUV's sources (beam cases, rejections)
NOT_JOINED = ("drop_no_stream", "drop_foreign_source")  # an ins's samples dropped as not of its stream


class KeyStats:
    """Per key: messages, bytes, publish->receive lags [ms], drops and duplicates (per-publisher seq), rejections."""

    __slots__ = ("count", "bytes", "lags", "next_seq", "drops", "dups", "rejected", "last_count", "rate",
                 "last_recv_ns", "schema")

    def __init__(self) -> None:
        self.count = 0
        self.bytes = 0
        self.lags: deque = deque(maxlen=2000)
        self.next_seq: dict[str, int] = {}
        self.drops = 0
        self.dups = 0
        self.rejected: Counter[str] = Counter()
        self.last_count = 0
        self.rate = 0.0
        self.last_recv_ns = 0
        self.schema = ""


def _pct(values, q):
    if not values:
        return None
    s = sorted(values)
    return s[min(len(s) - 1, int(round(q / 100.0 * (len(s) - 1))))]


def _progress(counters: dict) -> tuple[tuple[str, ...], int, int] | None:
    """(input key prefixes, work done, not-joined drops) of a service's status counters by PROGRESS, or None."""
    for inputs, names in PROGRESS:
        hits = [v for k, v in counters.items() for n in names
                if (k.startswith(n) if n.endswith("_") else k == n) and isinstance(v, (int, float))]
        if hits:
            return inputs, int(sum(hits)), int(sum(counters.get(k, 0) for k in NOT_JOINED))
    return None


class MonitorState:
    """Everything the monitor knows; fed from the bus workers, read by the reporter (one lock). stall_s, stale_s:
    the health rules (module docstring) [s]."""

    def __init__(self, keys: M.Keys, stall_s: float = 10.0, stale_s: float = 5.0):
        self.keys = keys
        self.stall_s, self.stale_s = float(stall_s), float(stale_s)
        self.progress: dict[str, deque] = {}  # service -> (receive wall time [ns], work done, not-joined drops)
        self.lock = threading.Lock()
        self.validator = M.Validator()
        self.per_key: dict[str, KeyStats] = {}
        self.alive: dict[str, bool] = {}
        self.services: dict[str, dict] = {}
        self.nav: dict = {}  # the ins's (<base>/nav/...)
        self.navs: dict[str, dict] = {}  # other ins instances by nav prefix (<base>/nav/<prefix>/..., --nav-prefix)
        self.aid: dict[str, dict] = {}  # by source; '<prefix>/<source>' for another ins
        self.models: dict[str, dict] = {}
        self.attitude: dict = {}
        self.correction: dict = {}
        self.t_rate = time.monotonic()
        self.started = time.time()

    def on_sample(self, key: str, payload: bytes, recv_ns: int) -> None:
        msg, reason = self.validator.check(key, payload)
        with self.lock:
            ks = self.per_key.get(key)
            if ks is None:
                ks = self.per_key[key] = KeyStats()
            ks.count += 1
            ks.bytes += len(payload)
            ks.last_recv_ns = recv_ns
            if msg is None:
                ks.rejected[reason.split(":", 1)[0]] += 1
                return
            ks.schema = msg["schema"]
            ks.lags.append((recv_ns - msg["pub_ns"]) / 1e6)
            src, seq = msg["src"], msg["seq"]
            nxt = ks.next_seq.get(src)
            if nxt is not None:
                if seq > nxt:
                    ks.drops += seq - nxt
                elif seq < nxt:
                    ks.dups += 1
            ks.next_seq[src] = max(seq + 1, nxt or 0)
            self._content(key, msg, recv_ns)

    def _content(self, key: str, msg: dict, recv_ns: int) -> None:
        schema = msg["schema"]
        prefix = self.keys.nav_prefix_of(key)
        nav = self.navs.setdefault(prefix, {}) if prefix else self.nav
        if schema == "service_status":
            self.services[msg["service"]] = {"state": msg["state"], "detail": msg["detail"],
                                             "counters": msg["counters"], "rejected": msg["rejected"],
                                             "wall_ns": msg["t_ns"], "recv_ns": recv_ns}
            prog = _progress(msg["counters"])
            if prog is not None:
                hist = self.progress.setdefault(msg["service"], deque())
                hist.append((recv_ns, prog[1], prog[2]))
                while len(hist) > 2 and hist[1][0] < recv_ns - 2 * self.stall_s * 1e9:
                    hist.popleft()  # keep one entry older than the stall window
        elif schema == "nav_status":
            keep = {k: v for k, v in nav.items() if k.startswith("solution_")}
            nav.clear()
            nav.update(keep, t_ns=msg["t_ns"], gnss_state=msg["gnss_state"], imu_count=msg["imu_count"],
                       gnss_count=msg["gnss_count"], counters=msg["counters"], rejected=msg["rejected"],
                       stream=msg["stream"], model=msg["model"])
            if msg.get("aid_counts") is not None:  # an AUV's stream: DVL and depth samples consumed
                nav["aid_counts"] = msg["aid_counts"]
            al = msg.get("alignment")
            if al is not None:  # optional fields (older ins: absent)
                nav["alignment"] = {**al, "heading_std_deg": round(math.degrees(al["heading_std_rad"]), 4),
                                    "times_s": {s: round((t - al["times_ns"].get("coarse", t)) / 1e9, 3)
                                                for s, t in al["times_ns"].items()}}
            if msg.get("adaptive_r") is not None:
                nav["adaptive_r"] = msg["adaptive_r"]
            if msg.get("measurement_noise") is not None:
                nav["measurement_noise"] = msg["measurement_noise"]
        elif schema == "nav_solution":
            nav["solution_gnss_state"] = msg["gnss_state"]
            nav["solution_t_ns"] = msg["t_ns"]
        elif schema == "aid_report":
            name = f"{prefix}/{msg['source']}" if prefix else msg["source"]
            a = self.aid.setdefault(name, {"count": 0, "fused": 0, "rejected": Counter(), "faults": Counter(),
                                           "ratios": deque(maxlen=200)})
            a["count"] += 1
            if msg["fused"]:
                a["fused"] += 1
            else:
                a["rejected"][msg["reason"] or "unknown"] += 1
            a["faults"].update(msg.get("faults") or ())  # e.g. inflated (consistency monitor), jump, gate
            if msg["test_ratio"] is not None:
                a["ratios"].append(msg["test_ratio"])
            a["last_test_ratio"] = msg["test_ratio"]
        elif schema == "model_params":
            cur = self.models.get(msg["name"])
            if cur is None or msg["version"] >= cur["version"]:
                self.models[msg["name"]] = {"version": msg["version"], "kind": msg["kind"],
                                            "created_t_ns": msg["created_t_ns"], "metrics": msg["metrics"]}
        elif schema == "attitude":
            w_in = msg.get("omega_in_n")
            self.attitude = {"t_ns": msg["t_ns"], "q_nb": msg["q_nb"],
                             "euler_deg": [x * 57.29577951308232 for x in msg["euler"]],
                             "gyro_bias_dph": [x * DEG_PER_H for x in msg["gyro_bias"]], "weight": msg["weight"],
                             "omega_in_n_dph": None if w_in is None else [x * DEG_PER_H for x in w_in]}
        elif schema == "correction":
            self.correction = {"t_ns": msg["t_ns"], "model": msg["model"], "version": msg["version"]}

    def health(self, service: str, alive: bool, st: dict, now_ns: int) -> tuple[str, str]:
        """(health, why) of one service (module docstring); called with the lock held."""
        if not alive:
            return "down", "no liveliness token"
        if st.get("state") == "error":
            return "error", st.get("detail") or ""
        if st and (age := (now_ns - st["recv_ns"]) / 1e9) > self.stale_s:  # this monitor's clock only
            return "degraded", f"no status for {age:.0f} s"
        prog = _progress(st.get("counters", {}))
        hist = self.progress.get(service)
        if prog is None or not hist:
            return ("running" if st else "unknown"), ""
        t0 = now_ns - self.stall_s * 1e9
        old = next((h for h in reversed(hist) if h[0] <= t0), None)
        fed = [k for k, ks in self.per_key.items() if ks.last_recv_ns >= t0
               and any(self.keys.rel(k).startswith(p) for p in prog[0])]
        if old is None or not fed or hist[-1][1] != old[1]:
            return "running", ""
        dropped = hist[-1][2] - old[2]
        if dropped > 0:
            return "degraded", (f"not joined: {dropped} samples dropped as not its stream in {self.stall_s:g} s, "
                                f"none processed")
        return "degraded", f"not progressing: {', '.join(self.keys.rel(k) for k in fed)} flowing, work counter " \
                           f"stuck at {hist[-1][1]} for {self.stall_s:g} s"

    def on_alive(self, service: str, alive: bool) -> None:
        with self.lock:
            self.alive[service] = alive

    def snapshot(self, now_ns: int | None = None) -> dict:
        """Everything, with the health of each service as of now_ns (wall clock [ns], default now)."""
        now = time.monotonic()
        with self.lock:
            dt = max(now - self.t_rate, 1e-6)
            self.t_rate = now
            keys: dict[str, dict] = {}
            for key, ks in sorted(self.per_key.items()):
                ks.rate = (ks.count - ks.last_count) / dt
                ks.last_count = ks.count
                lags = list(ks.lags)
                keys[key] = {"schema": ks.schema, "count": ks.count, "rate_hz": round(ks.rate, 1),
                             "lag_ms": {"p50": _r(_pct(lags, 50)), "p99": _r(_pct(lags, 99)),
                                        "max": _r(max(lags) if lags else None)},
                             "drops": ks.drops, "duplicates": ks.dups, "rejected": dict(ks.rejected)}
            names = set(self.alive) | set(self.services)
            services = {}
            now_ns = time.time_ns() if now_ns is None else now_ns
            for s in sorted(names):
                st = self.services.get(s, {})
                health, why = self.health(s, bool(self.alive.get(s, False)), st, now_ns)
                services[s] = {"alive": bool(self.alive.get(s, False)), "health": health, "why": why,
                               "state": st.get("state"),
                               "detail": st.get("detail"), "rejected": st.get("rejected", {}),
                               "counters": st.get("counters", {}),
                               "status_age_s": _r((now_ns - st["recv_ns"]) / 1e9) if st else None}
            aid = {src: {"count": a["count"], "fused": a["fused"], "rejected": dict(a["rejected"]),
                         "faults": dict(a["faults"]),
                         "last_test_ratio": _r(a.get("last_test_ratio")),
                         "p50_test_ratio": _r(_pct(list(a["ratios"]), 50)),
                         "max_test_ratio": _r(max(a["ratios"]) if a["ratios"] else None)}
                   for src, a in sorted(self.aid.items())}
            rejected: Counter[str] = Counter()
            for k in keys.values():
                rejected.update(k["rejected"])
            return {"vehicle": self.keys.vehicle, "wall_time": time.time(), "window_s": round(dt, 3),
                    "services": services, "keys": keys, "nav": dict(self.nav),
                    "navs": {p: dict(n) for p, n in sorted(self.navs.items())}, "aid": aid,
                    "models": dict(self.models), "attitude": dict(self.attitude),
                    "correction": dict(self.correction), "rejected_total": dict(rejected)}


def _r(x, nd=3):
    return None if x is None else round(float(x), nd)


def format_table(snap: dict) -> str:
    lines = [f"zennav monitor  vehicle {snap['vehicle']}  {time.strftime('%H:%M:%S')}  (window {snap['window_s']} s)",
             "", "SERVICES"]
    for s, d in snap["services"].items():
        rej = sum(d["rejected"].values()) if d["rejected"] else 0
        lines.append(f"  {s:<12} {'UP  ' if d['alive'] else 'DOWN'} {d['health']:<9} {d['state'] or '-':<10} "
                     f"rejected {rej:<6} {d['why'] or d['detail'] or ''}"[:160])
    nav = snap["nav"]
    if nav:
        lines += ["", f"NAV  gnss {nav.get('gnss_state')}  imu {nav.get('imu_count')}  gnss {nav.get('gnss_count')}  "
                      f"stream {nav.get('stream', {}).get('dataset', '')} done={nav.get('stream', {}).get('done')}"]
        if nav.get("aid_counts"):
            underwater = {k: v for k, v in nav.get("counters", {}).items() if k.startswith(UNDERWATER)}
            lines.append("  " + "  ".join(f"{k} {n}" for k, n in nav["aid_counts"].items()) +
                         f"  engine {underwater or '{}'}"[:200])
        al = nav.get("alignment")
        if al:
            times = ", ".join(f"{s} {t:.1f} s" for s, t in al["times_s"].items())
            lines.append(f"  alignment {al['state']:<8} method {al['method'] or '-'}  heading 1-sigma "
                         f"{al['heading_std_deg']:.3f} deg  tilt from {al['tilt_source'] or '-'}  ({times})")
            if al.get("initial_state"):
                lines.append(f"  initial state {al['initial_state']}"[:200])
            if al.get("waiting"):
                lines.append(f"  alignment waits for {al['waiting']}"[:200])
        if "adaptive_r" in nav:
            lines.append(f"  adaptive R {'on' if nav['adaptive_r'] else 'off'}")
        for src, r in (nav.get("measurement_noise") or {}).items():
            ratio = "-" if r["ratio"] is None else "[" + ", ".join(f"{x:.2f}" for x in r["ratio"]) + "]"
            lines.append(f"  R {src:<10} diag [{', '.join(f'{x:.3g}' for x in r['R_diag'])}]  R/reported {ratio}  "
                         f"branch {r['branch']}")
    for prefix, n in snap.get("navs", {}).items():
        lines.append(f"NAV/{prefix}  gnss {n.get('gnss_state')}  imu {n.get('imu_count')}  gnss {n.get('gnss_count')}  "
                     f"done={n.get('stream', {}).get('done')}")
    att = snap["attitude"]
    if att:
        rate = "applied" if att.get("omega_in_n_dph") and any(att["omega_in_n_dph"]) else "off"
        lines.append(f"ATT  roll/pitch/yaw {' '.join(f'{x:.2f}' for x in att['euler_deg'])} deg  gyro bias "
                     f"{' '.join(f'{x:.1f}' for x in att['gyro_bias_dph'])} deg/h  weight {att['weight']:.2f}  "
                     f"earth+transport rate {rate}")
    for src, a in snap["aid"].items():
        lines.append(f"  aid {src:<10} n {a['count']:<7} fused {a['fused']:<7} test ratio last {a['last_test_ratio']} "
                     f"p50 {a['p50_test_ratio']} max {a['max_test_ratio']}  rejected {a['rejected']}  "
                     f"faults {a['faults']}")
    if snap["models"]:
        lines.append("  models " + ", ".join(f"{n} v{m['version']}" for n, m in snap["models"].items()))
    else:
        lines.append("  models (none live)")
    lines += ["", f"{'KEY':<48} {'rate/s':>9} {'count':>9} {'lag p50':>8} {'p99 ms':>8} {'drops':>6} {'rej':>5}"]
    base = f"{M.ROOT}/{snap['vehicle']}/"
    for key, k in snap["keys"].items():
        lag = k["lag_ms"]
        lines.append(f"{key.replace(base, ''):<48} {k['rate_hz']:>9.1f} {k['count']:>9} "
                     f"{_fmt(lag['p50']):>8} {_fmt(lag['p99']):>8} {k['drops']:>6} {sum(k['rejected'].values()):>5}")
    return "\n".join(lines)


def _fmt(x):
    return "-" if x is None else f"{x:.3f}"
