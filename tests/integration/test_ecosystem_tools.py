"""The monitor's Prometheus endpoint scraped while an ingest and an ins run over real Zenoh."""
from __future__ import annotations

import urllib.request

from zennav_harness import Collector, free_port, wait_until


def _scrape(port: int) -> dict:
    from prometheus_client.parser import text_string_to_metric_families

    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    out: dict = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out.setdefault(s.name, []).append((s.labels, s.value))
    return out


def test_prometheus_scrape_of_a_running_monitor(cluster):
    k = cluster.keys
    port = free_port()
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    cluster.service("monitor", "--prometheus", port, "--interval", "0.5")
    cluster.service("ins")
    cluster.service("ingest", "sim:car", "-o", "duration_s=120", "--speed", "4", "--outage", "60:20", wait=False)
    wait_until(lambda: any(m["gnss_state"] == "outage" for m in status.msgs()), 120, "the ins in the GNSS outage")
    def in_outage():
        m = _scrape(port)
        return m if ({"state": "outage", "vehicle": "car"}, 1.0) in m.get("zennav_gnss_state", []) else None

    got = wait_until(in_outage, 30, "a scrape showing the outage")
    imu_key = k.imu("0")
    rates = {lab["key"]: val for lab, val in got["zennav_key_rate_hz"]}
    assert 100 < rates[imu_key] < 2000  # 200 Hz at 4x real time, as the monitor measured it over its window
    assert {lab["key"]: val for lab, val in got["zennav_key_drops_total"]}[imu_key] == 0
    alive = {lab["service"]: val for lab, val in got["zennav_service_alive"]}
    assert alive["ins"] == 1.0 and alive["ingest"] == 1.0
    states = {lab["state"]: val for lab, val in got["zennav_gnss_state"]}
    assert states["outage"] == 1.0 and states["valid"] == 0.0
    ratios = {(lab["source"], lab["stat"]): val for lab, val in got["zennav_aid_test_ratio"]}
    assert ratios[("gnss_pos", "p50")] < 1.0
    assert got["zennav_nav_imu_total"][0][1] > 1000
    assert all(lab["vehicle"] == "car" for samples in got.values() for lab, _ in samples)
    print(f"\nscrape: {len(got)} series names; imu rate {rates[imu_key]:.0f} Hz, gnss_pos p50 test ratio "
          f"{ratios[('gnss_pos', 'p50')]:.3f}, GNSS state {states}")
