"""A GNSS receiver on a pseudo-terminal feeding the ingest (``zennav-ingest --gnss-receiver serial:PTY``): NMEA for
the first half of the drive, UBX for the rest, fused by the ins over the bus; the ins's quality checks reject the
fixes sent with 3 satellites and those sent without a fix."""
from __future__ import annotations

import os
import threading

import numpy as np
from zennav_harness import Collector, wait_until

DURATION = 120.0
FEW_SATS = (40.0, 10.0)
NO_FIX = (70.0, 10.0)


def test_nmea_and_ubx_receiver_on_a_pty_fused_by_the_ins(cluster):
    from zennav.datasets.registry import load_dataset
    from zennav.metrics import evaluate
    from zennav.receivers.simulate import open_pty, send_fixes, write_all
    from zennav.replay import ReplayResult, outage_windows

    ds = load_dataset("sim:car", duration_s=DURATION)
    t0 = int(ds.initial.t_ns)
    fixes = [ds.gnss.fix_at(i) for i in range(len(ds.gnss.t_ns)) if ds.gnss.t_ns[i] > t0]
    half = fixes[len(fixes) // 2].t_ns
    master, slave, path = open_pty()
    k = cluster.keys
    sols = Collector(cluster.bus, k.nav_solution())
    aids = Collector(cluster.bus, k.nav_aid())
    status = Collector(cluster.bus, k.nav_status(), channel="ring")
    cluster.service("ins")
    ing = cluster.service("ingest", "sim:car", "-o", f"duration_s={DURATION:g}", "--speed", "0",
                          "--gnss-receiver", f"serial:{path}", "--start-delay", "3", wait=False)
    try:
        wait_until(lambda: "receiver serial:" in ing.text() and ": open" in ing.text(), 60, "the receiver to open")
        writer = threading.Thread(target=send_fixes, args=(
            write_all(master), fixes, lambda f: "nmea" if f.t_ns < half else "ubx", t0, 0.0,
            outage_windows(t0, t0 + int(DURATION * 1e9), [FEW_SATS]),
            outage_windows(t0, t0 + int(DURATION * 1e9), [NO_FIX])), daemon=True)
        writer.start()
        st = status.wait(lambda c: next((m for m in c.msgs() if m["stream"].get("done")), None), 240,
                         "ins to finish the stream")
        assert ing.wait(60) == 0
    finally:
        os.close(master)
        os.close(slave)
    n_sent = len(fixes)
    # the status and the aid reports travel on different keys: the "done" status may overtake the last reports
    reports = aids.wait(lambda c: r if len(r := [m for m in c.msgs() if m["source"] == "gnss_pos"]) >= n_sent
                        else None, 30, "an aid report of every fix")
    reasons = {r: sum(1 for m in reports if m["reason"] == r) for r in {m["reason"] for m in reports}}
    assert len(reports) == n_sent
    assert st["gnss_count"] == n_sent  # every epoch, NMEA and UBX, reached the ins
    assert reasons.get("gnss_few_satellites") == 10 and reasons.get("gnss_fix_quality") == 10
    fused_t = [m["t_ns"] for m in reports if m["fused"]]
    assert sum(1 for t in fused_t if t < half) > 30 and sum(1 for t in fused_t if t >= half) > 30  # both formats
    sols.wait(lambda c: len(c.msgs()) >= st["stream"]["solutions"], 60, "all solutions")
    msgs = sols.msgs()
    res = ReplayResult("sim:car", np.array([m["t_ns"] for m in msgs]), np.array([m["llh"] for m in msgs]),
                       np.array([m["v_n"] for m in msgs]), np.array([m["q_nb"] for m in msgs]),
                       np.array([m["std_pos_ned"] for m in msgs]), np.zeros(len(msgs), bool), [])
    m = evaluate(ds, res)
    print(f"\nreceiver over a pty: {n_sent} epochs (NMEA then UBX) -> ins gnss {reasons}; horizontal RMS "
          f"{m['horizontal_rms_m']:.3f} m, vertical RMS {m['vertical_rms_m']:.3f} m over {len(msgs)} solutions; "
          f"ingest counters: {[line for line in ing.text().splitlines() if 'fixes' in line][-1:]}")
    assert m["horizontal_rms_m"] < 3.0
