"""On-disk cache of the simulator's generated series (issue 17: `zennav replay sim:car` at its first sample within a
second of the process start, after the first run on a machine).

The IMU increments, bias and scale series and the truth of a long simulated dataset take about a second of CPU to
generate (the quadrature of the ideal increments and the Gauss-Markov recursions, which must stay sequential Python
floats to keep their values). They are a pure function of the simulator's parameters, so they are stored once per
machine and read back bit for bit:

- key: SHA-256 of the parameters (JSON), the source files that determine the floats (zennav.sim's and the zennav.nav
  modules it uses), numpy's version and the machine type; one file per key, ``<key>.npz`` (numpy's format, read with
  allow_pickle=False: data only, no code), which also holds the key's text and is used only when it matches.
- where: ``$XDG_CACHE_HOME/zennav/sim`` (default ``~/.cache/zennav/sim``); ``ZENNAV_CACHE=0`` turns the cache off.
- writes are atomic (a temporary file renamed into place); the folder is kept under MAX_BYTES by removing the least
  recently used files; an unreadable or unwritable file is logged and counted (``STATS``) and the series generated.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import json
import logging
import os
import platform
import tempfile
import time
import zipfile
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger("zennav.sim")

MIN_SAMPLES = 50_000  # IMU samples from which a dataset is cached (below, generating takes about 0.3 s CPU or less)
MAX_BYTES = 1 << 30  # the cache folder's bound [bytes]
_SOURCES = ("zennav.sim.cache", "zennav.sim.scenarios", "zennav.sim.sensors", "zennav.sim.trajectory",
            "zennav.nav.earth", "zennav.nav.rotation", "zennav.nav.types")  # the modules the cached series depend on
_KEY = "__key__"
_STALE_TMP_S = 3600.0  # a temporary file older than this is a crashed writer's [s]
STATS: Counter = Counter()  # hit, miss, stored, unreadable, unwritable, evicted


def cache_dir() -> Path | None:
    """The cache folder, or None when ZENNAV_CACHE=0."""
    if os.environ.get("ZENNAV_CACHE", "1") == "0":
        return None
    base = os.environ.get("XDG_CACHE_HOME", "")
    return (Path(base) if os.path.isabs(base) else Path.home() / ".cache") / "zennav" / "sim"


def _jsonable(x):
    if isinstance(x, np.ndarray):
        return {"ndarray": x.dtype.str, "values": x.tolist()}
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"{type(x).__name__} is not a cacheable parameter")


@functools.cache
def _sources_hash(modules: tuple[str, ...]) -> str:
    """SHA-256 of the source files of modules, read once per process."""
    sources = hashlib.sha256()
    for name in modules:
        path = importlib.import_module(name).__file__
        assert path is not None
        sources.update(Path(path).read_bytes())
    return sources.hexdigest()


def key_text(params: dict) -> str:
    """The cache key's text for params (JSON of plain values, tuples, lists, dicts and numpy arrays; anything else:
    TypeError) with the simulator's source hash, numpy's version and the machine type."""
    return json.dumps({"params": params, "sources": _sources_hash(_SOURCES), "numpy": np.__version__,
                       "machine": platform.machine()}, sort_keys=True, default=_jsonable)


def load_or_make(params: dict, make: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """make()'s arrays for params: read from the cache when it holds them, else made now and stored."""
    directory = cache_dir()
    if directory is None:
        return make()
    try:
        text = key_text(params)
    except TypeError as e:
        log.debug("simulator cache not used: %s", e)
        return make()
    path = directory / f"{hashlib.sha256(text.encode()).hexdigest()}.npz"
    arrays = _read(path, text)
    if arrays is not None:
        STATS["hit"] += 1
        return arrays
    STATS["miss"] += 1
    arrays = make()
    _write(path, text, arrays)
    return arrays


def _read(path: Path, text: str) -> dict[str, np.ndarray] | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if _KEY not in z.files or str(z[_KEY]) != text:
                raise ValueError("its key differs")
            arrays = {name: z[name] for name in z.files if name != _KEY}
    except FileNotFoundError:
        return None
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as e:
        STATS["unreadable"] += 1
        log.warning("simulator cache file %s unreadable (%s): generating the dataset", path, e)
        return None
    try:
        os.utime(path)  # recently used (eviction order)
    except OSError:
        pass  # a cache that is read-only for this user: still read
    return arrays


def _write(path: Path, text: str, arrays: dict[str, np.ndarray]) -> None:
    if sum(a.nbytes for a in arrays.values()) > MAX_BYTES:
        return
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=".", suffix=".tmp", delete=False) as f:
            tmp = f.name
            payload: dict[str, Any] = {**arrays, _KEY: np.array(text)}  # Any: numpy's stubs would match allow_pickle
            np.savez(f, **payload)
        os.replace(tmp, path)
        STATS["stored"] += 1
    except OSError as e:
        STATS["unwritable"] += 1
        log.warning("simulator cache file %s not written (%s)", path, e)
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        return
    _evict(path.parent, keep=path)


def _evict(directory: Path, keep: Path) -> None:
    """Remove the least recently used files until the folder holds at most MAX_BYTES (keep stays), and temporary
    files of writers that did not finish."""
    now = time.time()
    entries = []
    for p in directory.iterdir():
        try:
            st = p.stat()
        except OSError:
            continue  # removed by another process meanwhile
        if p.suffix == ".tmp" and now - st.st_mtime > _STALE_TMP_S:
            p.unlink(missing_ok=True)
        elif p.suffix == ".npz":
            entries.append((st.st_mtime, st.st_size, p))
    total = sum(size for _, size, _ in entries)
    for _, size, p in sorted(entries):
        if total <= MAX_BYTES:
            break
        if p != keep:
            p.unlink(missing_ok=True)
            total -= size
            STATS["evicted"] += 1
