"""A simulated GNSS receiver: a dataset's fixes sent as NMEA and/or UBX over a link, paced in time, optionally
degraded (few satellites, no fix) in windows: for tests and ``zennav gnss-sim`` (feeds ``zennav-ingest
--gnss-receiver`` without hardware).
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable

from ..nav.types import GnssFix
from .encode import nmea_sentences, ubx_frames

FEW_SATS = 3


def epoch_bytes(fix: GnssFix, fmt: str, few_sats: bool = False, no_fix: bool = False) -> bytes:
    """One epoch as a receiver sends it; fmt 'nmea', 'ubx' or 'both'; few_sats: FEW_SATS satellites; no_fix:
    GGA quality 0 / NAV-PVT fixType 0 (the position still sent)."""
    sats = FEW_SATS if few_sats else None
    out = b""
    if fmt in ("nmea", "both"):
        out += nmea_sentences(fix, quality=0 if no_fix else None, num_sats=sats)
    if fmt in ("ubx", "both"):
        out += ubx_frames(fix, fix_type=0 if no_fix else None, num_sats=sats)
    return out


def send_fixes(write: Callable[[bytes], object], fixes: Iterable[GnssFix], fmt: Callable[[GnssFix], str] | str,
               t0_ns: int, speed: float = 1.0, few_sats: list | tuple = (), no_fix: list | tuple = (),
               stop: Callable[[], bool] = lambda: False) -> int:
    """Write each fix at t0_ns-relative time / speed (speed 0: at once); few_sats / no_fix: [(start_ns, end_ns)]
    windows of degraded fixes; fmt a format or a function of the fix. Returns the number of epochs sent."""
    wall0 = time.perf_counter()
    n = 0
    for fix in fixes:
        if stop():
            break
        if speed > 0:
            delay = wall0 + (fix.t_ns - t0_ns) / 1e9 / speed - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        inside = [any(a <= fix.t_ns < b for a, b in w) for w in (few_sats, no_fix)]
        write(epoch_bytes(fix, fmt if isinstance(fmt, str) else fmt(fix), *inside))
        n += 1
    return n


def open_pty() -> tuple[int, int, str]:
    """A pseudo-terminal pair in raw mode (no echo, no line-end translation): (master fd to write to, slave fd,
    the slave's path a receiver link opens). Keep the slave fd open while writing: it holds the pair up."""
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def write_all(fd: int) -> Callable[[bytes], None]:
    """A writer of whole byte strings to a file descriptor."""
    def write(data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    return write
