"""A stopped command stops everything it started (rbfn.studies.stop): after SIGTERM to evaluate.py,
within seconds no process it started is left, its exit status is 143, no temporary file is left
and no file in its run directory changes afterwards. A forked part ends with its caller however
the caller ended, and a write stopped in the middle, even by SIGKILL, leaves no temporary file.
(A joblib multirun stopped the same way: tests/test_sweeps.py.)"""

import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import train
from rbfn.files import atomic_write_bytes
from rbfn.studies.beside import Beside, can_fork
from rbfn.studies.stop import stop_on_signals

from ..conftest import ROOT, TINY_TRAIN, compose_config

fork = multiprocessing.get_context("fork")


def _write_slowly(path: str, ready) -> None:
    """Write `path` (atomically), stopping half-way until killed; `ready` is told once half-way."""
    stop_on_signals()

    def write(f):
        f.write(b"new" * 1000)
        f.flush()
        ready.send(os.getpid())
        time.sleep(60)

    atomic_write_bytes(Path(path), write)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_write_stopped_half_way_leaves_the_old_file_and_no_temporary_file(tmp_path, sig):
    target = tmp_path / "metrics.json"
    target.write_bytes(b"old")
    ready, tell = fork.Pipe(duplex=False)
    child = fork.Process(target=_write_slowly, args=(str(target), tell))
    child.start()
    try:
        assert ready.poll(30), "the writer did not start"
        ready.recv()
        os.kill(child.pid, sig)
        child.join(10)
        assert child.exitcode == (128 + sig if sig == signal.SIGTERM else -sig)
    finally:
        child.kill()
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"] and target.read_bytes() == b"old"


def _sleep_then_write(path: str) -> None:
    time.sleep(1.0)
    Path(path).write_text("still running")


def _caller(flag: str, tell) -> None:
    with Beside(_sleep_then_write, flag) as part:
        tell.send(part._proc.pid)
        time.sleep(60)


@pytest.mark.skipif(not can_fork("cpu"), reason="this machine does not fork, or has one core")
def test_a_forked_part_ends_with_its_caller_even_when_the_caller_is_killed(tmp_path):
    flag = tmp_path / "flag"
    got, tell = fork.Pipe(duplex=False)
    caller = fork.Process(target=_caller, args=(str(flag), tell))
    caller.start()
    assert got.poll(30)
    part = got.recv()
    os.kill(caller.pid, signal.SIGKILL)
    caller.join()
    assert _gone([part], 5.0), "the forked part outlived its caller"
    time.sleep(1.5)
    assert not flag.exists()


def _stat(pid: int):
    """(state, parent, process group) of `pid`; None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    state, ppid, pgrp = text[text.rindex(")") + 2 :].split()[:3]
    return state, int(ppid), int(pgrp)


def group(pgid: int) -> list[int]:
    """The live (not zombie) processes of process group `pgid`."""
    found = [(int(p), _stat(int(p))) for p in os.listdir("/proc") if p.isdigit()]
    return [p for p, s in found if s is not None and s[2] == pgid and s[0] not in "ZX"]


def _gone(pids, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if all(_stat(p) is None or _stat(p)[0] in "ZX" for p in pids):
            return True
        time.sleep(0.05)
    return False


def _files(d: Path) -> dict:
    return {p: (p.stat().st_size, p.stat().st_mtime_ns) for p in d.rglob("*") if p.is_file()}


def start(args: list[str], log: Path) -> subprocess.Popen:
    """`python ARGS` in the repository root as the leader of a new process group, its output in
    `log` (not a pipe: processes it leaves behind could hold a pipe open)."""
    with open(log, "w") as out:
        return subprocess.Popen(
            [sys.executable, *args], cwd=ROOT, start_new_session=True, stdout=out, stderr=subprocess.STDOUT
        )


def stop_and_check(
    proc: subprocess.Popen, log: Path, run_dir: Path, started, seconds: float = 120, sig: int = signal.SIGTERM
) -> None:
    """Once `started()`, send `sig` to `proc` (from `start`; SIGINT to its whole group, as Ctrl-C
    does): it exits with 128 + sig, saying so in one line and with no traceback, every process
    of its group is gone within seconds, no *.tmp is left and no file under `run_dir` changes
    afterwards."""
    try:
        deadline = time.monotonic() + seconds
        while not started():
            assert proc.poll() is None, f"exited early ({proc.returncode}): {log.read_text()[-3000:]}"
            assert time.monotonic() < deadline, "the command did not start its processes in time"
            time.sleep(0.1)
        before = group(proc.pid)
        assert len(before) > 1, before
        if sig == signal.SIGINT:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        assert proc.wait(timeout=30) == 128 + sig, log.read_text()[-3000:]
        assert _gone(before, 5.0), f"still running after {signal.Signals(sig).name}: {group(proc.pid)}"
        text = log.read_text()
        assert "Traceback" not in text and "KeyboardInterrupt" not in text, text[-3000:]
        stopped = f"stopped by {signal.Signals(sig).name} (exit status {128 + sig})"
        assert any(line.startswith(stopped) for line in text.splitlines()), text[-3000:]
    finally:
        for pid in group(proc.pid):
            os.kill(pid, signal.SIGKILL)
        proc.wait()
    assert not list(run_dir.rglob("*.tmp"))
    files = _files(run_dir)
    time.sleep(2.0)
    assert _files(run_dir) == files


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    out = tmp_path_factory.mktemp("train")
    train.run(
        compose_config("train", *TINY_TRAIN),
        out,
    )
    return out / "checkpoint.pt"


@pytest.mark.skipif(not can_fork("cpu"), reason="this machine does not fork, or has one core")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "Ctrl-C"])
def test_a_signal_to_evaluate_stops_its_forked_part(ckpt, tmp_path, sig):
    run_dir = tmp_path / "eval"
    # Both parts last far longer than the test: the checkpoint's (forked) and the control part.
    proc = start(
        [
            "evaluate.py",
            f"checkpoint={ckpt}",
            "n_test=300",
            "online.duration=60",
            "online.sizes=[0.03]",
            "control.duration=60",
            "control.controllers=[smc]",
            "control.payloads=[0.0]",
            f"hydra.run.dir={run_dir}",
        ],
        tmp_path / "out.log",
    )
    # The forked part has started once its TensorBoard events file is there.
    stop_and_check(proc, tmp_path / "out.log", run_dir, lambda: any(run_dir.glob("events.*.checkpoint")), sig=sig)
