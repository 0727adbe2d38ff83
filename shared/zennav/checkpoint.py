"""Crash recovery of a stream consumer: its whole state on disk, written atomically.

``save(path, state)`` writes a msgpack map to ``path`` so that a reader (the restarted service) sees either the
previous checkpoint or the new one, never a torn file: the bytes go to a temporary file in the same directory,
are flushed to the disk (fsync), then renamed over ``path`` (atomic on POSIX) and the directory is synced.
``load(path)`` returns the map, or None when there is no checkpoint; a file that does not decode as a
checkpoint map of this format raises CheckpointError (the caller logs it and starts without).
``Checkpointer`` decides when: every ``every_s`` seconds of data time.
"""
from __future__ import annotations

import os
from pathlib import Path

import msgpack

FORMAT = "zennav-checkpoint-1"


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used (corrupt, another format)."""


def save(path: str | os.PathLike, state: dict) -> None:
    """Write state (msgpack-safe map) to path atomically (see the module docstring)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    data = msgpack.packb({"format": FORMAT, **state}, use_bin_type=True)
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def load(path: str | os.PathLike) -> dict | None:
    """The checkpoint at path, None when there is none; CheckpointError when it is unusable."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return None
    try:
        state = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as e:  # truncated or foreign bytes: msgpack raises many types
        raise CheckpointError(f"{path}: not a checkpoint ({type(e).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a {FORMAT} checkpoint")
    return state


class Checkpointer:
    """When to checkpoint: ``due(t_ns)`` is True once every ``every_s`` seconds of data time (the first time at
    the first sample it sees); ``path`` None: never."""

    def __init__(self, path: str | os.PathLike | None, every_s: float = 10.0):
        self.path = Path(path) if path else None
        self.every_ns = int(every_s * 1e9)
        self.next_t_ns: int | None = None
        self.written = 0

    def due(self, t_ns: int) -> bool:
        if self.path is None:
            return False
        if self.next_t_ns is None:
            self.next_t_ns = t_ns + self.every_ns
            return False
        if t_ns < self.next_t_ns:
            return False
        self.next_t_ns = t_ns + self.every_ns
        return True

    def write(self, state: dict) -> None:
        assert self.path is not None  # due() is False without a path
        save(self.path, state)
        self.written += 1
