"""Gradient refinement of centres, widths and per-input length scales, weights solved inside the loss.

The loss is the training MSE of the network whose output weights are the ridge least-squares
solution for the current centres and widths (variable projection), so gradients move only the
nonlinear parameters. Per-input scales (automatic relevance determination) let an input that
does not matter for the targets be stretched out. The iterate with the lowest validation error
is kept (early stopping).

On large problems (N P^2 above `FULL_ROWS_MAX`, P the design's columns) each step draws two
disjoint random row subsets of 2P rows: the weights are solved on one and the loss is measured
on the other (a held-out loss, which an interpolating fit on the first would make meaningless);
the steps are capped by a flop budget (`STEP_FLOPS`) and the validation check, whose weights come
from the full training set's normal equations summed over row blocks, runs 3 times.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .fit import design_matrix, ridge_solve

__all__ = ["Refined", "refine"]

# Above this N * P^2 a step works on row subsets (see the module's docstring).
FULL_ROWS_MAX = 2e9
# Floating-point operations the subsampled steps may spend in all (about a minute on one core;
# 13 steps at the UR5's M = 2000, N = 20000, where 8 steps already lowered validation E by 44%).
STEP_FLOPS = 2e12


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
    n, p = z_train.shape[0], centers.shape[0] + (z_train.shape[1] + 1 if tail else 0)
    sub = min(2 * p, n // 2) if n * p * p > FULL_ROWS_MAX else 0
    g = torch.Generator().manual_seed(0)
    if sub:
        steps = min(steps, max(4, int(STEP_FLOPS / (6.0 * (sub * p * p + p**3)))))
        eval_every = max(eval_every, -(-steps // 2))

    def val_error() -> float:
        with torch.no_grad():
            s = log_s.exp()
            w = log_w.clamp(max=log_max).exp()
            if sub:
                weights = _blocked_solve(z_train / s, y_train, c, w, tail, ridge)
            else:
                weights = ridge_solve(design_matrix(z_train / s, c, w, tail), y_train, ridge)
            pred = torch.cat([design_matrix(zb / s, c, w, tail) @ weights for zb in z_val.split(4096)])
            return float((pred - y_val).square().sum(-1).mean())

    best = (val_error(), c.detach().clone(), log_w.detach().clone(), log_s.detach().clone())
    history = [best[0]]
    for step in range(1, steps + 1):
        opt.zero_grad()
        s = log_s.exp()
        w = log_w.clamp(max=log_max).exp()
        if sub:     # weights solved on one row subset, the loss measured on another
            idx = torch.randperm(n, generator=g)[: 2 * sub].to(z_train.device)
            a = design_matrix(z_train[idx[:sub]] / s, c, w, tail)
            weights = ridge_solve(a, y_train[idx[:sub]], ridge)
            a_loss = design_matrix(z_train[idx[sub:]] / s, c, w, tail)
            loss = (a_loss @ weights - y_train[idx[sub:]]).square().sum(-1).mean()
        else:
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


def _blocked_solve(z: torch.Tensor, y: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor,
                   tail: bool, ridge: float, block: int = 2048) -> torch.Tensor:
    """`ridge_solve` weights (P, out) from normal equations summed over row blocks of z (N, d)."""
    gram, rhs = 0.0, 0.0
    for zb, yb in zip(z.split(block), y.split(block)):
        a = design_matrix(zb, centers, widths, tail)
        gram, rhs = a.T @ a + gram, a.T @ yb + rhs
    scale = gram.diagonal().mean()
    gram.diagonal().add_(ridge * scale)
    return torch.linalg.solve(gram, rhs)

