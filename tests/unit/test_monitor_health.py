"""The monitor's health judgement (zennav.nodes.monitor): down, error, degraded (stale status; input flowing while
the work counter stands still; an ins not joined), running."""
from zennav import messages as M
from zennav.nodes.monitor import MonitorState, format_table

K = M.Keys("car")
S = 1_000_000_000  # ns per s


class Feed:
    """A MonitorState fed by hand, on a clock of our own [ns]."""

    def __init__(self):
        self.state = MonitorState(K, stall_s=3.0, stale_s=2.0)
        self.seq: dict[str, int] = {}

    def put(self, key: str, msg: dict, t_ns: int) -> None:
        self.seq[key] = self.seq.get(key, -1) + 1
        self.state.on_sample(key, M.encode({**msg, "src": f"p-{key}", "seq": self.seq[key], "pub_ns": t_ns}), t_ns)

    def status(self, service: str, t_ns: int, state: str = "running", **counters) -> None:
        self.put(K.svc_status(service), M.service_status_msg(service, state, counters=counters, t_ns=t_ns), t_ns)

    def imu(self, t_ns: int) -> None:
        self.put(K.imu(), M.make("imu", t_ns, cseq=t_ns // S, dt_ns=S, dtheta=[0.0] * 3, dvel=[0.0] * 3), t_ns)

    def health(self, service: str, now_ns: int) -> tuple[str, str]:
        d = self.state.snapshot(now_ns)["services"][service]
        return d["health"], d["why"]


def test_ins_progressing_then_not_joined_then_stalled_then_stale_then_down():
    f = Feed()
    f.state.on_alive("ins", True)
    t = 100 * S
    for i in range(5):  # IMU flows and the ins navigates it
        f.imu(t + i * S)
        f.status("ins", t + i * S, imu=100 * i, drop_no_stream=0)
    assert f.health("ins", t + 4 * S) == ("running", "")
    for i in range(5, 10):  # IMU flows, the ins drops it as not its stream
        f.imu(t + i * S)
        f.status("ins", t + i * S, imu=400, drop_no_stream=50 * (i - 4))
    h, why = f.health("ins", t + 9 * S)
    assert h == "degraded" and why.startswith("not joined: 150 samples dropped"), why
    for i in range(10, 15):  # IMU flows, nothing dropped, nothing navigated: stalled
        f.imu(t + i * S)
        f.status("ins", t + i * S, imu=400, drop_no_stream=250)
    h, why = f.health("ins", t + 14 * S)
    assert h == "degraded" and why.startswith("not progressing: sensor/imu/0 flowing") and "stuck at 400" in why
    for i in range(15, 20):  # the stream has ended: no input, nothing to do
        f.status("ins", t + i * S, imu=400, drop_no_stream=250)
    assert f.health("ins", t + 19 * S) == ("running", "")
    assert f.health("ins", t + 22 * S) == ("degraded", "no status for 3 s")  # alive, silent (hung)
    f.state.on_alive("ins", False)
    assert f.health("ins", t + 22 * S)[0] == "down"
    assert "degraded" not in format_table(f.state.snapshot(t + 22 * S))


def test_trainer_and_predictor_progress_and_error_state():
    f = Feed()
    for s in ("trainer", "predictor"):
        f.state.on_alive(s, True)
    t = 100 * S
    for i in range(6):
        f.put(K.learn_samples(), M.make("learn_sample", t + i * S, features=[1.0], target=[2.0], variant="drift"),
              t + i * S)
        f.status("trainer", t + i * S, received_drift=min(i, 2), version_drift=1)  # stops taking samples at 2
        f.status("predictor", t + i * S, queries_answered=0)  # no query flows: nothing expected of it
    h, why = f.health("trainer", t + 5 * S)
    assert h == "degraded" and "learn/samples" in why and "stuck at 2" in why
    assert f.health("predictor", t + 5 * S) == ("running", "")
    f.status("predictor", t + 6 * S, state="error")
    assert f.health("predictor", t + 6 * S)[0] == "error"
    table = format_table(f.state.snapshot(t + 6 * S))
    assert "degraded" in table and "error" in table


def test_the_table_says_what_the_alignment_waits_for():
    from zennav.nodes.monitor import format_table

    waiting = "in motion: GNSS speed at most 1.66 m/s so far, below align_min_speed_mps 3.00 m/s"
    al = {"state": "coarse", "method": "", "heading_std_deg": 103.9, "tilt_source": "levelling",
          "times_s": {"coarse": 0.0}, "initial_state": "", "waiting": waiting}
    snap = {"vehicle": "auv", "window_s": 5, "services": {}, "nav": {"gnss_state": "valid", "alignment": al},
            "navs": {}, "attitude": None, "aid": {}, "models": {}, "keys": {}}
    assert f"alignment waits for {waiting}" in format_table(snap)
    al["waiting"] = ""
    assert "waits for" not in format_table(snap)
