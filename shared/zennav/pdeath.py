"""A child process that dies with its parent: Linux's parent-death signal (prctl PR_SET_PDEATHSIG), which the kernel
delivers even when the parent is killed with SIGKILL. Used by the launcher for its services (zennav.launch) and by
the trainer for its fit worker (zennav.learn.fit_worker). Elsewhere than on Linux it does nothing (the launcher's
own stop remains).

The launcher runs each service through ``python -m zennav.pdeath <launcher pid> -- <command...>``: the wrapper
sets the signal and execs the command (the setting survives exec), so nothing runs between fork and exec in the
threaded launcher (no preexec_fn). Pitfall: the kernel sends the signal when the *thread* that forked the child
ends, not the process; the launcher starts services from its main thread.
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int, sig: int = signal.SIGTERM) -> bool:
    """Ask the kernel to send sig to this process when its parent dies; exit at once (code 1) if the parent
    parent_pid is already gone. True when set (Linux)."""
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        return False
    if os.getppid() != parent_pid:  # died before prctl: no signal will come
        os._exit(1)
    return True


def wrap(command: list, parent_pid: int | None = None) -> list:
    """The argv that runs command as a child dying with parent_pid (default: this process)."""
    return [sys.executable, "-m", "zennav.pdeath", str(parent_pid or os.getpid()), "--", *command]


def main(argv: list) -> None:
    """``<parent pid> -- <command...>``: set the parent-death signal (SIGTERM), then exec the command."""
    if len(argv) < 3 or argv[1] != "--":
        sys.exit("usage: python -m zennav.pdeath PARENT_PID -- COMMAND...")
    die_with_parent(int(argv[0]))
    try:
        os.execvp(argv[2], argv[2:])
    except OSError as e:
        sys.exit(f"zennav.pdeath: cannot run {argv[2]}: {e.strerror or e}")


if __name__ == "__main__":
    main(sys.argv[1:])
