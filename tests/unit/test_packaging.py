"""The project installs as one import root, `zennav`, assembled from the user's shared/ and services/
folders, and never as top-level `shared` or `services` packages (ARCHITECTURE.md section 6)."""
from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_import_root_is_zennav_only(tmp_path):
    """As installed (run outside the repository, so the current folder adds nothing to sys.path)."""
    probe = ("import importlib.util as u, zennav.nav.navigator, zennav.services; "
             "print(u.find_spec('shared'), u.find_spec('services'))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, check=True, capture_output=True, text=True)
    assert out.stdout.split() == ["None", "None"]


def test_wheel_holds_only_the_zennav_tree(tmp_path):
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path), str(REPO)], check=True, capture_output=True)
    (wheel,) = tmp_path.glob("zennav-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    roots = {n.split("/")[0] for n in names}
    assert roots == {"zennav", next(r for r in roots if r.endswith(".dist-info"))}
    assert "zennav/nav/navigator.py" in names and "zennav/services/__init__.py" in names
    assert {"zennav/messages/__init__.py", "zennav/messages/validate.py", "zennav/nodes/ins.py", "zennav/params.py",
            "zennav/stream.py"} <= set(names)
    assert "zennav/__init__.py" not in names  # a PEP 420 namespace shared by both folders
    entry_points = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "zennav = zennav.cli:main" in entry_points
