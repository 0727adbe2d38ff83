"""The trainer's ANFIS fits in a child process, so that a fit can be interrupted: the trainer's process never
imports torch, and on SIGTERM it terminates the worker mid-fit and exits cleanly (a Python thread inside torch
cannot be stopped, and an interpreter that finalises while one runs can abort). The worker is the same function
as the in-process loop's (zennav.learn.anfis_torch.fit_anfis_sigma, torch on ``torch_threads`` threads), so the
sets are the same bit for bit.

``FitWorker(torch_threads)`` is a callable with fit_anfis_sigma's signature, config given as TrainConfig's
fields (zennav.learn.learner.Learner's ``fitter``); it returns a ``Fit`` (arrays, norm, metrics: plain numpy and
Python values) or raises RuntimeError (the fit's own error, or the worker gone). One fit at a time; the worker
(spawned, not forked: torch and zenoh threads must not be forked) starts on first use, or at ``start()``, and dies
with the trainer (zennav.pdeath, SIGKILL). ``zennav replay --compensation anfis`` starts one with the run, so that
torch's import (about 1.4 s of CPU) runs on another core while the replay loads and navigates up to its first fit.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from typing import Any, NamedTuple


class Fit(NamedTuple):
    arrays: dict
    norm: dict
    metrics: dict


def _serve(conn, parent_pid: int, torch_threads: int) -> None:
    """The worker's loop: ("device",) -> the default device; ("fit", x, y, kwargs) -> Fit fields or an error."""
    from zennav.pdeath import die_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C: the trainer decides
    die_with_parent(parent_pid, signal.SIGKILL)
    import torch

    from .anfis_torch import TrainConfig, default_device, fit_anfis_sigma

    if torch_threads:
        torch.set_num_threads(torch_threads)
    while True:
        try:
            req = conn.recv()
        except EOFError:
            return
        try:
            if req[0] == "device":
                conn.send(("ok", str(default_device())))
            else:
                _, x, y, kw = req
                fit = fit_anfis_sigma(x, y, **{**kw, "config": TrainConfig(**kw["config"])})
                conn.send(("ok", (fit.arrays, fit.norm, fit.metrics)))
        except Exception as e:  # the fit's error goes back to the learner, which counts it
            conn.send(("error", f"{type(e).__name__}: {e}"[:300]))


class FitWorker:
    """fit_anfis_sigma in a child process (module docstring)."""

    def __init__(self, torch_threads: int = 1):
        self.torch_threads = int(torch_threads)
        self._lock = threading.Lock()
        self._proc: Any = None
        self._conn: Any = None
        self._closed = False

    def start(self) -> FitWorker:
        """Spawn the worker now, so that it imports torch while the caller goes on (else on first use)."""
        with self._lock:
            self._spawn()
        return self

    def _spawn(self) -> None:
        if self._closed:
            raise RuntimeError("fit worker stopped")
        if self._proc is None:
            ctx = multiprocessing.get_context("spawn")
            self._conn, child = ctx.Pipe()
            self._proc = ctx.Process(target=_serve, args=(child, os.getpid(), self.torch_threads),
                                     name="zennav-fit", daemon=True)
            self._proc.start()
            child.close()

    def _call(self, req: tuple):
        with self._lock:
            self._spawn()
            conn = self._conn
        try:
            conn.send(req)
            status, value = conn.recv()
        except (EOFError, OSError) as e:
            raise RuntimeError(f"fit worker gone ({type(e).__name__})") from None
        if status != "ok":
            raise RuntimeError(value)
        return value

    def device(self) -> str:
        """The worker's default torch device (cuda when torch sees one, else cpu)."""
        return self._call(("device",))

    def __call__(self, x, y, **kw) -> Fit:
        return Fit(*self._call(("fit", x, y, kw)))

    def close(self, timeout: float = 2.0) -> None:
        """Stop the worker now, mid-fit if need be (SIGTERM, then SIGKILL): a fit waiting on it raises."""
        with self._lock:
            self._closed = True
            proc, conn = self._proc, self._conn
        if proc is None:
            return
        proc.terminate()
        proc.join(timeout)
        if proc.is_alive():
            proc.kill()
            proc.join(timeout)
        conn.close()
