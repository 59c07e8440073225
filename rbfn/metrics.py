"""IK accuracy: joint RMSE, and end-effector position (and orientation) error through the robot's FK."""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from .layer import RBFNetwork
    from .robots.robot import Robot

__all__ = ["ik_metrics", "ik_metrics_both", "error_summary"]


def error_summary(pos_mm: torch.Tensor, rot_deg: torch.Tensor | None) -> dict[str, float]:
    """pos_err_mm_median / p95 / max, and rot_err_deg_median / p95 / max where rotations apply."""
    out = {
        "pos_err_mm_median": float(pos_mm.median()),
        "pos_err_mm_p95": float(pos_mm.quantile(0.95)),
        "pos_err_mm_max": float(pos_mm.max()),
    }
    if rot_deg is not None:
        out.update(
            {
                "rot_err_deg_median": float(rot_deg.median()),
                "rot_err_deg_p95": float(rot_deg.quantile(0.95)),
                "rot_err_deg_max": float(rot_deg.max()),
            }
        )
    return out


@torch.no_grad()
def ik_metrics(
    model: RBFNetwork, robot: Robot, x: torch.Tensor, q: torch.Tensor, dtype: torch.dtype = torch.float64
) -> tuple[dict[str, float], torch.Tensor, torch.Tensor]:
    """Errors of a copy of `model` evaluated in `dtype` on targets x (N, 3 or 7) with true joints q (N, n).

    Returns (metrics, position errors (N,) mm, in-workspace flags (N,)). Metrics: joint_rmse (RMS
    over samples and joints, rad and m mixed, as the paper's E), jointK_rmse per joint, position
    error (FK of the predicted joints against the target, mm) and, for pose targets, rotation error
    (deg) as median / p95 / max, and in_workspace (the fraction flagged inside the trained region).
    """
    m = copy.deepcopy(model).to(dtype)
    q_hat, inside = m.solve(x.to(dtype))
    q_hat = q_hat.to(torch.float64)
    err = q_hat - q.to(q_hat)
    pos, rot = robot.errors(q_hat, x)
    out = {
        "joint_rmse": float(err.square().mean().sqrt()),
        **error_summary(pos, rot),
        "in_workspace": float(inside.double().mean()),
    }
    for j, r in enumerate(err.square().mean(0).sqrt().tolist()):
        out[f"joint{j + 1}_rmse"] = float(r)
    return out, pos, inside


def ik_metrics_both(
    model: RBFNetwork, robot: Robot, x: torch.Tensor, q: torch.Tensor, prefix: str = "test_"
) -> tuple[dict[str, float], torch.Tensor, torch.Tensor]:
    """`ik_metrics` in float64 (keys `prefix + name`) and float32 (`prefix + name + "_float32"`),
    with the float64 position errors (N,) mm and flags (N,)."""
    m64, pos, inside = ik_metrics(model, robot, x, q, torch.float64)
    m32, _, _ = ik_metrics(model, robot, x, q, torch.float32)
    out = {f"{prefix}{k}": v for k, v in m64.items()}
    out.update({f"{prefix}{k}_float32": v for k, v in m32.items()})
    return out, pos, inside
