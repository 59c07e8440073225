"""The paper's 3-DOF SCARA: parameters, URDF, closed-form kinematics.

Joints q = (q1, q2, q3): rad, rad, m. Base frame at joint 1's axis, in the arm's plane:
x = l1 cos q1 + l2 cos(q1 + q2), y = l1 sin q1 + l2 sin(q1 + q2), z = -q3.
"""
from __future__ import annotations

from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

import torch

__all__ = ["ScaraParams", "URDF_PATH", "END_LINK", "fk", "ik"]

URDF_PATH: Path = Path(str(files("rbfn.robots") / "scara.urdf"))
END_LINK = "quill"


@dataclass(frozen=True)
class ScaraParams:
    """Link lengths (m), masses (kg) and gravity (m/s^2); defaults are the paper's."""

    l1: float = 1.0
    l2: float = 0.8
    l3: float = 0.6
    m1: float = 1.0
    m2: float = 0.8
    m3: float = 0.5
    g: float = 9.8


def fk(q: torch.Tensor, p: ScaraParams = ScaraParams()) -> torch.Tensor:
    """Closed-form end-effector positions (B, 3) in m from joints q (B, 3)."""
    q1, q2, q3 = q.unbind(-1)
    x = p.l1 * torch.cos(q1) + p.l2 * torch.cos(q1 + q2)
    y = p.l1 * torch.sin(q1) + p.l2 * torch.sin(q1 + q2)
    return torch.stack([x, y, -q3], dim=-1)


def ik(pos: torch.Tensor, p: ScaraParams = ScaraParams(), elbow: int = 1) -> torch.Tensor:
    """Closed-form IK: joints (B, 3) for positions (B, 3) in m; elbow=+1 gives q2 >= 0.

    Unreachable radii are clamped to the nearest reachable one.
    """
    x, y, z = pos.unbind(-1)
    c2 = ((x * x + y * y - p.l1**2 - p.l2**2) / (2 * p.l1 * p.l2)).clamp(-1.0, 1.0)
    q2 = elbow * torch.acos(c2)
    q1 = torch.atan2(y, x) - torch.atan2(p.l2 * torch.sin(q2), p.l1 + p.l2 * torch.cos(q2))
    return torch.stack([q1, q2, -z], dim=-1)
