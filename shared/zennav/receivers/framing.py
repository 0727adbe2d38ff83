"""Split a receiver's byte stream into NMEA 0183 sentences and UBX frames (a serial line often carries both).

``Framer.feed(data)`` returns the complete frames found so far as ("nmea", bytes without the line end) or
("ubx", whole frame) and keeps an unfinished tail for the next call. What is not a frame is counted, never
raised: ``garbage_bytes`` (bytes outside any frame, e.g. a wrong baud rate), ``partial`` (a sentence cut by the
start of another frame, or longer than NMEA allows), ``ubx_length`` (an impossible UBX length). Checksums are
checked by the parsers (zennav.receivers.nmea / ubx), which count their own errors.
"""
from __future__ import annotations

from collections import Counter

UBX_SYNC = b"\xb5\x62"
NMEA_MAX = 120  # longest sentence accepted [bytes]: 82 by the standard, proprietary ones run longer
UBX_MAX_PAYLOAD = 8192


class Framer:
    """Stateful splitter of one byte stream (see the module docstring); ``counts`` holds what it discarded."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.counts: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[tuple[str, bytes]]:
        self.buf += data
        out: list[tuple[str, bytes]] = []
        buf = self.buf
        i = 0
        n = len(buf)
        while i < n:
            c = buf[i]
            if c == 0x24:  # '$' (or '!'-less NMEA): a sentence up to the line end
                end = buf.find(b"\n", i)
                nxt = self._next_start(buf, i + 1, n if end < 0 else end)
                if nxt >= 0:  # another frame starts before this one ended: cut sentence
                    self.counts["partial"] += 1
                    i = nxt
                    continue
                if end < 0:
                    if n - i > NMEA_MAX:
                        self.counts["partial"] += 1
                        i = n
                    break
                line = bytes(buf[i:end]).rstrip(b"\r")
                if len(line) > NMEA_MAX:
                    self.counts["partial"] += 1
                else:
                    out.append(("nmea", line))
                i = end + 1
            elif c == 0xB5 and i + 1 < n and buf[i + 1] == 0x62:
                if n - i < 6:
                    break
                length = buf[i + 4] | (buf[i + 5] << 8)
                if length > UBX_MAX_PAYLOAD:
                    self.counts["ubx_length"] += 1
                    i += 2
                    continue
                if n - i < 8 + length:
                    break
                out.append(("ubx", bytes(buf[i:i + 8 + length])))
                i += 8 + length
            elif c == 0xB5 and i + 1 == n:
                break  # maybe the first sync byte of a frame still arriving
            else:
                j = self._next_start(buf, i, n)
                if j < 0:  # keep a trailing first sync byte: its frame may still be arriving
                    j = n - 1 if buf[n - 1] == 0xB5 and n - 1 > i else n
                skipped = bytes(buf[i:j]).strip(b"\r\n")
                self.counts["garbage_bytes"] += len(skipped)
                i = j
        del buf[:i]
        return out

    @staticmethod
    def _next_start(buf: bytearray, i: int, end: int) -> int:
        """Index of the next '$' or UBX sync in buf[i:end], -1 if none."""
        a = buf.find(b"$", i, end)
        b = buf.find(UBX_SYNC, i, end)
        if a < 0:
            return b
        return a if b < 0 else min(a, b)
