"""Objectives that ACO minimizes over candidate centre sets, all K ants in one batch.

`fit`: validation MSE of the RBF network fitted by ridge least squares with the ant's centres
and widths (supervised; for the IK network). `cluster`: sum of squared distances of the data to
their nearest chosen centre (the k-means objective searched globally; no targets needed).
"""

from __future__ import annotations

from typing import Any, cast

import torch

from .fit import DEFAULT_RIDGES, ROUND_TOL, ridge_choose, rounding_tolerance
from .gaussians import distance_rows, exponent_coefficients, gaussians_from_exponents

__all__ = ["FitObjective", "cluster_objective"]

# Bytes of one row block's Gaussians for all ants of a batch on CPU: about what stays in a core's
# cache while the block is used (exponent, exp2, normal equations; fastest of 0.5-8 MiB here).
BLOCK_BYTES = 2**21
# Fewest rows a block has unless `block` says fewer: the normal equations' product stays efficient.
MIN_ROWS = 256


class FitObjective:
    """Callable (centres (K, M, d), widths (K, M)) -> validation MSE (K,), inputs already scaled.

    `ridge_fit` on every ant's design matrix A = [phi(z), z, 1] without ever holding one: the
    normal equations A^T A (P, P) and A^T y are summed over blocks of training rows, validation
    errors and rounding scales over blocks of validation rows, each block's Gaussians built and
    used while in cache (blocks of at most `block` rows). What depends on the data only is
    computed once, here: the inputs' [z, |z|^2, 1] (a block's Gaussian exponents are then one
    product with the ants' coefficients), the columns [z, 1, y] beside the Gaussians, and their
    own block [z, 1]^T [z, 1, y] of the normal equations. Ants go in batches sized from P to stay
    within `memory` bytes. The same ridge choice as `ridge_fit` (one eigendecomposition for all
    ridges, the float32-stability rule with `round_tol` and `round_rel` included), the same result up to the
    order of floating-point sums and, with a deployment dtype, the validation Gaussians' exp2 taken
    in that dtype (their exponents in float64; within 1e-6 relative of `ridge_fit`'s MSE).
    """

    def __init__(
        self,
        z_train: torch.Tensor,
        y_train: torch.Tensor,
        z_val: torch.Tensor,
        y_val: torch.Tensor,
        *,
        tail: bool = True,
        ridges: tuple[float, ...] = DEFAULT_RIDGES,
        eval_dtype: torch.dtype | None = None,
        memory: float = 2**31,
        block: int = 2048,
        round_tol: float = ROUND_TOL,
        round_rel: float = 0.0,
    ) -> None:
        self.z_train, self.y_train, self.z_val, self.y_val = z_train, y_train, z_val, y_val
        self.tail, self.ridges, self.eval_dtype, self.round_tol = tail, ridges, eval_dtype, round_tol
        self.round_rel = round_rel
        self.memory, self.block = memory, block
        self._train_rows, self._val_rows = _exponent_rows(z_train), _exponent_rows(z_val)
        # Columns beside the Gaussians: training [z, 1, y] (N, d + 1 + out), validation [z, 1] rows.
        ones = torch.ones_like(z_train[:, :1])
        tail_tr = torch.cat([z_train, ones], 1) if tail else z_train[:, :0]
        self._beside = torch.cat([tail_tr, y_train], 1)
        self._tail_normal = tail_tr.T @ self._beside  # (d + 1, d + 1 + out)
        self._tail_val = torch.cat([z_val.T, torch.ones_like(z_val[:, 0])[None]]) if tail else z_val.T[:0]
        self._tail_val_abs = self._tail_val.abs()
        self._y_val_t = y_val.T.contiguous()

    def subset(self, rows: int, seed: int) -> FitObjective:
        """The same objective on at most `rows` training and `rows` validation rows, drawn without
        replacement by a generator seeded with `seed` (itself where both sets are that small)."""
        n, n_v = self.z_train.shape[0], self.z_val.shape[0]
        if rows >= n and rows >= n_v:
            return self
        g = torch.Generator().manual_seed(seed)
        tr = torch.randperm(n, generator=g)[:rows].sort().values.to(self.z_train.device)
        va = torch.randperm(n_v, generator=g)[:rows].sort().values.to(self.z_val.device)
        return FitObjective(
            self.z_train[tr],
            self.y_train[tr],
            self.z_val[va],
            self.y_val[va],
            tail=self.tail,
            ridges=self.ridges,
            eval_dtype=self.eval_dtype,
            memory=self.memory,
            block=self.block,
            round_tol=self.round_tol,
            round_rel=self.round_rel,
        )

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
        p, rows = self.width(m), min(self.block, max(self.z_train.shape[0], self.z_val.shape[0]))
        item = self.z_train.element_size()
        per_ant = item * (4 * p * p + 3 * rows * p + 2 * len(self.ridges) * p * self.y_train.shape[1])
        batch = max(1, min(k, int(self.memory // per_ant)))
        if batch == k:
            return self._batch(centers, widths)
        return torch.cat([self._batch(c, w) for c, w in zip(centers.split(batch), widths.split(batch))])

    def _batch(self, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
        """Validation MSE (K,) of one batch of ants, centres (K, M, d), widths (K, M)."""
        k, m = centers.shape[:2]
        coef = exponent_coefficients(centers, widths)
        # Rows a block: as many as stay in cache on the CPU; on a GPU every row at once (`block`).
        # (float("inf") // n is NaN in Python, which is why the GPU takes its own branch.)
        fit = max(MIN_ROWS, BLOCK_BYTES // (k * m * coef.element_size()))
        rows = min(self.block, fit) if coef.device.type == "cpu" else self.block
        gram, rhs = self._normal_equations(coef, rows)
        val = self._val_blocks(coef, rows)
        # The rounding scale is summed in the deployment dtype, within (2 P + 3) u of float64's sum:
        # only a scale that close to round_tol could be judged otherwise; those are redone in float64.
        slack = 0.0 if self.eval_dtype is None else (2 * gram.shape[-1] + 3) * torch.finfo(self.eval_dtype).eps / 2
        tols: list[torch.Tensor] = []  # the grid's tolerance, kept for the finer ridges

        def score(weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
            mse, bound = self._score(val, weights)
            if bound is None:
                return mse, bound
            if not tols:
                tols.append(rounding_tolerance(mse, rhs.shape[-1], self.round_tol, self.round_rel))
            if bool(((bound - tols[0]).abs() <= slack * tols[0]).any()):
                bound = self._score(self._val_blocks(coef, rows, exact=True), weights)[1]  # (rare)
            return mse, bound

        return ridge_choose(gram, rhs, score, self.ridges, self.eval_dtype, self.round_tol, self.round_rel).val_mse

    def _normal_equations(self, coef: torch.Tensor, rows: int) -> tuple[torch.Tensor, torch.Tensor]:
        """A^T A (K, P, P) and A^T y (K, P, out) of the ants' training design matrices A, summed
        over row blocks: phi^T phi and phi^T [z, 1, y] by block, the tail's block once."""
        k, m = coef.shape[:2]
        gram = coef.new_zeros(k, m, m)
        beside = coef.new_zeros(self._beside.shape[1], k * m)  # [z, 1, y]^T phi
        for r0 in range(0, self.z_train.shape[0], rows):
            phi = gaussians_from_exponents(coef, self._train_rows[:, r0 : r0 + rows])  # (K, M, B)
            gram.baddbmm_(phi, phi.transpose(1, 2))
            beside.addmm_(self._beside[r0 : r0 + rows].T, phi.view(k * m, -1).T)
            del phi
        n_tail = self._tail_normal.shape[0]
        beside = beside.view(-1, k, m).permute(1, 2, 0)  # (K, M, d + 1 + out)
        tail = self._tail_normal.expand(k, -1, -1)
        gram = torch.cat(
            [
                torch.cat([gram, beside[..., :n_tail]], 2),
                torch.cat([beside[..., :n_tail].transpose(1, 2), tail[..., :n_tail]], 2),
            ],
            1,
        )
        return gram, torch.cat([beside[..., n_tail:], tail[..., n_tail:]], 1)

    def _val_blocks(self, coef: torch.Tensor, rows: int, exact: bool = False):
        """() -> iterable of validation row blocks (r0, design (K, P', b)): A^T = [phi; z, 1] in the
        deployment dtype (in float64 if `exact`), with [|z|, 1] below it (P' = P + d + 1) where
        the rounding scale is wanted. Kept for the call where they fit in a quarter of `memory`
        (the ridge refinement scores twice), else rebuilt on each pass."""
        k, m = coef.shape[:2]
        dtype = coef.dtype if exact or self.eval_dtype is None else self.eval_dtype
        bounds = self.eval_dtype is not None
        n_v, n_t = self.z_val.shape[0], self._tail_val.shape[0]

        def build(r0: int) -> tuple[int, torch.Tensor]:
            tail = self._tail_val[:, r0 : r0 + rows]
            a = torch.empty(k, m + n_t * (1 + bounds), tail.shape[1], dtype=dtype, device=coef.device)
            gaussians_from_exponents(coef, self._val_rows[:, r0 : r0 + rows], out=a[:, :m])  # float64, then rounded
            a[:, m : m + n_t] = tail
            if bounds:
                a[:, m + n_t :] = self._tail_val_abs[:, r0 : r0 + rows]
            return r0, a

        if exact or k * (m + 2 * n_t) * n_v * torch.finfo(dtype).bits / 8 > self.memory / 4:
            return lambda: map(build, range(0, n_v, rows))
        kept = [build(r0) for r0 in range(0, n_v, rows)]
        return lambda: kept

    def _score(self, val, weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Validation MSE (K, L) and rounding scale (K, L) or None of weights (K, L, P, out), as
        `ridge_fit` measures them: predictions in the deployment dtype, and the rounding scale
        u * max over rows and outputs of sum_i |a_i w_i| (one product: [w, 0; |w_phi|, 0, |w_tail|]
        times the blocks' [a; |tail|])."""
        k, n_l, p, n_out = weights.shape
        lo, m = n_l * n_out, p - self._tail_val.shape[0]
        w_t = weights.transpose(-1, -2).reshape(k, lo, p)  # (K, L * out, P)
        sse = w_t.new_zeros(k, n_l, n_out)
        bound = w_t.new_zeros(k, lo)
        bounds, w2 = self.eval_dtype is not None, None
        err: Any = None  # (K, L, out, block), made by the first block
        for r0, a in val():
            b = a.shape[-1]
            if w2 is None:
                w2 = w_t.new_zeros(k, lo * (1 + bounds), a.shape[1])
                w2[:, :lo, :p] = w_t
                if bounds:
                    w2[:, lo:, :m] = w_t[..., :m].abs()
                    w2[:, lo:, p:] = w_t[..., m:].abs()
                w2 = w2.to(a.dtype)
                err = w_t.new_empty(k, n_l, n_out, b)  # reused by every block
            out = torch.bmm(w2, a)
            pred = out[:, :lo].view(k, n_l, n_out, b)
            sse.add_(err[..., :b].copy_(pred).sub_(self._y_val_t[:, r0 : r0 + b]).square_().sum(-1))
            if bounds:
                torch.maximum(bound, out[:, lo:].amax(-1).to(bound.dtype), out=bound)
            del out, pred
        mse = sse.sum(-1) / self.z_val.shape[0]
        if not bounds:
            return mse, None
        return mse, bound.view(k, n_l, n_out).amax(-1) * (torch.finfo(cast(torch.dtype, self.eval_dtype)).eps / 2)


# The colony's Gaussians are rbfn.gaussians' colony form (exponent_coefficients,
# gaussians_from_exponents): all ants' exponents of a row block as one product of the data's
# `distance_rows` with the ants' coefficients, in base 2. Its own rounding order, kept: the
# colony's choices depend on its bits.


def _exponent_rows(z: torch.Tensor) -> torch.Tensor:
    """`rbfn.layer.distance_rows` [z, |z|^2, 1] transposed, (d + 2, N), contiguous."""
    return distance_rows(z).T.contiguous()


def cluster_objective(z: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Sum over inputs z (N, d) of the squared distance to the nearest of centres (K, M, d) -> (K,)."""
    return torch.cdist(z.expand(centers.shape[0], *z.shape), centers).amin(-1).square().sum(-1)
