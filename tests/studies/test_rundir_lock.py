"""A run directory belongs to one command (rbfn.studies.rundir.RunDir): a clock-named directory that
another process holds or that holds files is passed over for a numbered sibling, a named one in use
is refused, evaluate.py never writes into a directory holding files (a training run's), and a
refused run leaves no directory behind."""

import fcntl
import json
import os
import subprocess
import sys
from contextlib import contextmanager

import pytest

import train
from rbfn.studies.rundir import RunDir, RunDirInUse, relabel

from ..conftest import ROOT, TINY_TRAIN, compose_config

TINY = TINY_TRAIN


@contextmanager
def held_elsewhere(path):
    """The lock on `path` as another process holds it (a lock of another open file description)."""
    fd = os.open(path, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        yield
    finally:
        os.close(fd)


def _snapshot(d):
    return {p.relative_to(d): (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(d.rglob("*")) if p.is_file()}


def test_a_clock_named_directory_in_use_or_holding_files_is_passed_over(tmp_path):
    named = tmp_path / "12-00-00"
    named.mkdir()
    with held_elsewhere(named), RunDir(named, fresh=True) as first:
        assert first.path == tmp_path / "12-00-00_1"
        (first.path / "metrics.json").write_text("{}")
    (named / "train.log").write_text("another run's")
    (tmp_path / "12-00-00_2").mkdir()  # made by another run, not locked yet
    with RunDir(named, fresh=True) as second:
        assert second.path == tmp_path / "12-00-00_3"  # the others are another run's
    (named / "train.log").unlink()
    with RunDir(named, fresh=True) as third:
        assert third.path == named  # free and empty: taken as it is


def test_a_clock_named_directory_is_labelled_with_its_robot_and_keeps_its_lock(tmp_path):
    """relabel renames a clock-named directory NAME_robot (TensorBoard names runs by directory),
    passes over a taken name, moves the lock with it, and keeps a directory the user named."""
    named = tmp_path / "12-00-00"
    (tmp_path / "12-00-00_ur5").mkdir()  # another run's
    with RunDir(named, fresh=True, tidy=True) as run:
        assert relabel(named, "ur5") == tmp_path / "12-00-00_ur5_1" == run.path
        assert not named.exists()
        fd = os.open(run.path, os.O_RDONLY)  # another open file description: the lock is another's to it
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
    assert not (tmp_path / "12-00-00_ur5_1").exists()  # tidied: empty, made for the run
    with RunDir(named, fresh=True, tidy=True) as run:  # a URDF's own name, whatever it holds
        assert relabel(named, "my arm/v2") == tmp_path / "12-00-00_my-arm-v2" == run.path
    named.mkdir()
    with held_elsewhere(named), RunDir(named, fresh=True, tidy=True) as run:  # the clock's name taken
        assert run.path == tmp_path / "12-00-00_1"
        assert relabel(run.path, "scara") == tmp_path / "12-00-00_scara" == run.path  # numbered after
    mine = tmp_path / "my_run"
    with RunDir(mine) as run:
        assert relabel(mine, "ur5") == mine == run.path


def test_a_named_directory_in_use_or_holding_files_is_refused(tmp_path):
    with (
        held_elsewhere(tmp_path),
        pytest.raises(RunDirInUse, match=f"{tmp_path} is in use by another process"),
        RunDir(tmp_path),
    ):
        pass
    (tmp_path / "metrics.json").write_text("{}")
    with (
        pytest.raises(RunDirInUse, match=r"holds files already \(metrics.json\).*new or empty hydra.run.dir"),
        RunDir(tmp_path, own=True),
    ):
        pass
    with RunDir(tmp_path) as d:  # a training run may hold its own files
        assert d.path == tmp_path


def test_the_lock_is_reentrant_and_an_empty_directory_is_tidied(tmp_path):
    run = tmp_path / "run"
    with RunDir(run, tidy=True):
        with RunDir(run, own=True):  # the caller holds it: entered as it is
            pass
        with held_elsewhere(tmp_path), pytest.raises(RunDirInUse), RunDir(tmp_path):
            pass
    assert not run.exists()  # left empty: removed
    with RunDir(run, tidy=True):
        (run / "train.log").write_text("x")
    assert (run / "train.log").exists()
    with RunDir(run):  # free again
        pass


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("train")
    train.run(compose_config("train", *TINY), out, {".hydra/overrides.yaml": "- seed=0\n"})
    return out


def _evaluate(*overrides: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "evaluate.py", "control.enabled=false", "online.enabled=false", "n_test=200", *overrides],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_two_evaluations_started_together_keep_both_results(trained, tmp_path):
    # Both name the same clock-named directory (as two runs started in the same second do).
    same = f"hydra.run.dir={tmp_path}/eval-${{now:%Y}}"
    runs = [_evaluate(f"checkpoint={trained / 'checkpoint.pt'}", same) for _ in range(2)]
    for r in runs:
        _, err = r.communicate(timeout=120)
        assert r.returncode == 0, err[-3000:]
    dirs = sorted(tmp_path.iterdir())
    assert len(dirs) == 2 and dirs[1].name == dirs[0].name + "_1"
    for d in dirs:
        assert json.loads((d / "metrics.json").read_text())["ik"]["test_pos_err_mm_median"] > 0
        assert (d / ".hydra" / "config.yaml").is_file() and (d / "evaluate.log").stat().st_size > 0
        assert f"output_dir: {d}" in (d / ".hydra" / "hydra.yaml").read_text()


def test_two_trainings_started_together_both_run(tmp_path):
    same = f"hydra.run.dir={tmp_path}/train-${{now:%Y}}"
    runs = [
        subprocess.Popen(
            [sys.executable, "train.py", *TINY, same],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    for r in runs:
        _, err = r.communicate(timeout=120)
        assert r.returncode == 0, err[-3000:]
    dirs = sorted(tmp_path.iterdir())
    assert len(dirs) == 2 and dirs[1].name == dirs[0].name + "_1"
    for d in dirs:
        assert json.loads((d / "metrics.json").read_text())["num_centers"] == 10
        assert "test position error median" in (d / "train.log").read_text()


def test_evaluate_into_a_training_run_is_refused_and_changes_nothing(trained):
    before = _snapshot(trained)
    r = _evaluate(f"checkpoint={trained / 'checkpoint.pt'}", f"hydra.run.dir={trained}")
    _, err = r.communicate(timeout=120)
    assert r.returncode != 0 and f"hydra.run.dir={trained} holds files already" in err, err[-3000:]
    assert _snapshot(trained) == before


def test_a_refused_evaluation_leaves_no_directory(trained, tmp_path):
    r = _evaluate(f"checkpoint={trained / 'checkpoint.pt'}", "n_test=0", f"hydra.run.dir={tmp_path / 'eval'}")
    _, err = r.communicate(timeout=120)
    assert r.returncode != 0 and "n_test=0" in err, err[-3000:]
    assert list(tmp_path.iterdir()) == []
