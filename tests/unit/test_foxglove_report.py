"""Foxglove-ready MCAP of a replay read back with the mcap library; zennav report on a replay folder, with a
hand-made smoothed/ folder drawn side by side; the progress line."""
from __future__ import annotations

import io
import json
import math
import shutil

from click.testing import CliRunner


def test_replay_mcap_and_report(tmp_path):
    from mcap.reader import make_reader

    from zennav.cli import main
    from zennav.gpstime import gps_ns_to_unix_ns
    from zennav.recording import read_mcap

    out, mcap = tmp_path / "run", tmp_path / "run.mcap"
    r = CliRunner().invoke(main, ["replay", "sim:car", "-o", "duration_s=80", "--outage", "50:20", "--out", str(out),
                                  "--mcap", str(mcap)])
    assert r.exit_code == 0, r.output
    sols = [m for _k, m, _p, _t in read_mcap(mcap, [r"/nav/solution$"])]
    n_csv = sum(1 for _ in open(out / "nav.csv")) - 1
    assert len(sols) == n_csv
    with open(mcap, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
        assert {schemas[k] for k in ("foxglove.LocationFix", "foxglove.PoseInFrame", "foxglove.FrameTransform")} \
            == {"jsonschema"}
        topics = {c.topic: c for c in summary.channels.values()}
        loc_topic = next(t for t in topics if t.endswith("/nav/solution/location"))
        assert topics[loc_topic].message_encoding == "json"
        locs = [(m.log_time, json.loads(m.data)) for _s, c, m in reader.iter_messages(topics=[loc_topic])]
    assert len(locs) == len(sols)  # one LocationFix per solution
    for (log_ns, fix), sol in zip(locs[::500], sols[::500]):
        assert log_ns == gps_ns_to_unix_ns(sol["t_ns"])  # log time = sample time
        assert fix["timestamp"]["sec"] * 10**9 + fix["timestamp"]["nsec"] == log_ns
        assert abs(fix["latitude"] - math.degrees(sol["llh"][0])) < 1e-12  # degrees
        assert abs(fix["longitude"] - math.degrees(sol["llh"][1])) < 1e-12
        cov = fix["position_covariance"]  # ENU: east variance first
        assert abs(cov[0] - sol["std_pos_ned"][1] ** 2) < 1e-12 and abs(cov[4] - sol["std_pos_ned"][0] ** 2) < 1e-12

    # a smoothed/ folder as `zennav replay --smooth` will write it (here: the forward run, copied)
    (out / "smoothed").mkdir()
    shutil.copy(out / "nav.csv", out / "smoothed" / "nav.csv")
    m = json.loads((out / "metrics.json").read_text())
    m["smoothed"] = {k: m[k] for k in ("horizontal_rms_m", "vertical_rms_m", "velocity_rms_mps", "attitude_rms_deg",
                                       "outages", "outage_max_horizontal_rms_m", "outage_max_horizontal_max_m")}
    m["smoothed"]["horizontal_rms_m"] = 0.123456
    (out / "metrics.json").write_text(json.dumps(m))
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    rep = out / "report"
    assert {p.name for p in rep.glob("*.png")} == {"track.png", "errors.png", "test_ratios.png", "biases.png"}
    page = (rep / "index.html").read_text()
    assert "<th>forward</th><th>smoothed</th>" in page and "0.123 m" in page
    assert page.count("data:image/png;base64,") == 4 and "src=\"http" not in page  # self-contained


def test_progress_line_only_on_a_terminal():
    from zennav.progress import Progress

    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty, pipe = Tty(), io.StringIO()
    for stream in (tty, pipe):
        p = Progress(100.0, "replay x", stream=stream, after_s=0.0, every_s=0.0)
        p.update(50.0)
        p.close()
    assert pipe.getvalue() == ""
    assert "50.0%" in tty.getvalue() and "ETA" in tty.getvalue() and tty.getvalue().endswith("\r\x1b[K")
    assert Progress(100.0, stream=tty, quiet=True).enabled is False
