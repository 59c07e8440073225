"""Objectives that ACO minimizes over candidate centre sets, all K ants in one batch.

`fit`: validation MSE of the RBF network fitted by ridge least squares with the ant's centres
and widths (supervised; for the IK network). `cluster`: sum of squared distances of the data to
their nearest chosen centre (the k-means objective searched globally; no targets needed).
"""
from __future__ import annotations

import torch

from .fit import DEFAULT_RIDGES, design_matrix, ridge_fit

__all__ = ["FitObjective", "cluster_objective"]


class FitObjective:
    """Callable (centres (K, M, d), widths (K, M)) -> validation MSE (K,), inputs already scaled."""

    def __init__(self, z_train: torch.Tensor, y_train: torch.Tensor, z_val: torch.Tensor,
                 y_val: torch.Tensor, tail: bool = True, ridges: tuple[float, ...] = DEFAULT_RIDGES,
                 eval_dtype: torch.dtype | None = None, chunk: int = 32) -> None:
        self.z_train, self.y_train, self.z_val, self.y_val = z_train, y_train, z_val, y_val
        self.tail, self.ridges, self.eval_dtype, self.chunk = tail, ridges, eval_dtype, chunk

    def __call__(self, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
        out = []
        for c, w in zip(centers.split(self.chunk), widths.split(self.chunk)):  # bounds memory only
            a_tr = design_matrix(self.z_train, c, w, self.tail)
            a_val = design_matrix(self.z_val, c, w, self.tail)
            out.append(ridge_fit(a_tr, self.y_train, a_val, self.y_val, self.ridges, self.eval_dtype).val_mse)
        return torch.cat(out)


def cluster_objective(z: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Sum over inputs z (N, d) of the squared distance to the nearest of centres (K, M, d) -> (K,)."""
    return torch.cdist(z.expand(centers.shape[0], *z.shape), centers).amin(-1).square().sum(-1)
