"""Stop signals (SIGINT, SIGTERM) acted on outside the signal handler.

A Python signal handler runs in the main thread between two bytecodes, possibly while that thread holds a
non-reentrant lock: ``threading.Event.wait`` holds its Condition's lock, so an ``Event.set()`` (or a log line, or
a thread start) inside the handler can deadlock the main thread for ever. Seen: a service SIGTERMed by its
killed launcher (zennav.pdeath) hung in ``Event.set`` inside its handler, so its stop deadline was never armed.

Here the interpreter's C-level handler writes the signal's number to a pipe (``signal.set_wakeup_fd``); a daemon
thread reads it and calls ``on_stop(name)`` as ordinary code, with no lock held. The Python-level handler does
nothing. The stop is also prompt: the C handler runs in whichever thread the kernel picked, so the main thread
need not wake up first.
"""
from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _ignore(signum, frame) -> None:
    """The Python-level handler: the work is done by the reader thread (module docstring)."""


def on_stop_signals(on_stop: Callable[[str], None]) -> Callable[[], None]:
    """Call ``on_stop(signal_name)`` from a daemon thread at each SIGINT/SIGTERM. Main thread only. Returns the
    function that restores the previous handlers and wakeup fd (and ends the thread)."""
    r, w = os.pipe()
    os.set_blocking(w, False)  # set_wakeup_fd's requirement: the C handler must never block
    previous = {s: signal.signal(s, _ignore) for s in STOP_SIGNALS}
    previous_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    numbers = {int(s) for s in STOP_SIGNALS}

    def read() -> None:
        with os.fdopen(r, "rb", buffering=0) as pipe:
            while data := pipe.read(64):  # b"" once restore() closed the write end
                for n in data:
                    if n in numbers:
                        on_stop(signal.Signals(n).name)

    threading.Thread(target=read, name="zennav-stop-signals", daemon=True).start()

    def restore() -> None:
        signal.set_wakeup_fd(previous_fd)
        for s, h in previous.items():
            signal.signal(s, h)
        os.close(w)

    return restore
