"""Closed-loop control of any serial arm: batched simulator, controllers, the adaptive RBFN,
online IK."""

from .controllers import Gains, make_controller
from .models import ModelScales, NominalModel
from .plants import Plant
from .robot_setup import ControlRobot, control_robot
from .simulator import Rollout, Scenario, SimulationDiverged, control_metrics, simulate
from .trajectory import Reference, paper_trajectory, sinusoid_trajectory

__all__ = [
    "Reference",
    "Gains",
    "make_controller",
    "ModelScales",
    "NominalModel",
    "Plant",
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
