"""An entry point's refusal is one line on stderr (the traceback behind HYDRA_FULL_ERROR=1), and
leaves nothing behind."""

import os
import subprocess
import sys

import pytest

from ..conftest import ROOT


def _run(*args, env=None):
    return subprocess.run(
        [sys.executable, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.parametrize(
    "script,override,message",
    [
        ("train.py", "data.n_val=0", "error: data.n_val=0 is not allowed: must be > 0"),
        ("evaluate.py", "n_test=0", "error: n_test=0 is not allowed: must be > 0"),
    ],
)
def test_a_refused_setting_is_one_line_and_writes_nothing(tmp_path, script, override, message):
    r = _run(script, override, f"hydra.run.dir={tmp_path / 'run'}", env={"HYDRA_FULL_ERROR": "0"})
    assert r.returncode == 1 and r.stderr.strip().splitlines() == [message], r.stderr
    assert not (tmp_path / "run").exists()
    full = _run(script, override, f"hydra.run.dir={tmp_path / 'run'}", env={"HYDRA_FULL_ERROR": "1"})
    assert full.returncode == 1 and "Traceback" in full.stderr and message[len("error: ") :] in full.stderr


def test_a_run_directory_below_a_file_is_named(tmp_path):
    # (On the command line Hydra makes the directory first and names the path in its own error.)
    from rbfn.studies.rundir import RunDir, RunDirInUse

    (tmp_path / "afile").write_text("keep")
    with (
        pytest.raises(RunDirInUse, match=r"hydra.run.dir=.*afile/run: .*afile is a file, not a directory"),
        RunDir(tmp_path / "afile" / "run"),
    ):
        pass
    assert (tmp_path / "afile").read_text() == "keep"
