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


@pytest.mark.parametrize("progress,tty,beats", [(True, True, True), (False, True, False), (True, False, False)])
def test_a_part_says_what_it_does_how_long_it_took_and_on_a_terminal_that_it_runs(
    monkeypatch, caplog, progress, tty, beats
):
    import logging
    import time

    from rbfn.studies import cli

    monkeypatch.setattr(cli, "HEARTBEAT_S", 0.02)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: tty)
    log = logging.getLogger("test_cli")
    with (
        caplog.at_level(logging.INFO, logger="test_cli"),
        cli.announced(log, "control", "6 controllers", progress) as t,
    ):
        time.sleep(0.15)
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "control: 6 controllers" and lines[-1] == f"control: done in {t['seconds']:.1f} s"
    assert t["seconds"] >= 0.15
    assert any(line.startswith("control: still running (") for line in lines[1:-1]) == beats
    assert len(lines) == 2 or beats


def test_a_failed_part_logs_no_end_line(caplog):
    import logging

    from rbfn.studies.cli import announced

    log = logging.getLogger("test_cli")
    with caplog.at_level(logging.INFO, logger="test_cli"), pytest.raises(ValueError), announced(log, "ik", "x", False):
        raise ValueError("bad")
    assert [r.getMessage() for r in caplog.records] == ["ik: x"]
