"""Forward kinematics of any serial URDF through pytorch-kinematics, exact in float64.

pytorch-kinematics parses URDF origins into float32 transforms (0.8 m becomes
0.800000011920929 m). `load_serial_chain` rebuilds every joint and link offset from the parsed
URDF's Python floats, so float64 FK is exact to the URDF text.
"""
from __future__ import annotations

from pathlib import Path

import pytorch_kinematics as pk
import torch
from pytorch_kinematics import transforms as tf
from pytorch_kinematics.urdf_parser_py.urdf import URDF

__all__ = ["load_serial_chain", "forward_kinematics", "joint_limits"]


def _exact_transform(origin, dtype: torch.dtype) -> tf.Transform3d:
    if origin is None:
        return tf.Transform3d(dtype=dtype)
    rpy = torch.tensor(origin.rpy, dtype=torch.float64)
    rot = tf.quaternion_from_euler(rpy, "sxyz").to(dtype)
    return tf.Transform3d(rot=rot, pos=[float(v) for v in origin.xyz], dtype=dtype)


def load_serial_chain(urdf: str | Path, end_link: str, dtype: torch.dtype = torch.float64,
                      device: str | torch.device = "cpu") -> pk.SerialChain:
    """Serial chain from a URDF file (path) or URDF text, root to `end_link`, in `dtype`."""
    text = Path(urdf).read_text() if not str(urdf).lstrip().startswith("<") else str(urdf)
    robot = URDF.from_xml_string(text)
    if end_link not in robot.link_map:
        raise ValueError(f"end_link {end_link!r} is not a link of the URDF; links: "
                         f"{sorted(robot.link_map)}")
    full = pk.build_chain_from_urdf(text)
    joints = {j.child: j for j in robot.joints}

    def fix(frame):
        link = robot.link_map[frame.link.name]
        frame.link.offset = _exact_transform(link.origin, dtype)
        if frame.link.name in joints:
            frame.joint.offset = _exact_transform(joints[frame.link.name].origin, dtype)
            frame.joint.axis = frame.joint.axis.to(dtype)
        else:
            frame.joint.offset = tf.Transform3d(dtype=dtype)
        for child in frame.children:
            fix(child)

    fix(full._root)
    chain = pk.SerialChain(pk.Chain(full._root, dtype=dtype), end_link + "_frame"
                           if end_link + "_frame" in full.get_frame_names() else end_link,
                           dtype=dtype)
    return chain.to(dtype=dtype, device=device)


def forward_kinematics(chain: pk.SerialChain, th: torch.Tensor) -> torch.Tensor:
    """End-effector positions (B, 3) in m for joint values `th` (B, n_joints) (rad or m)."""
    th = th.to(dtype=chain.dtype, device=chain.device)
    return chain.forward_kinematics(th, end_only=True).get_matrix()[:, :3, 3]


def joint_limits(chain: pk.SerialChain) -> tuple[torch.Tensor, torch.Tensor]:
    """(low, high) joint limits from the URDF, each (n_joints,)."""
    low, high = chain.get_joint_limits()
    return (torch.as_tensor(low, dtype=torch.float64), torch.as_tensor(high, dtype=torch.float64))
