"""A replay that starts on the head of a long IMU file (issue 17): the head reader keeps only complete lines (a chunk
that ends inside a line, CRLF, comments, commas), a file shorter than one chunk is read whole, the head is the
whole's first rows bit for bit (a changed file is a DataError), and a run that starts on the head gives the floats,
files and counters of a run on the whole."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from zennav.datasets import kfgins
from zennav.datasets.errors import DataError, read_table, read_table_head
from zennav.datasets.streamed import StreamedImu
from zennav.replay import event_plan, head_plan, run_replay
from zennav.sim.scenarios import make_dataset

ROWS = [[456300.0 + 0.005 * k, 1e-5 * k, -2.5e-6, 3.0e-7 * k, 0.001, -0.002, -0.049 - 1e-9 * k] for k in range(40)]


def _text(rows, sep=" ", eol="\n") -> str:
    return "".join(sep.join(f"{x:.17g}" for x in row) + eol for row in rows)


@pytest.mark.parametrize("sep, eol", [(" ", "\n"), (" ", "\r\n"), (",", "\n"), ("\t", "\r\n")])
def test_the_head_is_the_complete_lines_of_the_first_chunk(tmp_path, sep, eol):
    path = tmp_path / "imu.txt"
    text = "# header comment" + eol + _text(ROWS[:5], sep, eol) + "# a comment line" + eol + _text(ROWS[5:], sep, eol)
    path.write_bytes(text.encode())
    whole = read_table(path, 7, commas_as_space=True).data
    for nbytes in (len(text) // 3, len(text) // 3 + 1, text.index(eol, 1200) + len(eol)):  # mid-line, at a line end
        head = read_table_head(path, 7, nbytes, commas_as_space=True)
        assert head is not None
        complete = sum(not line.startswith(b"#") for line in text.encode()[:nbytes].split(b"\n")[:-1])
        assert len(head.data) == complete and np.array_equal(head.data, whole[:complete])
        assert head.line_of(5) == 8  # the line numbers of the file (its two comment lines counted)
    assert read_table_head(path, 7, len(text)) is None  # a file not longer than one chunk: read it whole
    assert read_table_head(path, 8, len(text) // 2) is None  # a wrong column count: the whole read's error


@pytest.fixture(scope="module")
def kf_yaml(tmp_path_factory) -> Path:
    """A 20 s car drive as KF-GINS files (the IMU file about 640 kB)."""
    return kfgins.write_dataset(make_dataset("car", duration_s=20.0, seed=3), tmp_path_factory.mktemp("kf"))


def _same(a, b) -> None:
    for name in ("t_ns", "llh", "v_n", "q_nb", "std_pos_ned", "outage"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.windows == b.windows and a.status["counters"] == b.status["counters"]
    assert [(r.t_ns, r.source, r.fused, r.reason) for r in a.reports] == \
        [(r.t_ns, r.source, r.fused, r.reason) for r in b.reports]


@pytest.mark.parametrize("loop", [None, "python"])
def test_a_run_started_on_the_head_is_the_run_on_the_whole(kf_yaml, monkeypatch, loop):
    yaml_path = kf_yaml
    whole = kfgins.load_config(yaml_path)
    assert not isinstance(whole.imu, StreamedImu)  # unless asked for
    monkeypatch.setattr(kfgins, "IMU_HEAD_BYTES", 40_000)  # about 1.3 s of the 20 s
    for outages, every in (((), None), (((1.2, 2.0),), None), ((), (10.0, 3.0, 1.1))):
        ds = kfgins.load_config(yaml_path, stream_imu=True)
        assert isinstance(ds.imu, StreamedImu) and ds.imu.pending
        head = head_plan(ds, ds.imu.head, outages, every)
        assert head is not None and head.inserts  # the head reaches the first GNSS fix
        runs = []
        for data in (ds, whole):
            seen: list[int] = []
            runs.append((run_replay(data, outages, every, loop=loop, on_epoch=lambda nav, seen=seen: seen.append(
                nav.t_ns), epoch_due=lambda: 2**62), seen))
        assert not ds.imu.pending and len(ds.gnss) == len(whole.gnss)
        _same(runs[0][0], runs[1][0])
        assert runs[0][1] == runs[1][1]  # on_epoch sees the same epochs (a stretch cut at the head's end is not one)
        assert (len(runs[0][1]) < len(runs[0][0].t_ns) // 10) == (loop == "python")  # stretches in the block loop


def test_the_head_plan_stops_at_endtime_and_before_outages(kf_yaml, monkeypatch):
    monkeypatch.setattr(kfgins, "IMU_HEAD_BYTES", 40_000)
    ds = kfgins.load_config(kf_yaml, stream_imu=True)
    assert isinstance(ds.imu, StreamedImu)
    t0, t_head = int(ds.initial.t_ns), ds.imu.head.t_ns
    plan = head_plan(ds, ds.imu.head)
    assert plan is not None and plan.k1 == len(t_head) - 1  # before the head's last sample
    cut = head_plan(ds, ds.imu.head, [(0.5, 1.0)])
    assert cut is not None and t_head[cut.k1 - 1] < t0 + 0.5e9 <= t_head[cut.k1]
    ds.config = ds.config.with_(end_t_ns=int(t_head[50]))
    end = head_plan(ds, ds.imu.head)
    assert end is not None and end.k1 == 51
    whole = event_plan(ds)
    assert (whole.k0, whole.k1, whole.inserts[:len(end.inserts)]) == (end.k0, end.k1, end.inserts)


def test_a_changed_file_and_a_late_defect_are_data_errors(tmp_path, monkeypatch):
    monkeypatch.setattr(kfgins, "IMU_HEAD_BYTES", 40_000)
    yaml_path = kfgins.write_dataset(make_dataset("car", duration_s=5.0, seed=3), tmp_path / "kf")
    ds = kfgins.load_config(yaml_path, stream_imu=True)
    imu_path = Path(ds.imu.source)
    lines = imu_path.read_text().splitlines(keepends=True)
    first = lines[0].split()
    first[1] = repr(float(first[1]) + 1e-3)
    imu_path.write_text(" ".join(first) + "\n" + "".join(lines[1:]))  # the head's first row changed
    with pytest.raises(DataError, match="changed while it was read"):
        run_replay(ds)
    imu_path.write_text("".join(lines[:-10] + ["1 2 3\n"] + lines[-10:]))  # a bad line after the head
    ds = kfgins.load_config(yaml_path, stream_imu=True)
    with pytest.raises(DataError, match=f"{imu_path}:{len(lines) - 9}: "):
        ds.imu.whole()
    imu_path.write_text("".join(lines[:-10] + lines[-11:]))  # a duplicated row after the head: a remark then
    ds = kfgins.load_config(yaml_path, stream_imu=True)
    assert not ds.notes["remarks"]
    run_replay(ds)
    assert ds.notes["remarks"] and "1 rows left out" in ds.notes["remarks"][0]


def test_the_command_words_what_it_finds_after_the_head(tmp_path, monkeypatch):
    """zennav replay: a remark on the rest of the file as a note, a defect in it as the command's error."""
    from click.testing import CliRunner

    from zennav.cli import main

    monkeypatch.setattr(kfgins, "IMU_HEAD_BYTES", 40_000)
    yaml_path = kfgins.write_dataset(make_dataset("car", duration_s=5.0, seed=3), tmp_path / "kf")
    imu_path = next((tmp_path / "kf").glob("*_imu.txt"))
    lines = imu_path.read_text().splitlines(keepends=True)
    imu_path.write_text("".join(lines[:-10] + lines[-11:]))  # a duplicated row after the head
    r = CliRunner().invoke(main, ["replay", str(yaml_path), "-q", "--out", str(tmp_path / "out")])
    assert r.exit_code == 0 and f"note: {imu_path.name}: 1 rows left out" in r.output
    imu_path.write_text("".join(lines[:-10] + ["1 2 3\n"] + lines[-10:]))
    r = CliRunner().invoke(main, ["replay", str(yaml_path), "-q", "--out", str(tmp_path / "out")])
    assert r.exit_code == 1 and f"{imu_path}:{len(lines) - 9}: line has 3 columns" in r.output
