"""Shared by every test: the session's own simulator cache (zennav.sim.cache), so that a run neither reads nor fills
the user's (the services the tests start inherit it), removed at the end."""
from __future__ import annotations

import os
import shutil
import tempfile

_CACHE = tempfile.mkdtemp(prefix="zennav-test-cache-")
os.environ["XDG_CACHE_HOME"] = _CACHE


def pytest_sessionfinish(session, exitstatus) -> None:
    shutil.rmtree(_CACHE, ignore_errors=True)
