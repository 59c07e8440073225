"""Closed-loop control of any serial arm (the SCARA in closed form): batched simulator, controllers,
the adaptive RBFN, online IK."""

from .controllers import Gains, make_controller
from .models import ArmModel, NominalModel
from .plants import ArmPlant, ScaraPlant
from .robot_setup import ControlRobot, control_robot
from .simulator import Rollout, Scenario, SimulationDiverged, control_metrics, simulate
from .trajectory import Reference, paper_trajectory, sinusoid_trajectory

__all__ = [
    "Reference",
    "Gains",
    "make_controller",
    "NominalModel",
    "ArmModel",
    "ScaraPlant",
    "ArmPlant",
    "ControlRobot",
    "control_robot",
    "Rollout",
    "Scenario",
    "SimulationDiverged",
    "control_metrics",
    "simulate",
    "paper_trajectory",
    "sinusoid_trajectory",
]
