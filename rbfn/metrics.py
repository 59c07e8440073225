"""IK accuracy: joint RMSE and end-effector position error through forward kinematics."""
from __future__ import annotations

import copy

import pytorch_kinematics as pk
import torch

from .robots.kinematics import forward_kinematics

__all__ = ["ik_metrics", "ik_metrics_both"]


@torch.no_grad()
def ik_metrics(model: torch.nn.Module, chain: pk.SerialChain, x: torch.Tensor, q: torch.Tensor,
               dtype: torch.dtype = torch.float64) -> tuple[dict[str, float], torch.Tensor, torch.Tensor]:
    """Errors of a copy of `model` evaluated in `dtype` on positions x (N, 3) m with true joints q (N, n).

    Returns (metrics, position errors (N,) mm, in-workspace flags (N,)). Metrics: joint_rmse (RMS
    over samples and joints, rad and m mixed, as the paper's E), jointK_rmse per joint,
    pos_err_mm_median / p95 / max (distance between FK of the predicted joints and x, mm) and
    in_workspace (the fraction the model flags as inside its trained region).
    """
    m = copy.deepcopy(model).to(dtype)
    q_hat, inside = m.solve(x.to(dtype))
    q_hat = q_hat.to(torch.float64)
    err = q_hat - q.to(q_hat)
    pos = (forward_kinematics(chain, q_hat) - x.to(torch.float64)).norm(dim=-1) * 1000.0
    out = {"joint_rmse": float(err.square().mean().sqrt()),
           "pos_err_mm_median": float(pos.median()),
           "pos_err_mm_p95": float(pos.quantile(0.95)),
           "pos_err_mm_max": float(pos.max()),
           "in_workspace": float(inside.double().mean())}
    for j, r in enumerate(err.square().mean(0).sqrt().tolist()):
        out[f"joint{j + 1}_rmse"] = float(r)
    return out, pos, inside


def ik_metrics_both(model: torch.nn.Module, chain: pk.SerialChain, x: torch.Tensor, q: torch.Tensor,
                    prefix: str = "test_") -> tuple[dict[str, float], torch.Tensor, torch.Tensor]:
    """`ik_metrics` in float64 (keys `prefix + name`) and float32 (`prefix + name + "_float32"`),
    with the float64 position errors (N,) mm and flags (N,)."""
    m64, pos, inside = ik_metrics(model, chain, x, q, torch.float64)
    m32, _, _ = ik_metrics(model, chain, x, q, torch.float32)
    out = {f"{prefix}{k}": v for k, v in m64.items()}
    out.update({f"{prefix}{k}_float32": v for k, v in m32.items()})
    return out, pos, inside
