"""Group a receiver's messages into epochs: the messages with one time tag (NMEA GGA/RMC/GST/VTG of one second,
UBX NAV-PVT and NAV-COV of one iTOW) make one fix.

An epoch closes when a message with another time tag arrives, or as soon as it holds every message type the
last naturally closed epoch held (a receiver repeats its output set every epoch), so a fix is handed over when
its last sentence arrives instead of one epoch later.
"""
from __future__ import annotations

from collections import Counter

from ..nav.types import GnssFix


class EpochAssembler:
    """add(tag, kind, msg) -> the epochs completed by it (dicts kind -> msg), oldest first; flush() -> the open one."""

    def __init__(self) -> None:
        self.tag: object = None
        self.parts: dict[str, object] = {}
        self.cycle: frozenset[str] = frozenset()

    def add(self, tag, kind: str, msg) -> list[dict]:
        out = []
        if self.parts and tag != self.tag:
            self.cycle = frozenset(self.parts)
            out.append(self._close())
        self.tag = tag
        self.parts[kind] = msg
        if self.cycle and self.cycle <= self.parts.keys():
            out.append(self._close())
        return out

    def flush(self) -> list[dict]:
        return [self._close()] if self.parts else []

    def _close(self) -> dict:
        parts, self.parts = self.parts, {}
        return parts


class EpochDecoder:
    """Base of a receiver protocol's decoder: its messages grouped into epochs (EpochAssembler), each epoch made a
    fix by the protocol's ``_fix``; ref_t_ns [GPS ns] resolves partial time tags, the last fix's time once there
    is one; counts by message kind and rejection reason."""

    def __init__(self, ref_t_ns: int | None = None) -> None:
        self.ref_t_ns = ref_t_ns
        self.epochs = EpochAssembler()
        self.counts: Counter[str] = Counter()

    def flush(self) -> list[GnssFix]:
        """The fix of the epoch still open (end of the input)."""
        return self._fixes(self.epochs.flush())

    def _fixes(self, epochs: list[dict]) -> list[GnssFix]:
        out = []
        for parts in epochs:
            fix = self._fix(parts)
            if fix is not None:
                out.append(fix)
                self.ref_t_ns = fix.t_ns
        return out

    def _fix(self, parts: dict) -> GnssFix | None:
        raise NotImplementedError
