"""A replay's start and its files (issue 17): the polars reader gives np.loadtxt's floats bit for bit and hands every
irregular file to the checked reader; the numpy formatter writes Python's %-text byte for byte; a KF-GINS truth
read after the run is the one read before; the block loop that loads numba after its first stretch gives the Python
loop's floats."""
from __future__ import annotations

import gzip

import numpy as np
import pytest

from zennav.datasets import fasttext, kfgins
from zennav.datasets.errors import read_table
from zennav.datasets.fasttext import read_floats, table_bytes
from zennav.datasets.streamed import StreamedImu
from zennav.replay import run_replay
from zennav.sim.scenarios import make_dataset


def _values(seed: int, n: int) -> np.ndarray:
    """Awkward doubles: wide magnitudes, both signs, -0.0, dyadic values that are exact decimal ties at 4 to 13
    decimals (k / 2**m has exactly m decimals), and decimal halves (k + 0.5) / 10**j, whose products by 10**j are
    doubles at a half though the exact ones are not (a tie in the float product only)."""
    rng = np.random.default_rng(seed)
    wide = rng.normal(size=n) * 10.0 ** rng.integers(-12, 9, size=n)
    ties = rng.integers(-10**6, 10**6, size=n) / 2.0 ** rng.integers(5, 15, size=n)
    halves = (rng.integers(-10**6, 10**6, size=n) + 0.5) / 10.0 ** rng.integers(0, 7, size=n)
    return np.concatenate([[0.0, -0.0, 0.5, -2.5, -1e-20, 1e15 + 0.5], wide, ties, halves])


def test_plain_tables_parse_to_the_loadtxt_floats(tmp_path, monkeypatch):
    v = _values(1, 3000).reshape(-1, 6)  # 9006 values
    path = tmp_path / "t.txt"
    lines = [" ".join(f"{x:.17g}" if k % 2 else f"{x:.16e}" for x in row) for k, row in enumerate(v)]
    path.write_text("# a comment line\n" + "\n".join(lines) + "\n")
    assert read_floats(path, {6}) is None  # under MIN_BYTES: np.loadtxt's, polars not imported for it
    monkeypatch.setattr(fasttext, "MIN_BYTES", 0)
    got = read_floats(path, {6})
    assert got is not None and got.flags.c_contiguous
    assert np.array_equal(got, np.loadtxt(path, ndmin=2)) and np.array_equal(got, v)
    assert read_floats(path, {7}) is None  # the checked reader words the column count
    csv = tmp_path / "t.csv"
    csv.write_text("\n".join(",".join(f"{x:.17g}" for x in row) for row in v) + "\r\n")
    assert np.array_equal(read_floats(csv, {6}, ","), v)


@pytest.mark.parametrize("text", ["1 2 3\n\n4 5 6\n", "1  2 3\n4 5 6\n", "1 2 3 # x\n4 5 6\n", "1\t2 3\n4 5 6\n",
                                  " 1 2 3\n4 5 6\n", "1 2 3 \n4 5 6\n"])
