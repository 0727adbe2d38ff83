"""Start-up: a command imports only what it uses (benchmarks/startup.py measures the time). A fresh interpreter is
used for each check: this test process has imported everything already."""
from __future__ import annotations

import subprocess
import sys


def _modules_after(code: str, names: tuple[str, ...]) -> list[str]:
    probe = code + f"\nimport sys\nprint(sorted(m for m in {names!r} if m in sys.modules))"
    return eval(subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout)


def test_a_dataset_folder_imports_only_its_own_loader():
    """rtklibexplorer's folder: its loader only, not ANSFL's, comma2k19's or KF-GINS's (ANSFL's loads scipy.signal
    for every folder otherwise)."""
    names = ("zennav.datasets.rtklibexplorer", "zennav.datasets.ansfl", "zennav.datasets.comma2k19",
             "zennav.datasets.kfgins")
    got = _modules_after("from zennav.datasets.registry import load_dataset\nload_dataset('rtklibexplorer')",
                         names + ("scipy.signal",))
    assert got == ["zennav.datasets.rtklibexplorer"]  # its zero-phase filter without scipy.signal (about 1.2 s)


def test_a_plain_replay_does_not_import_the_learning_loop():
    """`zennav replay` without --compensation: no learning loop, no torch, no plotting, no MCAP writer, no scipy.signal,
    scipy.special or scipy.stats."""
    names = ("zennav.learn.loop", "torch", "matplotlib", "mcap")
    code = ("from click.testing import CliRunner\nfrom zennav.cli import main\n"
            "r = CliRunner().invoke(main, ['replay', 'sim:static', '-o', 'duration_s=2', '-q'])\n"
            "assert r.exit_code == 0, r.output")
    assert _modules_after(code, names) == []
    # nor scipy's slow imports: the simulator's Gauss-Markov series, the gates' chi-square quantiles (eskf.CHI2_TABLE)
    assert _modules_after(code, ("scipy.signal", "scipy.special", "scipy.stats")) == []
    with_loop = code.replace("'-q']", "'-q', '--compensation', 'anfis']")
    assert _modules_after(with_loop, names)[:1] == ["zennav.learn.loop"]  # the check sees it when it is used


def test_the_services_engine_and_the_cli_do_not_import_numba():
    """numba (about 100 MB resident, a second to load) only for zennav replay's compiled loop: the ins node and the
    step-wise engine run the kernels as Python, `zennav --help` loads neither."""
    code = ("import zennav.nodes.ins, zennav.cli\nfrom zennav.sim.scenarios import make_dataset\n"
            "from zennav.replay import run_replay\nrun_replay(make_dataset('car', duration_s=5.0), loop='step')")
    assert _modules_after(code, ("numba", "llvmlite")) == []
    assert _modules_after(code.replace("loop='step'", "loop='compiled'"), ("numba",)) == ["numba"]  # the check sees it


def test_a_long_kfgins_file_starts_without_polars(tmp_path):
    """A KF-GINS configuration with a long IMU file: loaded as `zennav replay` does (its IMU head, the GNSS files, the
    truth left for after the run) without polars; polars (about 0.3 s to import) reads the rest of the IMU file,
    over zennav.datasets.fasttext.MIN_BYTES, when it is used."""
    from zennav.datasets import kfgins
    from zennav.sim.scenarios import make_dataset

    yaml_path = kfgins.write_dataset(make_dataset("car", duration_s=40.0, seed=1), tmp_path)
    code = (f"from zennav.datasets.registry import load_dataset\n"
            f"ds = load_dataset({str(yaml_path)!r}, defer_truth=True, stream_imu=True)")
    assert _modules_after(code, ("polars", "zennav.datasets.streamed")) == ["zennav.datasets.streamed"]
    assert _modules_after(code + "\nds.imu.t_ns", ("polars",)) == ["polars"]  # the check sees it
