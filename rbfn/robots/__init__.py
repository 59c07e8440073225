"""Robots: URDF kinematics (any serial chain) and the paper's SCARA (closed forms, dynamics)."""
from .kinematics import forward_kinematics, forward_kinematics_pose, joint_limits, load_serial_chain, urdf_path

__all__ = ["forward_kinematics", "forward_kinematics_pose", "joint_limits", "load_serial_chain",
           "urdf_path"]
