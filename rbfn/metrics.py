"""IK accuracy: joint RMSE and end-effector position error through forward kinematics."""
from __future__ import annotations

import pytorch_kinematics as pk
import torch

from .robots.kinematics import forward_kinematics

__all__ = ["ik_metrics"]


@torch.no_grad()
def ik_metrics(model: torch.nn.Module, chain: pk.SerialChain, x: torch.Tensor, q: torch.Tensor,
               dtype: torch.dtype = torch.float64) -> dict[str, float]:
    """Errors of `model` evaluated in `dtype` on positions x (N, 3) m with true joints q (N, J).

    joint_rmse: RMS over samples and joints (rad and m mixed, as the paper's E); per-joint RMSE;
    pos_err_mm_*: distance between FK of the predicted joints and x, in mm; in_workspace: the
    fraction the model flags as inside its trained region.
    """
    m = model.to(dtype)
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
    return out
