"""Robots: every robot is a URDF (kinematics `kinematics`, dynamics `dynamics`), any serial chain.

The packaged ones are folders (`scara/`, `ur5/`, `panda/`: the URDF, its sources, optional closed
forms; presets in conf/robot/NAME.yaml); `registry.closed_form` is the one place that chooses closed
forms (the SCARA's, for exactly its packaged URDF)."""

from .kinematics import forward_kinematics, forward_kinematics_pose, joint_limits, load_serial_chain, urdf_path

__all__ = ["forward_kinematics", "forward_kinematics_pose", "joint_limits", "load_serial_chain", "urdf_path"]
