"""IMU data read in two steps, so that a replay starts before a long file is parsed (issue 17: the first sample
within a second of the process start).

A loader returns a ``StreamedImu``: its ``head`` (the first rows, parsed at once without the fast table reader's
import) and a function that reads the whole. ``zennav.replay.run_replay`` runs the samples it can place from the
head (``pending``) while the whole is read in the background (``prefetch``: zennav.datasets.fasttext's I/O thread,
where polars parses without holding the GIL), then takes the whole; any other use of ``t_ns``, ``dtheta`` or
``dvel`` reads the whole first. The whole must begin with the head's rows, bit for bit (else a DataError: the file
changed between the reads).
"""
from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future

import numpy as np

from zennav.datasets.errors import DataError
from zennav.datasets.fasttext import in_background
from zennav.nav.types import ImuData


class StreamedImu(ImuData):
    """ImuData whose whole is read on first use; ``head``: its first rows (ImuData), ``source``: the file, ``span_s``:
    the whole's time span [s] as the loader estimates it (the file's length at the head's bytes per second), for what
    a run decides before the whole is read (zennav.replay: whether the compiled loop loads beside the read)."""

    def __init__(self, head: ImuData, read_whole: Callable[[], ImuData], source: str,
                 on_whole: Callable[[ImuData], None] | None = None, span_s: float = 0.0):
        # no ImuData.__init__: its fields are the whole's, read on first use
        self.head = head
        self.source = source
        self.span_s = span_s
        self._read_whole: Callable[[], ImuData] | None = read_whole
        self._on_whole = on_whole
        self._whole: ImuData | None = None
        self._reading: Future[ImuData] | None = None

    @property
    def pending(self) -> bool:
        """Whether only the head has been read."""
        return self._whole is None

    def prefetch(self) -> None:
        """Start reading the whole in the I/O thread (fasttext.in_background), if it is not read or being read: whole()
        then waits for it."""
        if self._whole is None and self._reading is None:
            assert self._read_whole is not None
            self._reading = in_background(self._read_whole)

    def whole(self) -> ImuData:
        """The whole data (read now if not yet, or taken from prefetch; then on_whole(whole) runs once)."""
        if self._whole is None:
            assert self._read_whole is not None
            whole = self._read_whole() if self._reading is None else self._reading.result()
            n = len(self.head)
            same = len(whole) >= n and all(np.array_equal(getattr(whole, a)[:n], getattr(self.head, a))
                                           for a in ("t_ns", "dtheta", "dvel"))
            if not same:
                raise DataError(self.source, f"the first {n} samples differ from those read at the start: the file "
                                             f"changed while it was read")
            self._whole, self._read_whole = whole, None
            if self._on_whole is not None:
                self._on_whole(whole)
        return self._whole

    @property
    def t_ns(self) -> np.ndarray:  # type: ignore[override]
        return self.whole().t_ns

    @property
    def dtheta(self) -> np.ndarray:  # type: ignore[override]
        return self.whole().dtheta

    @property
    def dvel(self) -> np.ndarray:  # type: ignore[override]
        return self.whole().dvel
