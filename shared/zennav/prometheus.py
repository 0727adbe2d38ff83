"""Prometheus metrics of the monitor (``zennav monitor --prometheus PORT``): its latest snapshot
(zennav.nodes.monitor.MonitorState.snapshot) exposed on http://HOST:PORT/metrics for Prometheus or Grafana.

Per key (label ``key``): zennav_key_rate_hz, zennav_key_messages_total, zennav_key_lag_ms (quantile p50/p99/max),
zennav_key_drops_total, zennav_key_duplicates_total, zennav_key_rejected_total (label ``reason``). Per service:
zennav_service_alive. Per aid source (label ``source``): zennav_aid_attempts_total, zennav_aid_fused_total,
zennav_aid_rejected_total (``reason``), zennav_aid_test_ratio (``stat`` last/p50/max). Navigation:
zennav_gnss_state (label ``state``, 1 for the current one), zennav_nav_imu_total, zennav_nav_gnss_total,
zennav_nav_fault_total (the ins's counters, label ``counter``). Models: zennav_model_version (label ``name``).
Every series carries the ``vehicle`` label.
"""
from __future__ import annotations

import threading

GNSS_STATES = ("valid", "outage")  # zennav.nav.types.GnssState


class MonitorCollector:
    """A prometheus_client collector over the snapshot last handed to ``update``."""

    def __init__(self) -> None:
        self._snap: dict = {}
        self._lock = threading.Lock()

    def update(self, snap: dict) -> None:
        with self._lock:
            self._snap = snap

    def collect(self):
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        with self._lock:
            snap = self._snap
        if not snap:
            return
        v = snap["vehicle"]

        def gauge(name, doc, labels):
            return GaugeMetricFamily(name, doc, labels=["vehicle", *labels])

        def counter(name, doc, labels):
            return CounterMetricFamily(name, doc, labels=["vehicle", *labels])

        rate = gauge("zennav_key_rate_hz", "messages per second on the key", ["key"])
        total = counter("zennav_key_messages", "messages received on the key", ["key"])
        lag = gauge("zennav_key_lag_ms", "publish to receive lag [ms]", ["key", "quantile"])
        drops = counter("zennav_key_drops", "messages lost (publisher sequence gaps)", ["key"])
        dups = counter("zennav_key_duplicates", "messages received twice", ["key"])
        rej = counter("zennav_key_rejected", "payloads rejected by the validator", ["key", "reason"])
        for key, k in snap["keys"].items():
            rate.add_metric([v, key], k["rate_hz"])
            total.add_metric([v, key], k["count"])
            for q, x in k["lag_ms"].items():
                if x is not None:
                    lag.add_metric([v, key, q], x)
            drops.add_metric([v, key], k["drops"])
            dups.add_metric([v, key], k["duplicates"])
            for reason, n in k["rejected"].items():
                rej.add_metric([v, key, reason], n)
        yield from (rate, total, lag, drops, dups, rej)
        alive = gauge("zennav_service_alive", "1 while the service's liveliness token is up", ["service"])
        for s, st in snap["services"].items():
            alive.add_metric([v, s], 1.0 if st["alive"] else 0.0)
        yield alive
        att = counter("zennav_aid_attempts", "aiding attempts of the source", ["source"])
        fused = counter("zennav_aid_fused", "fused measurements of the source", ["source"])
        arej = counter("zennav_aid_rejected", "rejected measurements of the source", ["source", "reason"])
        ratio = gauge("zennav_aid_test_ratio", "innovation test ratio (> 1 fails the gate)", ["source", "stat"])
        for src, a in snap["aid"].items():
            att.add_metric([v, src], a["count"])
            fused.add_metric([v, src], a["fused"])
            for reason, n in a["rejected"].items():
                arej.add_metric([v, src, reason], n)
            for stat in ("last", "p50", "max"):
                x = a[f"{stat}_test_ratio"]
                if x is not None:
                    ratio.add_metric([v, src, stat], x)
        yield from (att, fused, arej, ratio)
        nav = snap["nav"]
        gs = gauge("zennav_gnss_state", "1 for the ins's current GNSS state", ["state"])
        cur = nav.get("gnss_state")
        for s in sorted(set(GNSS_STATES) | ({cur} if cur else set())):
            gs.add_metric([v, s], 1.0 if s == cur else 0.0)
        imu = counter("zennav_nav_imu", "IMU samples consumed by the ins", [])
        gnss = counter("zennav_nav_gnss", "GNSS fixes consumed by the ins", [])
        faults = counter("zennav_nav_fault", "the ins's event and rejection counters", ["counter"])
        if "imu_count" in nav:
            imu.add_metric([v], nav["imu_count"])
            gnss.add_metric([v], nav["gnss_count"])
            for name, n in {**nav.get("counters", {}), **nav.get("rejected", {})}.items():
                if isinstance(n, (int, float)) and not isinstance(n, bool):
                    faults.add_metric([v, name], n)
        yield from (gs, imu, gnss, faults)
        mv = gauge("zennav_model_version", "live version of the learned model", ["name"])
        for name, m in snap["models"].items():
            mv.add_metric([v, name], m["version"])
        yield mv


def serve(port: int, addr: str = "127.0.0.1") -> MonitorCollector:
    """Start the /metrics endpoint on addr:port (a daemon thread); returns the collector to update."""
    from prometheus_client import CollectorRegistry, start_http_server

    registry = CollectorRegistry()
    collector = MonitorCollector()
    registry.register(collector)
    start_http_server(port, addr=addr, registry=registry)
    return collector
