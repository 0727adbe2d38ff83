"""Fast paths for numeric text tables (issue 17: np.loadtxt and Python's %-formatting were most of a long replay's
start and end).

- ``read_floats``: a table whose rows are the same number of numbers separated by one ``separator`` (what zennav's
  writers and most tools write), through polars' multi-threaded CSV reader; None for anything else (blank lines,
  runs of spaces, inline comments, a missing field, text), which the checked reader
  (zennav.datasets.errors.read_table) then parses and reports by line. polars parses with correctly rounded float
  conversion: the same float64 as np.loadtxt, bit for bit.
- ``table_chunks`` (``table_bytes``, ``write_table``): the text of a table, columns formatted with one %-spec each,
  Python's %-text byte for byte: ``%.<d>f`` columns by integer arithmetic in numpy (the exact decimal rounding of
  each binary value, ties to even), any other spec with Python's %.
- ``in_background``: a read or a write in zennav's one I/O thread, beside the caller (polars parses and numpy formats
  without holding the GIL).

polars is imported on the first call for a table of MIN_BYTES or more only (about 0.2 s): a command that reads no
such table does not load it.
"""
from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TypeVar

import numpy as np

HEAD_BYTES = 1 << 16  # [bytes] read to find the first data line and count its fields
MIN_BYTES = 1 << 20  # [bytes] smaller tables go to np.loadtxt: it reads them in less time than polars's import


T = TypeVar("T")
_io: ThreadPoolExecutor | None = None


def in_background(job: Callable[[], T]) -> Future[T]:
    """job() in zennav's I/O thread, after the jobs asked for before it (one thread: files read or written beside the
    caller's work, polars and numpy running without the GIL); its Future's result() waits for its value or raises its
    error. A job must not wait for a later one (the thread runs them in order)."""
    global _io
    if _io is None:
        _io = ThreadPoolExecutor(max_workers=1, thread_name_prefix="zennav-io")
    return _io.submit(job)


def _field_count(data: bytes, separator: str, comments: str) -> int | None:
    """Fields of the first data line (neither blank nor a comment line) of a table's bytes; None when there is none
    in their first HEAD_BYTES."""
    head = data[:HEAD_BYTES].decode("utf-8", errors="replace")
    for line in head.splitlines()[:-1] if len(data) > HEAD_BYTES else head.splitlines():
        text = line.strip()
        if text and not text.startswith(comments):
            return len(line.rstrip("\r\n").split(separator))
    return None


def read_floats(path, columns: set[int], separator: str = " ", comments: str = "#") -> np.ndarray | None:
    """(N, columns) float64 of a plain numeric table (full-line ``comments`` allowed), C order; None where the file is
    not such a table, or its first line's field count is not in ``columns``, or it is compressed, or smaller than
    MIN_BYTES. A file without the comment character parses without comment handling (about half the time)."""
    path = Path(path)
    if path.suffix == ".gz" or len(separator) != 1 or len(comments) != 1:
        return None
    try:
        if path.stat().st_size < MIN_BYTES:
            return None
        data = path.read_bytes()
    except OSError:
        return None
    n = _field_count(data, separator, comments)
    if n is None or n not in columns:
        return None
    import polars as pl

    try:
        df = pl.read_csv(data, has_header=False, separator=separator, quote_char=None, raise_if_empty=True,
                         comment_prefix=comments if comments.encode() in data else None,
                         schema={f"c{i}": pl.Float64 for i in range(n)})
    except (pl.exceptions.PolarsError, OSError, ValueError):
        return None
    if len(df) == 0 or any(df.null_count().row(0)):  # a blank line or a missing field: the checked reader's case
        return None
    return np.ascontiguousarray(df.to_numpy(), dtype=np.float64)


