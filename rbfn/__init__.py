"""aco-rbfn: RBF networks with ACO-chosen centres for robot inverse kinematics and control."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("aco-rbfn")  # pyproject.toml's [project] version, the one source
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

from .checkpoint import load_model
from .layer import RBFNetwork
from .solver import IKSolver, load_solver

__all__ = ["load_model", "load_solver", "IKSolver", "RBFNetwork", "__version__"]
