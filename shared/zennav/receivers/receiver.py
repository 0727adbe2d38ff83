"""A live GNSS receiver: bytes from a serial port (pyserial), a TCP stream or a file -> GNSS fixes, on a thread.

Link specs: ``serial:/dev/ttyUSB0[:BAUD]`` (default 115200 baud), ``tcp:HOST:PORT``, ``file:PATH`` (or a plain
path). One link may carry NMEA and UBX at once (zennav.receivers.framing splits them). Nothing a receiver sends
crashes the reader: bad frames, checksum errors, partial sentences and line noise are counted by reason
(``counts``) and logged (the first few of each, then every 1000th). Silence longer than ``silence_s`` is counted
(``silences``) and logged once, and its end logged with its length; a serial port or TCP peer that fails is
reopened every second (``io_errors``, ``reconnects``). A fix not newer than the last one handed over (the same
epoch sent as NMEA and UBX, a receiver that jumps back) is dropped as ``old_fix``. A file ends the stream
(``exhausted``); serial and TCP links run until ``stop()``.
"""
from __future__ import annotations

import logging
import queue
import socket
import threading
import time
from collections import Counter
from pathlib import Path

from ..nav.types import GnssFix
from .framing import Framer
from .nmea import NmeaDecoder, NmeaSettings
from .ubx import UbxDecoder

READ_TIMEOUT_S = 0.1
CHUNK = 4096


class _File:
    def __init__(self, path: str):
        self.f = open(path, "rb")

    def read(self) -> bytes:
        data = self.f.read(CHUNK)
        if not data:
            raise EOFError
        return data

    def close(self) -> None:
        self.f.close()


class _Serial:
    def __init__(self, port: str, baud: int):
        import serial

        self.s = serial.Serial(port, baud, timeout=READ_TIMEOUT_S)

    def read(self) -> bytes:
        import serial

        try:
            return self.s.read(max(1, min(self.s.in_waiting, CHUNK)))
        except serial.SerialException as e:
            raise OSError(str(e)) from None

    def close(self) -> None:
        self.s.close()


class _Tcp:
    def __init__(self, host: str, port: int):
        self.s = socket.create_connection((host, port), timeout=2.0)
        self.s.settimeout(READ_TIMEOUT_S)

    def read(self) -> bytes:
        try:
            data = self.s.recv(CHUNK)
        except TimeoutError:
            return b""
        if not data:
            raise OSError("connection closed by the receiver")
        return data

    def close(self) -> None:
        self.s.close()


def parse_link(spec: str) -> tuple[str, tuple]:
    """A link spec (see the module docstring) -> (kind, arguments); ValueError with the reason when malformed."""
    kind, _, rest = spec.partition(":")
    try:
        if kind == "serial" and rest:
            port, _, baud = rest.rpartition(":") if rest.rsplit(":", 1)[-1].isdigit() else (rest, "", "115200")
            return kind, (port, int(baud))
        if kind == "tcp":
            host, _, port = rest.rpartition(":")
            if host:
                return kind, (host, int(port))
        if kind == "file" and rest:
            return kind, (rest,)
    except ValueError:
        pass
    if kind not in ("serial", "tcp", "file") and Path(spec).exists():
        return "file", (spec,)
    raise ValueError(f"receiver link {spec!r}: expected serial:PORT[:BAUD], tcp:HOST:PORT or file:PATH")


def open_link(spec: str):
    """A byte link from its spec; read() -> bytes (b'' on a quiet READ_TIMEOUT_S), EOFError at the end of a file,
    OSError when the link fails."""
    kind, args = parse_link(spec)
    return {"serial": _Serial, "tcp": _Tcp, "file": _File}[kind](*args)


class GnssReceiver:
    """Reads one link on a thread and queues its fixes (``fixes``: GnssFix, in receive order). ref_t_ns: a GPS
    time near the data (the stream's start), for epochs whose tags carry no date."""

    def __init__(self, spec: str, ref_t_ns: int | None = None, nmea: NmeaSettings | None = None,
                 silence_s: float = 2.0, log: logging.Logger | None = None):
        self.spec = spec
        self.is_file = parse_link(spec)[0] == "file"
        self.silence_s = silence_s
        self.log = log or logging.getLogger("zennav.receiver")
        self.framer = Framer()
        self.nmea = NmeaDecoder(nmea, ref_t_ns)
        self.ubx = UbxDecoder(ref_t_ns)
        self.fixes: queue.Queue[GnssFix] = queue.Queue()
        self.exhausted = threading.Event()
        self.opened = threading.Event()  # the link is open (a serial port drops what came before its opening)
        self.events: Counter[str] = Counter()
        self.last_t_ns = -1
        self.n_fixes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gnss-receiver", daemon=True)
        self._logged: Counter[str] = Counter()

    @property
    def counts(self) -> dict[str, int]:
        """Every count of the receiver: framing, NMEA, UBX and link events."""
        c = Counter(self.framer.counts)
        c.update(self.nmea.counts)
        c.update(self.ubx.counts)
        c.update(self.events)
        c["fixes"] = self.n_fixes
        return dict(c)

    def start(self) -> GnssReceiver:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def feed(self, data: bytes) -> None:
        """Bytes as read from the link -> fixes queued (the thread calls this; tests may too)."""
        before = self.counts
        for kind, frame in self.framer.feed(data):
            self._put((self.nmea if kind == "nmea" else self.ubx).decode(frame))
        self._log_new(before)

    def _put(self, fixes: list[GnssFix]) -> None:
        for fix in fixes:
            if fix.t_ns <= self.last_t_ns:
                self.events["old_fix"] += 1
                continue
            self.last_t_ns = fix.t_ns
            self.n_fixes += 1
            self.fixes.put(fix)

    def _log_new(self, before: dict) -> None:
        for reason, n in self.counts.items():
            if reason.startswith(("nmea_gga", "nmea_rmc", "nmea_gst", "nmea_vtg", "ubx_nav")) or reason == "fixes":
                continue
            if n > before.get(reason, 0):
                self._logged[reason] += 1
                k = self._logged[reason]
                if k <= 3 or k % 1000 == 0:
                    self.log.warning("receiver %s: %s (%d so far)", self.spec, reason, n)

    def _run(self) -> None:
        link = None
        last_data = time.monotonic()
        silent = False
        while not self._stop.is_set():
            if link is None:
                try:
                    link = open_link(self.spec)
                    self.log.info("receiver %s: open", self.spec)
                    self.opened.set()
                    if self.events["io_errors"]:
                        self.events["reconnects"] += 1
                        self.log.info("receiver %s: reopened", self.spec)
                except (OSError, ValueError) as e:
                    self.events["io_errors"] += 1
                    if self.events["io_errors"] <= 3:
                        self.log.warning("receiver %s: cannot open (%s); retrying every second", self.spec, e)
                    self._stop.wait(1.0)
                    continue
            try:
                data = link.read()
            except EOFError:
                break
            except OSError as e:
                self.events["io_errors"] += 1
                self.log.warning("receiver %s: %s; reopening", self.spec, e)
                link.close()
                link = None
                self._stop.wait(1.0)
                continue
            now = time.monotonic()
            if not data:
                if not silent and now - last_data > self.silence_s:
                    silent = True
                    self.events["silences"] += 1
                    self.log.warning("receiver %s: silent for %.1f s", self.spec, now - last_data)
                continue
            if silent:
                self.log.info("receiver %s: data again after %.1f s of silence", self.spec, now - last_data)
                silent = False
            last_data = now
            self.feed(data)
        self._put(self.nmea.flush() + self.ubx.flush())
        if link is not None:
            link.close()
        self.exhausted.set()
