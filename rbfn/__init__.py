"""aco-rbfn: RBF networks with ACO-chosen centres for robot inverse kinematics and control."""
__version__ = "0.1.0"

from .checkpoint import load_model  # noqa: E402
from .layer import RBFNetwork  # noqa: E402
from .solver import IKSolver, load_solver  # noqa: E402

__all__ = ["load_model", "load_solver", "IKSolver", "RBFNetwork", "__version__"]
