"""A part run in a forked process beside the main one: same result as in this process, its
errors raised here, and stopped when the caller fails first."""

import os
import subprocess
import sys

import pytest
import torch

from rbfn.studies.beside import Beside, ChildTraceback, can_fork


def _work(n: int) -> tuple[int, float]:
    g = torch.Generator().manual_seed(n)
    return os.getpid(), float(torch.rand(1000, generator=g, dtype=torch.float64).sum())


def _fail(msg: str) -> None:
    raise ValueError(msg)


@pytest.mark.skipif(not can_fork("cpu"), reason="this machine does not fork, or has one core")
def test_forked_part_equals_the_same_part_run_here():
    with Beside(_work, 3) as forked:
        pid, value = forked.result()
    with Beside(_work, 3, fork=False) as here:
        pid_here, value_here = here.result()
    assert pid != os.getpid() and pid_here == os.getpid() and value == value_here
    big = torch.arange(10)  # arguments reach the child by the fork, unpickled
    with Beside(lambda: float(big.sum())) as lam:
        assert lam.result() == 45.0


@pytest.mark.skipif(not can_fork("cpu"), reason="this machine does not fork, or has one core")
def test_errors_reach_the_caller_and_a_failing_caller_stops_the_part(tmp_path):
    with pytest.raises(ValueError, match="bad part") as err, Beside(_fail, "bad part") as b:
        b.result()
    assert isinstance(err.value.__cause__, ChildTraceback) and "_fail" in str(err.value.__cause__)
    with pytest.raises(RuntimeError, match="ended without a result"), Beside(os._exit, 3) as b:
        b.result()
    _a_failing_caller_stops_the_part_at_once(tmp_path)


@pytest.mark.skipif(not can_fork("cpu"), reason="this machine does not fork, or has one core")
def test_a_part_forked_by_a_stopping_caller_still_stops_at_sigterm(tmp_path):
    """A caller that has handled a stop signal ignores later ones (rbfn.studies.stop); a part it forks
    handles its own: SIGTERM stops it at once, not after the 5 s its caller waits before killing it."""
    _a_failing_caller_stops_the_part_at_once(tmp_path, stopping=True)


# A caller as an entry point is: a fresh interpreter (a test worker's threads and thread pools, which a
# fork copies in whatever state they are, are not what a part is forked from), with the stop handlers
# installed and, if asked, one stop signal handled already. It forks a part that sleeps 5 s and then
# writes a file, fails at once, and prints how long it took to leave the `Beside` block.
_CALLER = """
import sys, time
from rbfn.studies import stop
from rbfn.studies.beside import Beside

def _sleep(path):
    time.sleep(5.0)
    open(path, "w").close()

stop.stop_on_signals()
stop._stopping = sys.argv[2] == "stopping"
t0 = time.perf_counter()
try:
    with Beside(_sleep, sys.argv[1]):
        raise RuntimeError("caller failed")
except RuntimeError:
    print(time.perf_counter() - t0)
"""


def _a_failing_caller_stops_the_part_at_once(tmp_path, stopping: bool = False) -> None:
    """A part forked by a caller that fails at once (`_CALLER`): stopped within 4 s (SIGTERM, not
    the kill 5 s later), its file never written."""
    flag = tmp_path / "finished"
    mode = "stopping" if stopping else "running"
    run = subprocess.run([sys.executable, "-c", _CALLER, str(flag), mode], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    elapsed = float(run.stdout.split()[-1])
    assert elapsed < 4.0 and not flag.exists(), f"the part ran {elapsed:.1f} s after its caller failed"


def test_no_fork_for_cuda_work():
    assert not can_fork("cuda")
    assert not can_fork("cuda:0")
