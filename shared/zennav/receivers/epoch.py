"""Group a receiver's messages into epochs: the messages with one time tag (NMEA GGA/RMC/GST/VTG of one second,
UBX NAV-PVT and NAV-COV of one iTOW) make one fix.

An epoch closes when a message with another time tag arrives, or as soon as it holds every message type the
last naturally closed epoch held (a receiver repeats its output set every epoch), so a fix is handed over when
its last sentence arrives instead of one epoch later.
"""
from __future__ import annotations


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
