"""A child process that dies with its parent: Linux's parent-death signal (prctl PR_SET_PDEATHSIG), which the kernel
delivers even when the parent is killed with SIGKILL. Used by the launcher for its services (zennav.launch) and by
the trainer for its fit worker (zennav.learn.fit_worker). Elsewhere than on Linux it does nothing (the launcher's
own stop remains).

The launcher sets it between fork and exec (``preexec``: libc's prctl is looked up in the parent, so the child only
makes the call; the setting survives exec). Pitfall: the kernel sends the signal when the *thread* that forked the
child ends, not the process; the launcher starts services from its main thread.
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable

PR_SET_PDEATHSIG = 1


def _prctl() -> Callable | None:
    """libc's prctl on Linux, else None."""
    if not sys.platform.startswith("linux"):
        return None
    return ctypes.CDLL(None, use_errno=True).prctl


def die_with_parent(parent_pid: int, sig: int = signal.SIGTERM) -> bool:
    """Ask the kernel to send sig to this process when its parent dies; exit at once (code 1) if the parent
    parent_pid is already gone. True when set (Linux)."""
    prctl = _prctl()
    if prctl is None or prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return False
    if os.getppid() != parent_pid:  # died before prctl: no signal will come
        os._exit(1)
    return True


def preexec(sig: int = signal.SIGTERM) -> Callable[[], None] | None:
    """A subprocess.Popen preexec_fn that makes the child die (sig) with this process; None off Linux."""
    prctl, parent = _prctl(), os.getpid()
    if prctl is None:
        return None

    def child() -> None:
        prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:
            os._exit(1)

    return child
