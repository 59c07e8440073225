"""A stopped command stops everything it started, and leaves no half-written file behind.

By default SIGTERM (what kill, timeout and SLURM send) and SIGHUP (a closed terminal) end a Python
process at once: no `finally` block or context manager's exit runs, so a temporary file being
written stays, and the processes the command started (evaluate.py's forked parts, a joblib
multirun's workers) go on writing into the run directory. SIGINT (Ctrl-C) raises
KeyboardInterrupt wherever the process is, which a library's broad `except` may swallow, and which
ends in a traceback. After `stop_on_signals()` (train.py and
evaluate.py call it first) the first such signal, in the main thread:

1. is passed on to this process's children (those that do not ignore it) and waits up to
   `CHILDREN_SECONDS` for them to end, each after its own cleanup;
2. raises `Stopped`, a SystemExit with the conventional status 128 + the signal's number (143 for
   SIGTERM, 130 for SIGINT): every `finally` and context manager's exit runs on the way out, and
   the entry point says so in one line (rbfn.studies.cli.report_stop).

Later signals are ignored (they would cut that cleanup short); a process forked from it then
handles its own first signal. A process started by another (a forked part, a pool's worker) also
asks Linux to send it SIGTERM when its parent ends, however the parent ended (PR_SET_PDEATHSIG); a
pool's worker stopped by a signal ends once its job's cleanup ran (`job`) instead of going back to
its pool. A handler some launcher installed (submitit's, under SLURM), or a signal the process was
started ignoring (nohup), is left as it is.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager, suppress
from typing import cast

from ..files import STOP_SIGNALS

__all__ = ["Stopped", "job", "stop_on_signals"]

SIGNALS = STOP_SIGNALS  # SIGINT, SIGTERM, SIGHUP: rbfn.files defers them while files are renamed
CHILDREN_SECONDS = 10.0  # how long a stopped process waits for its children's cleanup
_PR_SET_PDEATHSIG = 1
_stopping = False


class Stopped(SystemExit):
    """This process was stopped by signal `signum`; its exit status is 128 + signum."""

    def __init__(self, signum: int) -> None:
        super().__init__(128 + signum)
        self.signum = signum


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of process `pid` from /proc; None when there is no such process."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            text = f.read()
    except OSError:
        return None
    state, ppid = text[text.rindex(")") + 2 :].split()[:2]
    return state, int(ppid)


def _running_child(pid: int) -> bool:
    """Whether `pid` is a child of this process that has not ended (a zombie has)."""
    s = _stat(pid)
    return s is not None and s[1] == os.getpid() and s[0] not in "ZX"


def _ignores(pid: int, signum: int) -> bool:
    """Whether process `pid` ignores signal `signum` (as multiprocessing's resource tracker does)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            mask = next(int(line.split()[1], 16) for line in f if line.startswith("SigIgn:"))
    except (OSError, StopIteration, ValueError):
        return False
    return bool(mask >> (signum - 1) & 1)


def _stop_children(signum: int) -> None:
    """Send `signum` to this process's running children that heed it; wait for them to end."""
    try:
        pids = [int(p) for p in os.listdir("/proc") if p.isdigit()]
    except OSError:  # no /proc: the children's context managers stop them instead
        return
    children = [p for p in pids if _running_child(p) and not _ignores(p, signum)]
    for pid in children:
        with suppress(ProcessLookupError):
            os.kill(pid, signum)
    deadline = time.monotonic() + CHILDREN_SECONDS
    while any(map(_running_child, children)) and time.monotonic() < deadline:
        time.sleep(0.02)


def _not_stopping() -> None:
    global _stopping
    _stopping = False


# A process forked while this one was stopping (or after a signal it handled in a test) is not
# stopping itself: it handles its own first signal.
os.register_at_fork(after_in_child=_not_stopping)


def _on_signal(signum: int, frame) -> None:
    global _stopping
    if _stopping:
        return
    _stopping = True
    _stop_children(signum)
    raise Stopped(signum)


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def _die_with_parent(parent: int) -> None:
    """Ask Linux for SIGTERM when the parent process ends; stop now if it has ended already."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent and not _exists(parent):  # (a forkserver's child has another parent)
        os.kill(os.getpid(), signal.SIGTERM)


def stop_on_signals() -> None:
    """SIGTERM and SIGHUP stop this process as the module says (from the main thread; elsewhere
    nothing changes). In a process started by multiprocessing or loky, it also ends with its parent."""
    if threading.current_thread() is not threading.main_thread():
        return
    for s in SIGNALS:
        if signal.getsignal(s) in (signal.SIG_DFL, signal.default_int_handler, _on_signal):
            signal.signal(s, _on_signal)
    parent = multiprocessing.parent_process()
    if parent is not None:
        _die_with_parent(cast(int, parent.pid))  # a started process's pid


@contextmanager
def job():
    """An entry point's job: `stop_on_signals()`, and in a pool's worker process a `Stopped` that
    left the job (its cleanup done) ends the process instead of returning the worker to its pool."""
    stop_on_signals()
    try:
        yield
    except Stopped as e:
        if multiprocessing.parent_process() is not None:
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(e.code)
        raise
