"""Run one part of a study in a forked process beside the main one.

evaluate.py's parts are independent, and each closed loop at a small batch is per-operation
overhead on one core: two parts side by side take the longer one's time on a machine with two
cores. Forking (not spawning) costs no re-import and passes the arguments without pickling them;
it is used where it is safe: a POSIX `fork`, more than one usable core, and CPU work only (CUDA
cannot be used across a fork). Elsewhere the part runs when its result is asked for, in this
process. The child runs with one torch thread (the parent's thread pool does not survive a fork)
and inherits the logging handlers, so its log lines reach the same console and log file; only
its result (or its exception) is pickled back. The child ends with its parent, and SIGTERM or
SIGHUP stop it after its cleanup (rbfn.studies.stop); a caller that fails or is stopped stops it.
"""

from __future__ import annotations

import multiprocessing
import os
import time
import traceback
from collections.abc import Callable
from typing import Any

import torch

from .stop import Stopped, stop_on_signals

__all__ = ["can_fork", "Beside", "ChildTraceback"]


def can_fork(device: str) -> bool:
    """Whether `Beside` would fork for work on `device`: POSIX fork, >= 2 usable cores, CPU."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return device == "cpu" and cores >= 2 and "fork" in multiprocessing.get_all_start_methods()


class ChildTraceback(Exception):
    """The forked part's traceback, as the cause of the exception it raised."""


def _in_child(fn: Callable, args: tuple, conn) -> None:
    stop_on_signals()
    torch.set_num_threads(1)
    try:
        out = (True, fn(*args), "")
    except Stopped:
        raise  # the child exits with 128 + the signal's number
    except BaseException as e:  # noqa: BLE001 - every other failure goes back to the parent
        out = (False, e, traceback.format_exc())
    try:
        conn.send(out)
    except Exception as e:  # noqa: BLE001 - an unpicklable result or exception
        conn.send(
            (
                False,
                RuntimeError(f"the forked part's outcome could not be sent back: {e!r}"),
                out[2] or traceback.format_exc(),
            )
        )
    conn.close()


class Beside:
    """`fn(*args)` started in a forked process (if `fork`), else run when `result()` is asked for.

    Use as a context manager: leaving it before `result()` (on an error) stops the child."""

    _conn: Any  # the receiving end of the pipe while a child runs, else None

    def __init__(self, fn: Callable, *args, fork: bool = True) -> None:
        self._fn, self._args, self._proc, self._conn = fn, args, None, None
        if fork:
            ctx = multiprocessing.get_context("fork")
            self._conn, send = ctx.Pipe(duplex=False)
            self._proc = ctx.Process(target=_in_child, args=(fn, args, send), daemon=True)
            self._proc.start()
            send.close()

    def result(self) -> Any:
        """fn's return value; its exception re-raised here (caused by the child's traceback)."""
        if self._proc is None:
            return self._fn(*self._args)
        received = False
        try:
            ok, value, tb = self._conn.recv()
            received = True
        except EOFError:
            self._proc.join()
            raise RuntimeError(
                f"the forked part {getattr(self._fn, '__name__', self._fn)} ended without a "
                f"result (exit code {self._proc.exitcode})"
            ) from None
        finally:
            self._stop(wait=received)  # interrupted (stopped) here: no waiting for the child
        if not ok:
            raise value from ChildTraceback(tb)
        return value

    def _stop(self, wait: bool) -> None:
        """End the child: let it exit for up to 5 s if `wait`, else terminate it (SIGTERM: it cleans
        up and exits) and kill it if it has not ended 5 s later."""
        if self._proc is None:
            return
        if wait:
            self._proc.join(timeout=5.0)
        deadline = time.monotonic() + 5.0
        while self._proc.is_alive() and time.monotonic() < deadline:
            # SIGTERM, again every 0.1 s: one that reaches a child just forked, before Python's start-up
            # in it, is dropped there (the child clears the signals pending at its start); one that comes
            # during its cleanup is ignored (rbfn.studies.stop)
            self._proc.terminate()
            self._proc.join(timeout=0.1)
        if self._proc.is_alive():
            self._proc.kill()
        self._proc.join()
        self._conn.close()
        self._proc = self._conn = None

    def __enter__(self) -> Beside:
        return self

    def __exit__(self, *exc) -> None:
        self._stop(wait=False)  # result() was not reached: stop the child
