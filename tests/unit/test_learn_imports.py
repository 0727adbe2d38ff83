"""The edge-side learning modules, and the learning loop's modules (torch only inside a fit), must not import torch."""
import subprocess
import sys

import pytest

EDGE_MODULES = ["anfis_numpy", "paramset", "elman", "fr_cg", "pso", "sigma", "settings", "predictor_core", "learner",
                "loop", "link"]


def test_edge_modules_do_not_import_torch():
    code = (
        "import sys\n"
        + "".join(f"import zennav.learn.{m}\n" for m in EDGE_MODULES)
        + "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_the_check_sees_torch_when_it_is_imported():
    pytest.importorskip("torch")
    code = "import sys, zennav.learn.lse\nprint('torch' in sys.modules)\n"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
