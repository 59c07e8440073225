"""What a user sees when an entry point (train.py, evaluate.py) refuses or fails: one line.

A refused setting, file or directory (ValueError, OSError, a run directory in use, another
config's run) or a diverged closed loop (its message names the controller, case, step and state)
is printed as one line, `error: <message>`, and the command exits with status 1;
the traceback is shown with HYDRA_FULL_ERROR=1 (as Hydra's own errors are). Anything else (a bug)
keeps its traceback. In a multirun every error is left to Hydra, which runs the other jobs and
reports the first failure at the end.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager

from ..control.simulator import SimulationDiverged
from ..resume import DifferentRun
from .rundir import RunDirInUse

__all__ = ["REFUSALS", "one_line_errors"]

REFUSALS = (ValueError, OSError, RunDirInUse, DifferentRun, SimulationDiverged)


@contextmanager
def one_line_errors(enabled: bool = True):
    """Inside, a refusal (REFUSALS) ends the process with `error: <message>` on stderr and exit
    status 1 (where `enabled` and HYDRA_FULL_ERROR is not 1)."""
    try:
        yield
    except REFUSALS as e:
        if not enabled or os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        print(f"error: {e}", file=sys.stderr, flush=True)
        sys.exit(1)
