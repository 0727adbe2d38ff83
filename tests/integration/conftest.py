"""Fixtures of the integration tests (see zennav_harness.py): real processes over real Zenoh on loopback."""
from __future__ import annotations

import pytest
from zennav_harness import Cluster


@pytest.fixture
def cluster(request, tmp_path):
    c = Cluster(tmp_path)
    yield c
    rep = getattr(request.node, "rep_call", None)
    c.close(failed=bool(rep is not None and rep.failed))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    setattr(item, f"rep_{rep.when}", rep)


