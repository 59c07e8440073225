"""The console scripts pyproject.toml declares resolve to callables, and each answers --help."""

import shutil
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, distribution, entry_points
from pathlib import Path

import pytest

SCRIPTS = {
    "aco-rbfn-train": "rbfn.scripts:train",
    "aco-rbfn-evaluate": "rbfn.scripts:evaluate",
    "aco-rbfn-summarize": "rbfn.studies.summarize:main",
    "aco-rbfn-export": "rbfn.export:main",
}

try:
    distribution("aco-rbfn")
    INSTALLED = True
except PackageNotFoundError:
    INSTALLED = False
needs_install = pytest.mark.skipif(not INSTALLED, reason="aco-rbfn is not installed (pip install -e .)")


@needs_install
def test_entry_points_resolve():
    found = {ep.name: ep for ep in entry_points(group="console_scripts") if ep.name in SCRIPTS}
    assert {name: ep.value for name, ep in found.items()} == SCRIPTS, "reinstall (pip install -e .) after editing"
    for ep in found.values():
        assert callable(ep.load())


@needs_install
@pytest.mark.parametrize(
    "name,shows",
    [
        ("aco-rbfn-summarize", "SWEEP_DIR"),
        ("aco-rbfn-export", "CHECKPOINT"),
        ("aco-rbfn-train", "python train.py [group=option ...]"),
        ("aco-rbfn-evaluate", "python evaluate.py [group=option ...]"),
    ],
)
def test_help_runs(name, shows, tmp_path):
    beside = Path(sys.executable).parent / name  # this interpreter's environment first
    exe = str(beside) if beside.is_file() else shutil.which(name)
    assert exe, f"{name} is not on PATH"
    out = subprocess.run([exe, "--help"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and shows in out.stdout, out.stderr[-2000:]
    assert list(tmp_path.iterdir()) == []  # --help writes nothing, wherever it runs


@needs_install
def test_the_version_is_pyprojects():
    import rbfn

    assert rbfn.__version__ == distribution("aco-rbfn").version