def test_irregular_tables_go_to_the_checked_reader(tmp_path, monkeypatch, text):
    monkeypatch.setattr(fasttext, "MIN_BYTES", 0)
    path = tmp_path / "t.txt"
    path.write_text(text)
    assert read_floats(path, {3}) is None
    assert np.array_equal(read_table(path, 3).data, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    gz = tmp_path / "t.txt.gz"
    gz.write_bytes(gzip.compress(b"1 2 3\n"))
    assert read_floats(gz, {3}) is None


def _percent(cols, fmts, separator=" ", lead=None, ns=None) -> bytes:
    """The table by Python's %, line by line."""
    head = "" if lead is None else lead + separator
    heads = [head] * len(cols) if ns is None else [f"{head}{t // 10**9}.{t % 10**9:09d}{separator}"
                                                   for t in ns.tolist()]
    return "".join(h + separator.join(fmts) % tuple(r) + "\n" for h, r in zip(heads, cols.tolist())).encode()


def test_fixed_columns_are_the_percent_text(monkeypatch):
    monkeypatch.setattr(fasttext, "CHUNK", 1000)  # several chunks
    v = _values(2, 2000)
    v = v[np.abs(v) < 1e5]  # |x| 10^d under 2**52 at d = 10: numpy's integers
    cols = np.column_stack([v, v[::-1], v * 3.0, np.abs(v) % 1.0, -np.abs(v)])
    fmts = ["%.4f", "%.10f", "%.7f", "%.0f", "%.1f"]
    ns = np.arange(len(v), dtype=np.int64) * 5_000_001 + 7
    python_lines = fasttext._python_lines
    monkeypatch.setattr(fasttext, "_python_lines", None)  # numpy's integers only (Python's % would fail)
    assert table_bytes(list(cols.T), fmts, " ", "0", ns) == _percent(cols, fmts, " ", "0", ns)
    assert table_bytes(list(cols.T), fmts, ",") == _percent(cols, fmts, ",")
    monkeypatch.setattr(fasttext, "_python_lines", python_lines)
    big = np.column_stack([_values(3, 500), _values(4, 500)])  # 1e15 + 0.5 at 13 decimals: Python's % for the table
    assert table_bytes(list(big.T), ["%.13f", "%.2f"]) == _percent(big, ["%.13f", "%.2f"])
    cols[5, 2] = np.nan  # not finite, or another spec: Python's % for the whole table
    assert table_bytes(list(cols.T), fmts) == _percent(cols, fmts)
    sci = ["%.3e", "%.2f"]
    assert table_bytes(list(cols[:, :2].T), sci) == _percent(cols[:, :2], sci)
    assert table_bytes([np.empty(0), np.empty(0)], ["%.3f", "%.2f"], ns=np.empty(0, dtype=np.int64)) == b""


def test_truth_read_after_the_run_is_the_truth(tmp_path, monkeypatch):
    """Read after the run, or in the I/O thread once a streamed IMU file has been read (zennav replay's way)."""
    yaml_path = kfgins.write_dataset(make_dataset("car", duration_s=20.0, seed=3), tmp_path, "car")
    now = kfgins.load_config(yaml_path)
    monkeypatch.setattr(kfgins, "IMU_HEAD_BYTES", 40_000)  # the 20 s IMU file streamed
    for stream in (False, True):
        later = kfgins.load_config(yaml_path, defer_truth=True, stream_imu=stream)
        assert later.truth is None and now.truth is not None
        if stream:
            assert isinstance(later.imu, StreamedImu) and abs(later.imu.span_s - 20.0) < 0.5  # its estimate
            later.imu.prefetch()
            later.imu.whole()
            assert "reading" in later.notes["truth_file"]  # the truth file read beside
        kfgins.load_deferred_truth(later)
        assert "truth_file" not in later.notes
        for name in ("t_ns", "llh", "v_n", "euler"):
            assert np.array_equal(getattr(later.truth, name), getattr(now.truth, name))
        assert (later.truth.source, later.truth.at_antenna) == (now.truth.source, now.truth.at_antenna)


def test_block_loop_that_loads_numba_after_its_first_stretch_gives_the_python_floats():
    ds = make_dataset("car", duration_s=60.0, seed=5)
    a = run_replay(ds, outages=[(20.0, 15.0)], loop="python")
    b = run_replay(ds, outages=[(20.0, 15.0)], loop="lazy")
    for x, y in ((a.t_ns, b.t_ns), (a.llh, b.llh), (a.v_n, b.v_n), (a.q_nb, b.q_nb), (a.std_pos_ned, b.std_pos_ned),
                 (a.outage, b.outage)):
        assert np.array_equal(x, y)
    assert a.status["counters"] == b.status["counters"]


def test_an_epoch_hook_that_wants_every_epoch_sees_every_epoch():
    """epoch_due() None (an MCAP recording): on_epoch sees every epoch in any loop, the block loop's too."""
    ds = make_dataset("car", duration_s=5.0, seed=5)
    seen: dict[str, list[int]] = {"step": [], "python": []}
    for loop, times in seen.items():
        res = run_replay(ds, loop=loop, on_epoch=lambda nav, times=times: times.append(nav.t_ns),
                         epoch_due=lambda: None)
        assert times == res.t_ns.tolist()
