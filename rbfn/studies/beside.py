"""Run one part of a study in a forked process beside the main one.

evaluate.py's parts are independent, and each closed loop at a small batch is per-operation
overhead on one core: two parts side by side take the longer one's time on a machine with two
cores. Forking (not spawning) costs no re-import; it is used where it is safe: a POSIX `fork`,
more than one usable core, and CPU work only (CUDA cannot be used across a fork). Elsewhere the
part runs at once, in this process. The child runs with one torch thread (the parent's
thread pool does not survive a fork) and inherits the logging handlers, so its log lines reach
the same console and log file.
"""
from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from typing import Any

import torch

__all__ = ["can_fork", "Beside"]


def can_fork(device: str) -> bool:
    """Whether `Beside` would fork for work on `device`: POSIX fork, >= 2 usable cores, CPU."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return device == "cpu" and cores >= 2 and "fork" in multiprocessing.get_all_start_methods()


def _in_child(fn: Callable, args: tuple) -> Any:
    torch.set_num_threads(1)
    return fn(*args)


class Beside:
    """`fn(*args)` started in a forked process (if `fork`), else run when `result()` is asked for.

    Use as a context manager: leaving it on an error stops the child."""

    def __init__(self, fn: Callable, *args, fork: bool = True) -> None:
        self._fn, self._args, self._pool, self._async = fn, args, None, None
        if fork:
            self._pool = multiprocessing.get_context("fork").Pool(1)
            self._async = self._pool.apply_async(_in_child, (fn, args))

    def result(self) -> Any:
        """fn's return value (its exception re-raised here)."""
        if self._pool is None:
            return self._fn(*self._args)
        try:
            return self._async.get()
        finally:
            self._pool.close()
            self._pool.join()
            self._pool = None
            self._fn = None

    def __enter__(self) -> "Beside":
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:          # result() was not reached: stop the child
            self._pool.terminate()
            self._pool.join()
            self._pool = None
