"""User-input errors of the loaders, and the checked text-table reader that raises them.

Every mistake in a user's file (missing file, wrong column count, unparsable text, NaN/inf, time not
strictly increasing, missing YAML key) becomes one ``DataError`` whose str is ``"path:line: message"``.
"""
from __future__ import annotations

import gzip
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zennav.datasets.fasttext import read_floats


class DataError(Exception):
    """A problem in a user's data or configuration file; ``line`` is 1-based or None."""

    def __init__(self, path, message: str, line: int | None = None):
        self.path = str(path)
        self.line = line
        self.message = message
        super().__init__(str(self))

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.message}"


def existing_file(path) -> Path:
    """``path`` as a Path, or DataError when it is not a readable file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "file not found" if not path.exists() else "not a regular file")
    return path


def read_text(path) -> str:
    """Whole text of a file (UTF-8; a ``.gz`` file is decompressed first); DataError when missing or not text."""
    path = existing_file(path)
    try:
        if path.suffix == ".gz":
            with gzip.open(path, "rt", encoding="utf-8") as f:
                return f.read()
        return path.read_text(encoding="utf-8")
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise DataError(path, f"cannot read as text: {exc}") from None


@dataclass
class Table:
    """Rows of a numeric text file: ``data`` (N, columns) float64, ``text`` (N, text_cols) str.

    ``line_of(row)`` gives the 1-based file line of a data row, for error messages.
    """

    path: Path
    data: np.ndarray
    text: np.ndarray | None
    _lines: list[str] | None
    _first_line: int
    _comments: str
    _row_lines: list[int] | None = field(default=None, repr=False)

    def line_of(self, row: int) -> int:
        if self._row_lines is None:
            if self._lines is None:
                self._lines = read_text(self.path).splitlines()
            self._row_lines = [n for n, _ in _data_lines(self._lines, self._first_line, self._comments)]
        return self._row_lines[row]

    def error(self, row: int, message: str) -> DataError:
        return DataError(self.path, message, self.line_of(row))

    def require_finite(self) -> None:
        bad = np.flatnonzero(~np.isfinite(self.data).all(axis=1))
        if bad.size:
            raise self.error(int(bad[0]), "value is NaN or infinite")

    def require_increasing(self, t_ns: np.ndarray, what: str = "time") -> None:
        """DataError at the first row whose ``t_ns`` [ns] is not after the previous row's."""
        bad = np.flatnonzero(np.diff(t_ns) <= 0)
        if bad.size:
            k = int(bad[0]) + 1
            raise self.error(k, f"{what} {t_ns[k] / 1e9:.9f} s is not after the previous {t_ns[k - 1] / 1e9:.9f} s")


def _data_lines(lines: list[str], first_line: int, comments: str):
    """(1-based line number, content without comment) of every non-blank, non-comment line."""
    for i, line in enumerate(lines):
        content = line.split(comments, 1)[0].strip()
        if content:
            yield first_line + i, content