_FIXED = re.compile(r"%\.(\d+)f")
_POW10 = 10 ** np.arange(19, dtype=np.int64)  # 1 .. 10**18
_VELTKAMP = 134217729.0  # 2**27 + 1: splits a double into two halves of 26 bits (Veltkamp, in Dekker 1971)
CHUNK = 40_000  # rows formatted at once: their bytes stay in the CPU's cache (a power of 2 would thrash it)


def _halves(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Veltkamp's split a = hi + lo, each of at most 26 significant bits (their products are exact)."""
    c = _VELTKAMP * a
    hi = c - (c - a)
    return hi, a - hi


def _scaled(x: np.ndarray, d: int) -> np.ndarray:
    """round(|x| 10^d) of the exact product, half to even (the digits ``%.<d>f`` prints), as int64; for |x| 10^d below
    2^52.

    y = fl(|x| 10^d) is the double nearest the exact product z, and below 2^52 every half-integer is a double: so z
    and y round to the same integer unless y is a half-integer. There the product's rounding error e = z - y,
    exact by Dekker's two-product (Dekker 1971; Ogita, Rump and Oishi 2005), decides: e = 0 is a true tie."""
    p = 10.0**d
    a = np.abs(x)
    y = a * p
    r = np.rint(y)  # half to even
    t = y - r  # exact
    tie = np.flatnonzero(np.abs(t) == 0.5)
    if tie.size:
        (ah, al), (ph, pl) = _halves(a[tie]), _halves(np.float64(p))
        e = ((ah * ph - y[tie]) + ah * pl + al * ph) + al * pl
        r[tie] += ((t[tie] > 0) & (e > 0)).astype(float) - ((t[tie] < 0) & (e < 0))
    return r.astype(np.int64)


def _width(m: int) -> int:
    """Decimal digits of m >= 0, at least 1."""
    return max(1, int(np.searchsorted(_POW10, m, side="right")))


def _put_digits(rows: np.ndarray, m: np.ndarray, blank: bool) -> None:
    """The decimal digits of m (int64, 0 <= m < 10**width) as ASCII into rows (width, N) uint8, units last; blank: the
    zeros before the first digit (the units' kept) as 0 bytes (dropped later), else printed. Eight digits at a time
    in uint32 (numpy divides by a constant fast)."""
    w = len(rows)
    rest = m
    for lo in range(0, w, 8):
        if lo + 8 < w:
            up = rest // 100_000_000
            c = (rest - up * 100_000_000).astype(np.uint32)
            rest = up
        else:
            c = rest.astype(np.uint32)
        for p in range(lo, min(lo + 8, w)):
            q = c // 10
            digit = c - q * 10
            c = q
            if blank and p:
                rows[w - 1 - p] = np.where(m >= _POW10[p], digit + 48, 0)
            else:
                np.add(digit, 48, out=rows[w - 1 - p], casting="unsafe")


def _python_lines(columns: list[np.ndarray], fmts: list[str], separator: str, lead: str | None,
                  ns: np.ndarray | None) -> str:
    """table_chunks' text by Python's %, row by row."""
    head = "" if lead is None else lead + separator
    n = len(columns[0])
    if ns is not None:
        sec, frac = np.divmod(ns, 1_000_000_000)
        head_rows = [f"{head}{a}.{b:09d}{separator}" for a, b in zip(sec.tolist(), frac.tolist())]
    else:
        head_rows = [head] * n
    fmt = separator.join(fmts) + "\n"
    return "".join(h + fmt % tuple(row) for h, row in zip(head_rows, np.column_stack(columns).tolist()))


def table_chunks(columns: Sequence[np.ndarray], fmts: list[str], separator: str = " ", lead: str | None = None,
                 ns: np.ndarray | None = None) -> Iterator[bytes]:
    """UTF-8 text of a table in pieces of whole lines, one ``\\n``-terminated line per row: ``lead`` (a constant first
    field, if given), ``ns`` (int64 nanoseconds >= 0, if given) as exact decimal seconds ``%d.%09d``, then
    ``columns[j]`` (N,) formatted with ``fmts[j]``, the fields joined by ``separator``: Python's %-text byte for byte.
    Finite ``%.<d>f`` columns (d <= 17, |x| 10^d < 2^52) are formatted by integer arithmetic in numpy (_scaled: the
    exact decimal rounding), CHUNK rows at a time, each field right-aligned in its widest place, the unused bytes
    dropped; any other spec or value, the whole table with Python's %."""
    cols = [np.ascontiguousarray(c, dtype=np.float64).reshape(-1) for c in columns]
    ns = None if ns is None else np.asarray(ns, dtype=np.int64)
    n = len(cols[0])
    fixed = [_FIXED.fullmatch(f) for f in fmts]
    decimals = [int(m.group(1)) if m is not None else 99 for m in fixed]
    peaks = [float(np.abs(c).max()) if n else 0.0 for c in cols]  # nan if any is
    if not n or max(decimals) > 17 or not all(p * 10.0**d < 2.0**52 for p, d in zip(peaks, decimals)):
        if n:
            yield _python_lines(cols, fmts, separator, lead, ns).encode()
        return
    # a number: (column or None, decimals, width of its integer part, whether it has a sign place)
    numbers: list[tuple[np.ndarray | None, int, int, bool]] = \
        [] if ns is None else [(None, 9, _width(int(ns.max()) // 1_000_000_000), False)]
    numbers += [(c, d, _width(int(_scaled(np.array([p]), d)[0]) // 10**d), bool(np.signbit(c).any()))
                for c, d, p in zip(cols, decimals, peaks)]
    head = np.frombuffer(b"" if lead is None else (lead + separator).encode(), dtype=np.uint8)
    sep = np.frombuffer(separator.encode(), dtype=np.uint8)
    at, places = len(head), []  # a line's byte places: [sign] integer digits [. fraction digits] separator ...
    for _, d, w_int, signed in numbers:
        digits = slice(at + signed, at + signed + w_int)  # the sign before them
        places.append((digits, slice(digits.stop + 1, digits.stop + 1 + d)))
        at = digits.stop + (d + 1 if d else 0) + len(sep)
    for a in range(0, n, CHUNK):  # the lines' bytes place by place ((place, line): contiguous writes)
        b = min(n, a + CHUNK)
        buf = np.empty((at - len(sep) + 1, b - a), dtype=np.uint8)
        buf[:len(head)] = head[:, None]
        for (c, d, _, signed), (digits, fraction) in zip(numbers, places):
            if c is None:  # ns
                assert ns is not None
                m = ns[a:b]
            else:
                m = _scaled(c[a:b], d)
                if signed:  # -0.0 and what rounds to 0 keep their sign, as with %
                    buf[digits.start - 1] = np.where(np.signbit(c[a:b]), ord("-"), 0)
            q = m // 10**d
            _put_digits(buf[digits], q, True)
            if d:
                buf[digits.stop] = ord(".")
                _put_digits(buf[fraction], m - q * 10**d, False)
            end = fraction.stop if d else digits.stop
            buf[end:end + len(sep)] = sep[:, None]
        buf[-1] = ord("\n")
        lines = np.ascontiguousarray(buf.T).reshape(-1)
        yield lines[lines != 0].tobytes()  # the unused bytes (0) out


def table_bytes(columns: Sequence[np.ndarray], fmts: list[str], separator: str = " ", lead: str | None = None,
                ns: np.ndarray | None = None) -> bytes:
    """table_chunks' text in one piece."""
    return b"".join(table_chunks(columns, fmts, separator, lead, ns))


def write_table(path, columns: Sequence[np.ndarray], fmts: list[str], separator: str = " ", lead: str | None = None,
                ns: np.ndarray | None = None, header: str = "") -> None:
    """A file of ``header`` then table_chunks' text."""
    with open(path, "wb") as f:
        f.write(header.encode())
        for piece in table_chunks(columns, fmts, separator, lead, ns):
            f.write(piece)
