"""What a refused or failed run leaves behind (rbfn.studies.rundir.hydra_run_dir): no directory, not
even the parents Hydra made for hydra.run.dir, when it wrote nothing or only its bookkeeping; its
results, named in the error, when it wrote some."""

import fcntl
import os
import subprocess
import sys
import time

import pytest
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import open_dict

from rbfn.studies.cli import one_line_errors
from rbfn.studies.rundir import birth_time, hydra_run_dir, remove_new_empty_parents

from ..conftest import ROOT, compose_config

needs_birth_time = pytest.mark.skipif(
    birth_time(ROOT) is None, reason="the file system records no creation times: new parents are kept"
)


@pytest.fixture
def hydra_job(tmp_path):
    """HydraConfig as a single run's job in tmp_path/run sees it (Hydra made the directory)."""
    cfg = compose_config("evaluate", f"hydra.run.dir={tmp_path / 'run'}", hydra=True)
    with open_dict(cfg):
        cfg.hydra.mode = RunMode.RUN
        cfg.hydra.runtime.output_dir = str(tmp_path / "run")
    HydraConfig.instance().set_config(cfg)
    (tmp_path / "kept").write_text("not this run's")
    (tmp_path / "run").mkdir()
    yield tmp_path / "run"
    HydraConfig.instance().cfg = None


def _bookkeeping(out):
    (out / ".hydra").mkdir()
    (out / ".hydra" / "config.yaml").write_text("n_test: 1\n")
    (out / "evaluate.log").write_text("started\n")
    (out / "events.out.tfevents.1.host.1.0").write_bytes(b"")


def test_a_run_failing_with_bookkeeping_only_leaves_no_directory(hydra_job):
    with pytest.raises(ValueError, match="bad value") as info, hydra_run_dir(own=True) as out:
        _bookkeeping(out)
        raise ValueError("bad value")
    assert not hydra_job.exists()
    assert not getattr(info.value, "__notes__", None)


def test_a_run_failing_after_results_keeps_them_and_says_so(hydra_job, capsys):
    with pytest.raises(SystemExit), one_line_errors(), hydra_run_dir(own=True) as out:
        _bookkeeping(out)
        (out / "workspace_error_map.png").write_bytes(b"png")
        raise ValueError("controller pd diverged")
    assert (hydra_job / "workspace_error_map.png").read_bytes() == b"png"
    assert (hydra_job / "evaluate.log").is_file()
    assert capsys.readouterr().err.splitlines() == [
        "error: controller pd diverged",
        f"note: {hydra_job} keeps what this run wrote before it stopped (workspace_error_map.png)",
    ]


def test_a_bug_after_results_keeps_its_traceback_with_the_note(hydra_job):
    with pytest.raises(KeyError) as info, one_line_errors(), hydra_run_dir(own=True) as out:
        (out / "last.pt").write_bytes(b"state")
        raise KeyError("bug")
    assert info.value.__notes__ == [
        f"{hydra_job} keeps what this run wrote before it stopped (last.pt); run the same command again to resume it"
    ]


def test_files_held_before_the_run_are_never_removed(hydra_job):
    (hydra_job / "last.pt").write_bytes(b"an interrupted run's state")
    with pytest.raises(ValueError), hydra_run_dir() as out:
        _bookkeeping(out)
        raise ValueError("bad value")
    assert (hydra_job / "last.pt").read_bytes() == b"an interrupted run's state"


@needs_birth_time
def test_only_parents_made_since_the_run_started_are_removed(tmp_path):
    old = tmp_path / "old"
    (old / "kept").mkdir(parents=True)
    time.sleep(0.05)  # the file system's clock is coarser than time.time()
    since = time.time()
    time.sleep(0.05)
    (old / "new" / "day" / "run").mkdir(parents=True)  # also changes old's modification time
    remove_new_empty_parents(old / "new" / "day" / "run", since)
    assert sorted(p.name for p in old.iterdir()) == ["kept"]
    remove_new_empty_parents(old / "kept", since)  # empty, but there before the run
    assert (old / "kept").is_dir()


def test_a_directory_another_run_holds_is_never_removed(tmp_path):
    """Two runs started in the same second: the first moves off the clock's name (relabel), the
    second makes it again and holds it; the first, leaving, removes what it made, but not that."""
    named = tmp_path / "12-00-00"
    named.mkdir()
    (tmp_path / "another run's").mkdir()  # the parent is kept
    fd = os.open(named, os.O_RDONLY)  # another open file description: another process's lock to this one
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        remove_new_empty_parents(named, since=0.0)
        assert named.is_dir()
    finally:
        os.close(fd)
    remove_new_empty_parents(named, since=0.0)  # free again: removed, as made since `since`
    assert not named.exists()


def _run(*args):
    env = {**os.environ, "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=120, env=env)


@needs_birth_time
@pytest.mark.parametrize(
    "script,override", [("train.py", "data.n_val=0"), ("evaluate.py", "n_test=0")], ids=["train", "evaluate"]
)
def test_a_refused_run_leaves_none_of_the_parents_hydra_made(tmp_path, script, override):
    (tmp_path / "kept").mkdir()
    r = _run(script, override, f"hydra.run.dir={tmp_path / 'a' / 'b' / 'run'}")
    assert r.returncode == 1 and r.stderr.startswith("error: "), r.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["kept"]


def test_a_control_part_that_diverges_before_any_result_leaves_no_directory(tmp_path):
    r = _run(
        "evaluate.py",
        "ik=false",
        "online.enabled=false",
        "loop=ideal",
        "gains.Lambda=1e9",  # the surface far stiffer than the step can follow (K itself is capped)
        "control.controllers=[pd]",
        "control.duration=1",
        "control.payload_on=0.6",
        "control.payload_off=0.9",
        f"hydra.run.dir={tmp_path / 'day' / 'run'}",
    )
    assert r.returncode == 1, r.stderr
    assert r.stderr.splitlines()[-1].startswith("error: controller pd, payload 0kg: simulation diverged"), r.stderr
    assert "Traceback" not in r.stderr
    assert tmp_path.is_dir() and list(tmp_path.iterdir()) == []  # there before the run: kept


@pytest.mark.parametrize(
    "script,override", [("train.py", "data.n_val=0"), ("evaluate.py", "n_test=0")], ids=["train", "evaluate"]
)
def test_a_refused_run_keeps_the_empty_directory_the_user_made(tmp_path, script, override):
    """An empty run directory made before the run is the user's: a refused run leaves it, and its
    mode, as they were."""
    mine = tmp_path / "mine"
    mine.mkdir(mode=0o700)
    time.sleep(0.05)  # the file system's clock is coarser than time.time()
    r = _run(script, override, f"hydra.run.dir={mine}")
    assert r.returncode == 1 and r.stderr.startswith("error: "), r.stderr
    assert mine.is_dir() and not os.listdir(mine)
    assert mine.stat().st_mode & 0o777 == 0o700
