"""Console scripts for train.py and evaluate.py (aco-rbfn-train, aco-rbfn-evaluate), and the
one-line error of the package's argparse tools (`fail`).

The two Hydra applications live at the repository root beside conf/, which Hydra finds relative
to the script (config_path="conf"). These entry points run that script as `python train.py`
would: as __main__, with sys.argv[0] naming it and its directory first on sys.path, so the job
name, the config search path, the output directories, signal handling and exit statuses are the
same. They need the source checkout the package is installed from (`pip install -e .`); from
anywhere else they refuse in one line.
"""

from __future__ import annotations

import argparse
import runpy
import sys
from pathlib import Path
from typing import NoReturn

__all__ = ["evaluate", "fail", "train"]

ROOT = Path(__file__).resolve().parent.parent


def _run_script(name: str) -> None:
    script, config = ROOT / f"{name}.py", ROOT / "conf" / f"{name}.yaml"
    if not (script.is_file() and config.is_file()):
        print(
            f"error: aco-rbfn-{name} runs {name}.py of the source checkout, and {ROOT} has no {name}.py "
            f"and conf/{name}.yaml; install the package from a checkout with pip install -e . (or run "
            f"python {name}.py there)",
            file=sys.stderr,
        )
        raise SystemExit(1)
    sys.argv[0] = str(script)
    sys.path.insert(0, str(ROOT))
    runpy.run_path(str(script), run_name="__main__")


def train() -> None:
    """`python train.py ARGS` as the console script aco-rbfn-train."""
    _run_script("train")


def evaluate() -> None:
    """`python evaluate.py ARGS` as the console script aco-rbfn-evaluate."""
    _run_script("evaluate")


def fail(parser: argparse.ArgumentParser, message: str, status: int = 2) -> NoReturn:
    """Exit with `status` after a one-line error in argparse's manner, `PROG: error: MESSAGE`
    (without the usage; the message's whitespace folded to single spaces)."""
    parser.exit(status, f"{parser.prog}: error: {' '.join(message.split())}\n")
