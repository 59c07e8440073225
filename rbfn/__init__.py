"""aco-rbfn: RBF networks with ACO-chosen centres for robot inverse kinematics and control."""

import signal
import sys
from importlib.metadata import PackageNotFoundError, version


def _run_module() -> str:
    """The module `python -m MODULE` runs, while Python is still importing its packages (then
    sys.argv[0] is "-m"); "" otherwise."""
    argv = getattr(sys, "orig_argv", [])
    if sys.argv[:1] != ["-m"]:
        return ""
    flag = next((i for i, a in enumerate(argv) if a.startswith("-m")), None)
    if flag is None:
        return ""
    return argv[flag][2:] or (argv[flag + 1] if flag + 1 < len(argv) else "")


# `python -m rbfn.export`: Ctrl-C while the imports below load (torch: seconds) ends the process
# at once, status 130, instead of in a traceback; the command's main takes SIGINT over (as train.py
# and evaluate.py do before their imports).
if _run_module() == "rbfn.export" and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    signal.signal(signal.SIGINT, signal.SIG_DFL)

try:
    __version__ = version("aco-rbfn")  # pyproject.toml's [project] version, the one source
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

from .checkpoint import load_model  # noqa: E402 - Ctrl-C is set to end `python -m rbfn.export` before these load
from .layer import RBFNetwork  # noqa: E402
from .solver import IKSolver, load_solver  # noqa: E402

__all__ = ["load_model", "load_solver", "IKSolver", "RBFNetwork", "__version__"]
