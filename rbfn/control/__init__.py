"""Closed-loop control of the SCARA: batched simulator, controllers, the adaptive RBFN, scenarios."""
from .controllers import CONTROLLERS, Gains, make_controller
from .plant import ScaraPlant
from .scenario import Rollout, Scenario, SimulationDiverged, control_metrics, simulate
from .trajectory import paper_trajectory

__all__ = ["CONTROLLERS", "Gains", "make_controller", "ScaraPlant", "Rollout", "Scenario",
           "SimulationDiverged", "control_metrics", "simulate", "paper_trajectory"]
