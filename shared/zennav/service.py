"""What every zennav service process shares: command-line options for the bus, logging, signal handling,
the heartbeat (``svc/<service>/status`` once a second) and a clean stop. No zenoh here (see zennav.bus).

A service's ``main(argv=None)`` builds an ``argparse`` parser with ``add_bus_args``, creates a
``ServiceRunner`` (which opens the Bus *without* the liveliness token), declares its subscribers and
publishers, then calls ``runner.ready()`` (token + "running" status: the service is up only once it can
receive) and ``runner.wait()`` until SIGINT/SIGTERM or ``runner.stop()``.

A stop is bounded: --exit-deadline seconds after the first SIGINT/SIGTERM a service still running (a session
close or a thread join that hangs) exits at once, code 1, with one error line. A service whose launcher died
(zennav.pdeath sends it SIGTERM) is then gone within that time, whatever its stop was waiting for.
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, NoReturn

from .stopsignals import on_stop_signals

if TYPE_CHECKING:  # zenoh is imported when a service opens its bus
    from .bus import Bus

log = logging.getLogger("zennav.service")

LOG_FORMAT = "%(asctime)s.%(msecs)03d %(levelname)s %(name)s: %(message)s"


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are one line ("prog: error: ... (see --help)"), not the usage block."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def add_bus_args(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    g = p.add_argument_group("bus (zenoh)")
    g.add_argument("--vehicle", default=os.environ.get("ZENNAV_VEHICLE", "car"), help="key-space vehicle name")
    g.add_argument("--mode", choices=("peer", "client", "router"), default=None,
                   help="zenoh mode (default: ZENNAV_MODE, else the config file's, peer)")
    g.add_argument("--zenoh-config", default=None, help="zenoh json5 config (default deploy/zenoh-<mode>.json5)")
    g.add_argument("--connect", default=None, help="comma-separated endpoints to connect, e.g. tcp/127.0.0.1:7447")
    g.add_argument("--listen", default=None, help="comma-separated endpoints to listen on")
    g.add_argument("--name", default=None, help="service name for liveliness/status (default: the service)")
    g.add_argument("--log-level", default=os.environ.get("ZENNAV_LOG", "INFO"))
    g.add_argument("--status-period", type=float, default=1.0, help="heartbeat period [s]")
    g.add_argument("--exit-deadline", type=float, default=15.0,
                   help="[s] after SIGINT/SIGTERM: exit at once (code 1) if the clean stop is not over by then")
    return p


def setup_logging(level: str = "INFO") -> None:
    root = logging.getLogger()
    if not root.handlers:
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter(LOG_FORMAT, "%H:%M:%S"))
        root.addHandler(h)
    root.setLevel(getattr(logging, str(level).upper(), logging.INFO))


def exit_process(code: int) -> NoReturn:
    """End the process now, its logs and standard streams flushed, without the interpreter's finalization: where
    zenoh threads may still meet it (an ingest that had closed its session and logged its stop aborted there twice
    in about 8 full test runs, "FATAL: exception not rethrown", exit -6), or where a stop must not wait."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


