"""A progress line for long runs (replays, benchmarks) on stderr: done fraction, speed (times real time) and ETA.

Quiet unless the stream is a terminal, the run has taken longer than ``after_s``, and not ``quiet``; redrawn in
place (carriage return) at most every ``every_s``, so logs and pipes get no progress spam; ``close()`` clears it.
"""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Progress:
    """update(done_s) with the data seconds processed out of total_s [s of data] (a number, or a function that
    gives it when the line is first drawn)."""

    def __init__(self, total_s: float | Callable[[], float], label: str = "", stream: TextIO | None = None,
                 quiet: bool = False, after_s: float = 2.0, every_s: float = 0.5):
        self.stream = stream or sys.stderr
        self._total = total_s
        self.label = label
        self.enabled = not quiet and self.stream.isatty()
        self.after_s, self.every_s = after_s, every_s
        self.wall0 = time.monotonic()
        self._next = self.wall0 + after_s
        self.shown = False

    def update(self, done_s: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + self.every_s
        self.stream.write("\r" + self.line(done_s, now - self.wall0) + "\x1b[K")
        self.stream.flush()
        self.shown = True

    @property
    def total_s(self) -> float:
        if callable(self._total):
            self._total = self._total()
        return max(float(self._total), 1e-9)

    def line(self, done_s: float, wall_s: float) -> str:
        """The progress text after wall_s seconds with done_s of total_s data seconds processed."""
        frac = min(max(done_s / self.total_s, 0.0), 1.0)
        rate = done_s / wall_s if wall_s > 0 else 0.0
        eta = (self.total_s - done_s) / rate if rate > 0 else float("inf")
        width = 24
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        eta_txt = "--" if eta == float("inf") else f"{int(eta) // 60:d}:{int(eta) % 60:02d}"
        return f"{self.label} [{bar}] {100 * frac:5.1f}% {done_s:.0f}/{self.total_s:.0f} s, {rate:.0f}x real time, " \
               f"ETA {eta_txt}"

    @classmethod
    def of_replay(cls, ds, label: str, quiet: bool = False) -> Progress:
        """The progress of a replay of ds (zennav.replay.run_replay): pass ``on_epoch`` as its hook."""
        from .replay import run_end_ns

        t0_ns = int(ds.initial.t_ns)
        p = cls(lambda: (run_end_ns(ds) - t0_ns) / 1e9, label, quiet=quiet)  # the IMU data's end: when drawn
        p.t0_ns = t0_ns
        return p

    t0_ns = 0

    def on_epoch(self, nav) -> None:
        """run_replay's per-epoch hook: the data time the engine has reached."""
        self.update((nav.t_ns - self.t0_ns) / 1e9)

    def close(self) -> None:
        if self.shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
