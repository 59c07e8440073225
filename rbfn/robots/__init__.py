"""Robots: URDF kinematics (any serial chain) and the paper's SCARA (closed forms, dynamics)."""
from .kinematics import forward_kinematics, joint_limits, load_serial_chain

__all__ = ["forward_kinematics", "joint_limits", "load_serial_chain"]
