"""Fixtures shared by the unit tests."""
from __future__ import annotations

import pytest


@pytest.fixture
def block_samples(monkeypatch) -> list[int]:
    """[n]: n counts the IMU samples that Navigator.run_imu runs in its block loop during the test."""
    from zennav.nav.navigator import Navigator

    ran = [0]
    run_imu = Navigator.run_imu

    def counted(self, *a, **kw):
        k = run_imu(self, *a, **kw)
        ran[0] += max(0, k - a[3])
        return k

    monkeypatch.setattr(Navigator, "run_imu", counted)
    return ran
