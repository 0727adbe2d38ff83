"""Fast paths for numeric text tables, over polars' multi-threaded CSV reader and writer (issue 17: np.loadtxt and
Python's %-formatting were most of a long replay's start and end).

- ``read_floats``: a table whose rows are the same number of numbers separated by one ``separator`` (what zennav's
  writers and most tools write); None for anything else (blank lines, runs of spaces, inline comments, a missing
  field, text), which the checked reader (zennav.datasets.errors.read_table) then parses and reports by line. polars
  parses with correctly rounded float conversion: the same float64 as np.loadtxt, bit for bit.
- ``table_text``: the text of a table, columns formatted with one %-spec each; ``%.<d>f`` columns through polars'
  float_precision output (exact decimal rounding of the binary value, ties to even: the same text as Python's %),
  any other spec with Python's %.

polars is imported on the first call for a table of MIN_BYTES or more only (about 0.2 s): a command that reads no
such table does not load it.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

HEAD_BYTES = 1 << 16  # [bytes] read to find the first data line and count its fields
MIN_BYTES = 1 << 20  # [bytes] smaller tables go to np.loadtxt: it reads them in less time than polars's import


def _field_count(path: Path, separator: str, comments: str) -> int | None:
    """Fields of the first data line (neither blank nor a comment line); None when there is none in HEAD_BYTES."""
    with open(path, "rb") as f:
        head = f.read(HEAD_BYTES).decode("utf-8", errors="replace")
    for line in head.splitlines()[:-1] if len(head) == HEAD_BYTES else head.splitlines():
        text = line.strip()
        if text and not text.startswith(comments):
            return len(line.rstrip("\r\n").split(separator))
    return None


def read_floats(path, columns: set[int], separator: str = " ", comments: str = "#") -> np.ndarray | None:
    """(N, columns) float64 of a plain numeric table (full-line ``comments`` allowed), C order; None where the file is
    not such a table, or its first line's field count is not in ``columns``, or it is compressed, or smaller than
    MIN_BYTES."""
    path = Path(path)
    if path.suffix == ".gz" or len(separator) != 1 or len(comments) != 1:
        return None
    try:
        if path.stat().st_size < MIN_BYTES:
            return None
        n = _field_count(path, separator, comments)
    except OSError:
        return None
    if n is None or n not in columns:
        return None
    import polars as pl

    try:
        df = pl.read_csv(path, has_header=False, separator=separator, comment_prefix=comments, quote_char=None,
                         schema={f"c{i}": pl.Float64 for i in range(n)}, raise_if_empty=True)
    except (pl.exceptions.PolarsError, OSError, ValueError):
        return None
    if len(df) == 0 or any(df.null_count().row(0)):  # a blank line or a missing field: the checked reader's case
        return None
    return np.ascontiguousarray(df.to_numpy(), dtype=np.float64)


def _fixed_series(columns: np.ndarray, decimals: list[int], separator: str) -> list:
    """polars string Series of runs of columns with the same decimals, each row of a run formatted ``%.<d>f`` and
    joined by separator (one polars write per run)."""
    import polars as pl

    out = []
    j = 0
    while j < columns.shape[1]:
        k = j
        while k < columns.shape[1] and decimals[k] == decimals[j]:
            k += 1
        df = pl.DataFrame(columns[:, j:k], schema=[f"c{i}" for i in range(j, k)], orient="row")
        text = df.write_csv(None, include_header=False, separator=separator, float_precision=decimals[j],
                            float_scientific=False, line_terminator="\n", quote_style="never")
        out.append(pl.Series(f"g{j}", [text]).str.split("\n").explode().head(len(columns)))  # no Python str per row
        j = k
    return out


_FIXED = re.compile(r"%\.(\d+)f")


def table_text(columns: np.ndarray, fmts: list[str], separator: str = " ", lead: str | None = None,
               ns: np.ndarray | None = None) -> str:
    """Text of a table, one ``\\n``-terminated line per row: ``lead`` (a constant first field, if given), ``ns``
    (int64 nanoseconds >= 0, if given) as exact decimal seconds ``%d.%09d``, then column j of ``columns`` (N, k)
    formatted with ``fmts[j]``, the fields joined by ``separator``. All-``%.<d>f`` finite columns go through polars;
    any other spec or a non-finite value, the whole table with Python's %."""
    columns = np.asarray(columns, dtype=np.float64).reshape(-1, len(fmts))
    n = len(columns)
    fixed = [_FIXED.fullmatch(f) for f in fmts]
    if n == 0 or not all(fixed) or not np.isfinite(columns).all():
        head = "" if lead is None else lead + separator
        if ns is not None:
            sec, frac = np.divmod(np.asarray(ns, dtype=np.int64), 1_000_000_000)
            head_rows = [f"{head}{a}.{b:09d}{separator}" for a, b in zip(sec.tolist(), frac.tolist())]
        else:
            head_rows = [head] * n
        fmt = separator.join(fmts) + "\n"
        return "".join(h + fmt % tuple(row) for h, row in zip(head_rows, columns.tolist()))
    import polars as pl

    fields = []
    if lead is not None:
        fields.append(pl.Series("lead", [lead] * n, dtype=pl.String))
    if ns is not None:
        sec, frac = np.divmod(np.asarray(ns, dtype=np.int64), 1_000_000_000)
        fields.append(pl.Series("s", sec).cast(pl.String) + "." + pl.Series("f", frac).cast(pl.String).str.zfill(9))
    fields += _fixed_series(columns, [int(m.group(1)) for m in fixed if m is not None], separator)
    df = pl.DataFrame([f.alias(f"f{i}") for i, f in enumerate(fields)])
    return df.write_csv(None, include_header=False, separator=separator, line_terminator="\n", quote_style="never")
