"""Closed-loop control of the SCARA: batched simulator, controllers, the adaptive RBFN, online IK."""
from .controllers import Gains, make_controller
from .simulator import Rollout, ScaraPlant, Scenario, SimulationDiverged, control_metrics, simulate
from .trajectory import paper_trajectory

__all__ = ["Gains", "make_controller", "ScaraPlant", "Rollout", "Scenario", "SimulationDiverged",
           "control_metrics", "simulate", "paper_trajectory"]
