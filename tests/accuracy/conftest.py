"""Shared fixtures of the accuracy tests: real recordings from the shared data folder."""
from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

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


@pytest.fixture(scope="session")
def load_benchmark():
    """load(NAME): the benchmark script benchmarks/NAME.py as a module (the accuracy tests run the product through
    the same functions the README's commands do)."""
    return _load_benchmark


def _load_benchmark(name: str) -> ModuleType:
    script = Path(__file__).resolve().parents[2] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, script)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
