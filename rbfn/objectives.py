"""Objectives that ACO minimizes over candidate centre sets, all K ants in one batch.

`fit`: validation MSE of the RBF network fitted by ridge least squares with the ant's centres
and widths (supervised; for the IK network). `cluster`: sum of squared distances of the data to
their nearest chosen centre (the k-means objective searched globally; no targets needed).
"""
from __future__ import annotations

import torch

from .fit import DEFAULT_RIDGES, design_matrix, ridge_choose, ridge_fit, rounding_scale

__all__ = ["FitObjective", "cluster_objective"]


class FitObjective:
    """Callable (centres (K, M, d), widths (K, M)) -> validation MSE (K,), inputs already scaled.

    Where the K design matrices fit in `memory` bytes (32 ants at a time) they are built whole
    and fitted by `ridge_fit`. Otherwise the normal equations A^T A (P, P) and A^T y are summed
    over row blocks of `block` rows, so no (N, P) design matrix is ever held, ants go in batches
    sized from P to stay within `memory`, and validation errors and rounding scales are summed over
    row blocks too: the same ridge choice (float32-stability rule included), the same result up to
    the order of floating-point sums.
    """

    def __init__(self, z_train: torch.Tensor, y_train: torch.Tensor, z_val: torch.Tensor,
                 y_val: torch.Tensor, tail: bool = True, ridges: tuple[float, ...] = DEFAULT_RIDGES,
                 eval_dtype: torch.dtype | None = None, chunk: int = 32, memory: float = 2**31,
                 block: int = 2048) -> None:
        self.z_train, self.y_train, self.z_val, self.y_val = z_train, y_train, z_val, y_val
        self.tail, self.ridges, self.eval_dtype, self.chunk = tail, ridges, eval_dtype, chunk
        self.memory, self.block = memory, block

    def width(self, m: int) -> int:
        """Design-matrix columns P for M = m."""
        return m + (self.z_train.shape[1] + 1 if self.tail else 0)

    def cost(self, m: int) -> float:
        """Floating-point operations of one ant at M = m (normal equations, eigh, validation)."""
        p = self.width(m)
        n, nv = self.z_train.shape[0], self.z_val.shape[0]
        return n * p * p + 10.0 * p**3 + 4.0 * nv * p * len(self.ridges) * self.y_train.shape[1]

    def __call__(self, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
        k, m = centers.shape[0], centers.shape[1]
        n_rows = self.z_train.shape[0] + self.z_val.shape[0]
        item = self.z_train.element_size()
        if min(self.chunk, k) * n_rows * self.width(m) * item * 2 <= self.memory:
            out = []
            for c, w in zip(centers.split(self.chunk), widths.split(self.chunk)):  # bounds memory only
                a_tr = design_matrix(self.z_train, c, w, self.tail)
                a_val = design_matrix(self.z_val, c, w, self.tail)
                out.append(ridge_fit(a_tr, self.y_train, a_val, self.y_val, self.ridges, self.eval_dtype).val_mse)
            return torch.cat(out)
        p = self.width(m)
        rows = min(self.block, n_rows)
        per_ant = item * (4 * p * p + 3 * rows * p + 2 * len(self.ridges) * p * self.y_train.shape[1])
        batch = max(1, min(k, int(self.memory // per_ant)))
        return torch.cat([self.blocked(c, w) for c, w in zip(centers.split(batch), widths.split(batch))])

    def blocked(self, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
        """Validation MSE (K,) from normal equations summed over row blocks; centres (K, M, d)."""
        z, y = self.z_train, self.y_train
        k, p, n_out = centers.shape[0], self.width(centers.shape[1]), y.shape[1]
        gram = z.new_zeros(k, p, p)
        rhs = z.new_zeros(k, p, n_out)
        for r0 in range(0, z.shape[0], self.block):                          # training row blocks
            a = design_matrix(z[r0:r0 + self.block], centers, widths, self.tail)   # (K, B, P)
            gram.baddbmm_(a.transpose(-1, -2), a)
            rhs.baddbmm_(a.transpose(-1, -2), y[r0:r0 + self.block].expand(k, -1, -1))
            del a
        deploy = self.eval_dtype

        def evaluate(w_flat: torch.Tensor, rows: slice):
            a = design_matrix(self.z_val[rows], centers, widths, self.tail)       # (K, b, P)
            if deploy is None:
                pred = a @ w_flat
            else:
                pred = (a.to(deploy) @ w_flat.to(deploy)).to(a.dtype)
            return pred, None if deploy is None else rounding_scale(a, w_flat, deploy)

        blocks = -(-self.z_val.shape[0] // self.block)
        return ridge_choose(gram, rhs, self.y_val, evaluate, self.ridges, deploy, blocks=max(blocks, 2)).val_mse


def cluster_objective(z: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Sum over inputs z (N, d) of the squared distance to the nearest of centres (K, M, d) -> (K,)."""
    return torch.cdist(z.expand(centers.shape[0], *z.shape), centers).amin(-1).square().sum(-1)
