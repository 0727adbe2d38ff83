"""Shared fixtures of the accuracy tests: real recordings from the shared data folder."""
from __future__ import annotations

import pytest

from zennav.datasets import registry
from zennav.datasets.errors import DataError


@pytest.fixture(scope="session")
def rtklib_dataset():
    """The rtklibexplorer drive; skipped with the reason only when the shared data folder is absent."""
    try:
        folder = registry.data_root() / "rtklibexplorer_drive_0708"
    except DataError as exc:
        pytest.skip(f"shared data folder not found ({exc})")
    if not folder.is_dir():
        pytest.skip(f"data folder {folder} is absent")
    return registry.load_dataset(str(folder))
