"""zennav.stopsignals: a stop signal acted on by a thread, never inside the signal handler."""
import os
import signal
import threading
import time

from zennav.stopsignals import on_stop_signals


def test_sigterm_wakes_a_main_thread_waiting_on_the_event_set_by_the_stop():
    ev, callers = threading.Event(), []

    def on_stop(name: str) -> None:
        callers.append((name, threading.current_thread().name))
        ev.set()

    before = signal.getsignal(signal.SIGTERM)
    restore = on_stop_signals(on_stop)
    try:
        # the signal arrives while the main thread is inside Event.wait (holding its Condition's lock): the
        # deadlock of a handler that calls Event.set
        threading.Timer(0.2, os.kill, args=(os.getpid(), signal.SIGTERM)).start()
        t0 = time.monotonic()
        assert ev.wait(5.0), "the stop was never acted on"
        assert time.monotonic() - t0 < 2.0
    finally:
        restore()
    assert callers == [("SIGTERM", "zennav-stop-signals")]
    assert signal.getsignal(signal.SIGTERM) is before


def test_each_signal_reaches_the_callback_and_other_signals_do_not():
    got: list[str] = []
    done = threading.Event()

    def on_stop(name: str) -> None:
        got.append(name)
        if len(got) == 2:
            done.set()

    usr1 = signal.signal(signal.SIGUSR1, lambda *_: None)  # a Python handler: its number reaches the pipe too
    restore = on_stop_signals(on_stop)
    try:
        for sig in (signal.SIGUSR1, signal.SIGINT, signal.SIGTERM):
            os.kill(os.getpid(), sig)
            time.sleep(0.05)
        assert done.wait(5.0)
    finally:
        restore()
        signal.signal(signal.SIGUSR1, usr1)
    assert got == ["SIGINT", "SIGTERM"]
