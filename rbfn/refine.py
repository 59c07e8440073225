"""Gradient refinement of centres, widths and per-input length scales, weights solved inside the loss.

The loss is the training MSE of the network whose output weights are the ridge least-squares
solution for the current centres and widths (variable projection), so gradients move only the
nonlinear parameters. Per-input scales (automatic relevance determination) let an input that
does not matter for the targets be stretched out. The iterate with the lowest validation error
is kept (early stopping).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .fit import design_matrix, ridge_solve

__all__ = ["Refined", "refine"]


@dataclass
class Refined:
    """Centres (M, d) and widths (M,) in the new scaled space z' = z / input_scale; input_scale (d,)."""

    centers: torch.Tensor
    widths: torch.Tensor
    input_scale: torch.Tensor
    val_mse: float
    history: list[float]


def refine(z_train: torch.Tensor, y_train: torch.Tensor, z_val: torch.Tensor, y_val: torch.Tensor,
           centers: torch.Tensor, widths: torch.Tensor, ridge: float, steps: int = 300, lr: float = 0.01,
           tail: bool = True, learn_input_scale: bool = True, max_width: float = float("inf"),
           eval_every: int = 10) -> Refined:
    """Adam on (centres, log widths, log input scales); returns the best-on-validation iterate."""
    c = centers.detach().clone().requires_grad_(True)
    log_w = widths.detach().log().clone().requires_grad_(True)
    log_s = torch.zeros(z_train.shape[-1], dtype=z_train.dtype, device=z_train.device,
                        requires_grad=learn_input_scale)
    params = [c, log_w] + ([log_s] if learn_input_scale else [])
    opt = torch.optim.Adam(params, lr=lr)
    log_max = math.log(max_width)

    def val_error() -> float:
        with torch.no_grad():
            s = log_s.exp()
            w = log_w.clamp(max=log_max).exp()
            weights = ridge_solve(design_matrix(z_train / s, c, w, tail), y_train, ridge)
            pred = design_matrix(z_val / s, c, w, tail) @ weights
            return float((pred - y_val).square().sum(-1).mean())

    best = (val_error(), c.detach().clone(), log_w.detach().clone(), log_s.detach().clone())
    history = [best[0]]
    for step in range(1, steps + 1):
        opt.zero_grad()
        s = log_s.exp()
        w = log_w.clamp(max=log_max).exp()
        a = design_matrix(z_train / s, c, w, tail)
        loss = (a @ ridge_solve(a, y_train, ridge) - y_train).square().sum(-1).mean()
        if not torch.isfinite(loss):
            break
        loss.backward()
        opt.step()
        if step % eval_every == 0 or step == steps:
            e = val_error()
            history.append(e)
            if e < best[0]:
                best = (e, c.detach().clone(), log_w.detach().clone(), log_s.detach().clone())
    e, cb, lwb, lsb = best
    return Refined(centers=cb, widths=lwb.clamp(max=log_max).exp(), input_scale=lsb.exp(),
                   val_mse=e, history=history)