def _split(content: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return content.split()
    return [tok.strip() for tok in content.split(delimiter)]


def _column_message(found: int, columns: set) -> str:
    return f"line has {found} columns, expected {' or '.join(str(c) for c in sorted(columns))}"


def _find_bad_line(path, lines, first_line, columns, delimiter, comments, text_cols) -> DataError | None:
    """Rescan after a failed fast parse: the first line with a wrong column count or an unparsable number."""
    expected = None
    for number, content in _data_lines(lines, first_line, comments):
        tokens = _split(content, delimiter)
        if expected is None:
            if len(tokens) not in columns:
                return DataError(path, _column_message(len(tokens), columns), number)
            expected = len(tokens)
        elif len(tokens) != expected:
            return DataError(path, f"line has {len(tokens)} columns, expected {expected} like the first data line",
                             number)
        for col, tok in enumerate(tokens[text_cols:], start=text_cols + 1):
            try:
                float(tok)
            except ValueError:
                return DataError(path, f"cannot parse {tok!r} in column {col} as a number", number)
    return None


def read_table(
    path,
    columns,
    *,
    delimiter: str | None = None,
    comments: str = "#",
    skip_header: int = 0,
    skip_footer: int = 0,
    text_cols: int = 0,
    commas_as_space: bool = False,
) -> Table:
    """Read a numeric text table fast (a plain table: fasttext.read_floats; else np.loadtxt), rescanning only on failure
    to name the bad line.

    columns: the accepted column count, or a set of them (all rows must have the same count).
    delimiter None splits on whitespace; commas_as_space also accepts commas (KF-GINS splits on ", \\t").
    skip_header/skip_footer drop whole lines at the start/end, as numpy.genfromtxt does.
    text_cols: leading columns kept as strings in ``Table.text`` (e.g. RTKLIB date and time).
    Blank lines and text after ``comments`` are ignored. Raises DataError on any defect.
    """
    path = existing_file(path)
    columns = {columns} if isinstance(columns, int) else set(columns)
    lines = None
    fast = skip_header == 0 and skip_footer == 0 and text_cols == 0
    data = read_floats(path, columns, delimiter or " ", comments) if fast else None
    if data is not None:
        return Table(path, data, None, None, 1, comments)
    if not fast:
        all_lines = read_text(path).splitlines()
        lines = all_lines[skip_header : len(all_lines) - skip_footer]
    try:
        data, text = _loadtxt(path if fast else lines, columns, delimiter, comments, text_cols)
    except ValueError as exc:
        if lines is None:
            lines = read_text(path).splitlines()
        parsed = None
        if commas_as_space:
            lines = [line.replace(",", " ") for line in lines]
            try:
                parsed = _loadtxt(lines, columns, delimiter, comments, text_cols)
            except ValueError:
                pass
        if parsed is None:
            error = _find_bad_line(path, lines, skip_header + 1, columns, delimiter, comments, text_cols)
            raise (error or DataError(path, f"cannot parse the table: {exc}")) from None
        data, text = parsed
    table = Table(path, data, text, lines, skip_header + 1, comments)
    if len(data) == 0:
        raise DataError(path, "no data rows")
    ncols = data.shape[1] + text_cols
    if ncols not in columns:
        raise table.error(0, _column_message(ncols, columns))
    return table


def read_table_head(path, columns, nbytes: int, *, comments: str = "#", commas_as_space: bool = False) -> Table | None:
    """The complete lines within the first ``nbytes`` of a whole-table file (read_table without header, footer or
    text columns), parsed with np.loadtxt (no fast reader to import; the same float64 as read_table's): a Table of
    their rows, whose line_of works. None when the file is not longer than nbytes (read it whole), is compressed, or
    its head has no data row or a defect (read_table then reports it by line)."""
    path = existing_file(path)
    columns = {columns} if isinstance(columns, int) else set(columns)
    if path.suffix == ".gz":
        return None
    try:
        with open(path, "rb") as f:
            raw = f.read(nbytes + 1)
        lines = raw[:raw.rfind(b"\n", 0, nbytes) + 1].decode("utf-8").splitlines()  # complete lines only
    except (OSError, UnicodeDecodeError):
        return None
    if len(raw) <= nbytes:
        return None
    for source in [lines] + ([[line.replace(",", " ") for line in lines]] if commas_as_space else []):
        try:
            data, _ = _loadtxt(source, columns, None, comments, 0)
        except ValueError:
            continue
        if len(data) and data.shape[1] in columns:
            return Table(path, data, None, lines, 1, comments)
    return None


def _loadtxt(source, columns, delimiter, comments, text_cols):
    """np.loadtxt into (float data, str text or None); raises ValueError on any malformed line."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "input contained no data": reported by the caller
        if text_cols == 0:
            data = np.loadtxt(source, dtype=float, delimiter=delimiter, comments=comments, ndmin=2)
            return data, None
        (ncols,) = columns
        dtype = [(f"s{i}", "U64") for i in range(text_cols)] + [(f"f{i}", "f8") for i in range(ncols - text_cols)]
        rec = np.loadtxt(source, dtype=dtype, delimiter=delimiter, comments=comments, ndmin=1)
    names = rec.dtype.names
    text = np.stack([rec[n] for n in names[:text_cols]], axis=1)
    data = np.stack([rec[n] for n in names[text_cols:]], axis=1)
    return data, text