class ServiceRunner:
    """Bus + lifecycle of one service process."""

    def __init__(self, service: str, args: argparse.Namespace, *, serial: bool = True):
        from .bus import Bus

        setup_logging(args.log_level)
        self.name = args.name or service
        self.log = logging.getLogger(f"zennav.{self.name}")
        try:
            self.bus = Bus(self.name, args.vehicle, mode=args.mode, config=args.zenoh_config, connect=args.connect,
                           listen=args.listen, token=False, serial=serial)
        except Exception as e:  # a bad config file or endpoint (zenoh raises its own error type): one line
            raise SystemExit(f"zennav-{service}: cannot open the bus: {' '.join(str(e).split())[:400]}") from None
        self.keys = self.bus.keys
        self.state = "starting"
        self.detail = ""
        self.describe: Callable[[], str] | None = None  # when set: the detail of every heartbeat (live progress)
        self.counters: Callable[[], dict] = dict
        self._stop = threading.Event()
        self._period = args.status_period
        self._exit_deadline_s = args.exit_deadline
        self._deadline: threading.Timer | None = None
        self._hb: threading.Thread | None = None
        self._restore_signals = (on_stop_signals(self._on_signal)
                                 if threading.current_thread() is threading.main_thread() else None)

    def _on_signal(self, name: str) -> None:
        """A SIGINT/SIGTERM (zennav.stopsignals: called from a thread, not in the signal handler)."""
        self.log.info("%s received, stopping", name)
        self._stop.set()
        if self._deadline is None:  # the first signal arms the deadline of the stop (module docstring)
            self._deadline = threading.Timer(self._exit_deadline_s, self._exit_now, args=(name,))
            self._deadline.daemon = True
            self._deadline.start()

    def _exit_now(self, signame: str) -> None:
        self.log.error("still running %.0f s after %s: exiting without a clean stop", self._exit_deadline_s,
                       signame)
        exit_process(1)

    def ready(self, state: str = "running", detail: str = "") -> None:
        """Declare the liveliness token and start the heartbeat: call after the subscriptions exist."""
        self.state, self.detail = state, detail
        self.bus.announce()
        self.heartbeat()
        self._hb = threading.Thread(target=self._heartbeat_loop, name="zennav-heartbeat", daemon=True)
        self._hb.start()
        self.log.info("%s up (%s%s) on vehicle %s, zid %s", self.name, state, f": {detail}" if detail else "",
                      self.keys.vehicle, self.bus.zid)

    def fail(self, detail: str, code: int = 2) -> int:
        """Log one error line, publish the "error" state and close: the exit code of a main() that cannot start
        (e.g. a bad parameter file)."""
        self.log.error("%s", detail)
        self.set_state("error", detail)
        self.close()
        return code

    def stream_start_of(self, src: str) -> dict | None:
        """The stream_start of the sensor stream of ``src``, asked of the ingest's latest value on the stream key
        (a late joiner's question, zennav.stream); None when no ingest answers with it."""
        try:
            replies = self.bus.get_latest(self.keys.stream(), timeout=1.0)
        except Exception as e:  # session closing, no route: the follower asks again later
            self.log.debug("stream start query failed: %s", e)
            return None
        return next((m for _k, m in replies if m["schema"] == "stream_start" and m["src"] == src), None)

    def set_state(self, state: str, detail: str = "") -> None:
        self.state, self.detail = state, detail
        self.heartbeat()

    def heartbeat(self) -> None:
        try:
            detail = self.describe() if self.describe is not None and self.state == "running" else self.detail
            self.bus.publish_status(self.state, detail, self.counters())
        except Exception:
            self.log.exception("status publish failed")

    def _heartbeat_loop(self) -> None:
        while not self._stop.wait(self._period):
            self.heartbeat()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def stop(self) -> None:
        self._stop.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until stopped (signal or stop()); True if stopped."""
        return self._stop.wait(timeout)

    def serve(self, state: str = "running", detail: str = "") -> int:
        """Announce the service as ready, block until it is stopped, close it; the exit code of main()."""
        self.ready(state, detail)
        try:
            self.wait()
        finally:
            self.close()
        return 0

    def close(self) -> None:
        """Last status, then the bus closed; the heartbeat thread is joined first, so that no heartbeat races the
        last status or the closing session."""
        self._stop.set()
        hb = self._hb
        if hb is not None and hb is not threading.current_thread():
            hb.join(2.0)
        try:
            self.state = "stopping"
            self.heartbeat()
        except Exception:
            pass
        self.bus.close()
        self.log.info("%s stopped", self.name)
        if self._restore_signals is not None and threading.current_thread() is threading.main_thread():
            self._restore_signals()  # (set_wakeup_fd: main thread only; a close elsewhere ends the process)
            self._restore_signals = None


class EndAcks:
    """The ins instances that follow a sensor stream published by ``src`` (this bus's) and their acknowledgement
    of its end (a nav status of the stream with done and its last cseq), seen on the ins's status key and on
    every --nav-prefix ins's: the publisher of a stream keeps its session open until all have it, since closing
    drops what is still queued."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.src = bus.src
        self.following: set[str] = set()  # status publishers (src) that reported on this stream ...
        self.acks: dict[str, int] = {}  # ... and the last cseq each acknowledged
        self._cv = threading.Condition()
        bus.watch_alive()
        for key in (bus.keys.nav_status(), f"{bus.keys.base}/nav/*/status"):
            bus.subscribe(key, self._on_status, channel="ring", name="acks")

    def _on_status(self, key, msg, recv_ns) -> None:
        st = msg["stream"]
        if st.get("src") == self.src:
            with self._cv:
                if msg["src"] not in self.following:  # a restarted ins (same service name) replaces its old self
                    name = msg["src"].rsplit(".", 2)[0]
                    for old in [s for s in self.following if s.rsplit(".", 2)[0] == name]:
                        self.following.discard(old)
                        self.acks.pop(old, None)
                self.following.add(msg["src"])
                if st.get("done"):
                    self.acks[msg["src"]] = int(st.get("last_cseq", -1))
                self._cv.notify_all()

    def pending(self, last_cseq: int | None) -> set[str]:
        """The following ins (src) that have not acknowledged the end at last_cseq (None: any) yet."""
        with self._cv:
            return {s for s in self.following if s not in self.acks or last_cseq not in (None, self.acks[s])}

    def wait(self, last_cseq: int | None, timeout: float, stop: Callable[[], bool] = lambda: False) -> bool:
        """Wait until every ins that reported on the stream (at least one) acknowledged its end (at last_cseq;
        None: any), or stop(). An ins still alive (its liveliness token; a slow one, e.g. learning in lockstep)
        is waited for as long as it lives; timeout [s] runs while no pending ins is alive (none reported yet, or
        the pending ones died). True when acknowledged."""
        deadline = time.monotonic() + timeout
        while not stop():
            pending = self.pending(last_cseq)
            if self.following and not pending:
                return True
            alive = self.bus.alive()
            if any(s.rsplit(".", 2)[0] in alive for s in pending):  # src = <service>.<zid>.<id>
                deadline = time.monotonic() + timeout
            elif time.monotonic() > deadline:
                return False
            with self._cv:
                self._cv.wait(0.2)
        return False


def wall_ns() -> int:
    return time.time_ns()


