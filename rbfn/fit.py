"""Output weights by ridge least squares, the ridge chosen on a validation split.

Everything is batched over a leading "ant" dimension K, so a colony's candidate centre sets are
fitted in one tensor computation. The design matrix is [phi(z), z, 1] (the linear tail and bias
are optional columns), the column order of RBFNetwork.design.

Fits meant for a lower deployment precision (float32) keep only ridges whose weights evaluate
stably in it: see `ridge_fit` and `rounding_scale`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch

from .gaussians import gaussian_features, gaussian_matrix

__all__ = [
    "design_matrix",
    "RidgeFit",
    "ridge_fit",
    "ridge_choose",
    "ridge_solve",
    "deployed_design",
    "rounding_scale",
    "DEFAULT_RIDGES",
    "ROUND_TOL",
    "rounding_tolerance",
    "RoundingRule",
]

# Ridge values relative to the mean diagonal of the Gram matrix.
DEFAULT_RIDGES = tuple(10.0**e for e in range(-13, -1))
# Largest rounding scale (output units: rad, m) a fit for a deployment dtype may have on any
# validation row. Measured float32 differences between op orders (ONNX runtime vs torch, matmul vs
# broadcast distances, reversed summation) reached up to ~4.6 times this scale, so 2e-6 keeps them
# below 1e-5.
ROUND_TOL = 2e-6


def design_matrix(z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor, tail: bool = True) -> torch.Tensor:
    """Design matrix (..., N, P) with P = M [+ d + 1]: features, then tail z and bias column.

    Without the tail there is no bias column either (P = M); `assemble` then sets a zero bias.

    The Gaussians are `rbfn.gaussians.gaussian_matrix`, fitting's form of the reference
    `gaussian_features` (within 1e-12 in float64, tested).
    """
    phi = gaussian_matrix(z, centers, widths)
    if not tail:
        return phi
    shape = phi.shape[:-1]
    ones = torch.ones(*shape, 1, dtype=phi.dtype, device=phi.device)
    return torch.cat([phi, z.expand(*shape, z.shape[-1]), ones], dim=-1)


def deployed_design(
    x: torch.Tensor,
    offset: torch.Tensor,
    scale: torch.Tensor,
    centers: torch.Tensor,
    widths: torch.Tensor,
    tail: bool,
    dtype: torch.dtype,
) -> torch.Tensor:
    """The design matrix (N, P) as `RBFNetwork.design` in `dtype` computes it from raw inputs x
    (broadcast distances); the module's prediction path expands them instead, which differs by
    float rounding only (bounded with the rest by ROUND_TOL)."""
    cast = [t.to(dtype) for t in (x, offset, scale, centers, widths)]
    z = (cast[0] - cast[1]) / cast[2]
    phi = gaussian_features(z, cast[3], cast[4])
    if not tail:
        return phi
    return torch.cat([phi, z, torch.ones_like(z[:, :1])], dim=-1)


@dataclass
class RidgeFit:
    """Weights (..., P, out), the chosen relative ridge (...,), validation MSE (...,) and, when
    fitted for a deployment dtype, the rounding scale of the chosen fit (...,): max over validation
    rows and outputs of u * sum_i |a_i(x) w_ij| (output units; see `ridge_fit`)."""

    weights: torch.Tensor
    ridge: torch.Tensor
    val_mse: torch.Tensor
    rounding: torch.Tensor | None = None


def rounding_scale(a: torch.Tensor, weights: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """Rounding scale (..., N, out) of a @ weights evaluated in `dtype`: u * |a| @ |weights|.

    a (..., N, P), weights (..., P, out); u is the unit roundoff of `dtype` (2**-24 for float32).
    Each term a_i w_ij carries a relative rounding error of a few u (the feature, the product, the
    sum), however the features and the sum are ordered, so the deployed output's error is a small
    multiple of this scale. With large weights that cancel it is far above u * |a @ weights|.
    """
    return (a.abs() @ weights.abs()).mul_(torch.finfo(dtype).eps / 2)


def ridge_fit(
    a_train: torch.Tensor,
    y_train: torch.Tensor,
    a_val: torch.Tensor,
    y_val: torch.Tensor,
    ridges: tuple[float, ...] = DEFAULT_RIDGES,
    *,
    eval_dtype: torch.dtype | None = None,
    a_val_eval: torch.Tensor | None = None,
    round_tol: float = ROUND_TOL,
    round_rel: float = 0.0,
) -> RidgeFit:
    """Ridge least squares for every ridge in `ridges`; keep the one with the lowest validation MSE.

    a_train (..., N, P), y_train (N, out), a_val (..., Nv, P), y_val (Nv, out). Solved through
    the eigendecomposition of the Gram matrix, so all ridges cost one decomposition. MSE is the
    mean over samples of the summed squared output error.

    With a deployment dtype (`eval_dtype`, or the dtype of `a_val_eval`, the validation design as
    the deployed module computes it) the validation MSE is measured in that dtype and only stable
    ridges compete: the fit's rounding scale (`rounding_scale`) must be <= `round_tol` (output
    units), or `round_rel` times the best candidate's validation RMS error per output where that
    is larger (`rounding_tolerance`), on every validation row and output. Small ridges give large weights that
    cancel, and
    the deployed output then depends on the order of operations (ONNX runtime vs torch, distance
    formula, summation order) by far more than the dtype's precision; choosing on the measured
    error alone would reward the op order that happened to be measured. Where the constraint
    binds, the ridge is refined between the grid's neighbours. If no ridge is stable, the most
    stable one is kept.
    """
    gram = a_train.transpose(-1, -2) @ a_train
    rhs = a_train.transpose(-1, -2) @ y_train
    deploy = a_val_eval.dtype if a_val_eval is not None else eval_dtype

    def score(weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Validation MSE (..., L) and rounding scale (..., L) or None of weights (..., L, P, out)."""
        n_l, p, n_out = weights.shape[-3:]
        w_flat = weights.movedim(-3, -2).reshape(*weights.shape[:-3], p, n_l * n_out)
        if a_val_eval is not None:
            pred = (a_val_eval @ w_flat.to(a_val_eval.dtype)).to(gram.dtype)
        elif eval_dtype is None:
            pred = a_val @ w_flat
        else:
            pred = (a_val.to(eval_dtype) @ w_flat.to(eval_dtype)).to(gram.dtype)
        pred = pred.unflatten(-1, (n_l, n_out))  # (..., Nv, L, out)
        mse = (pred - y_val.unsqueeze(-2)).square().sum(-1).mean(-2)
        if deploy is None:
            return mse, None
        return mse, rounding_scale(a_val, w_flat, deploy).unflatten(-1, (n_l, n_out)).amax((-3, -1))

    return ridge_choose(gram, rhs, score, ridges, deploy, round_tol, round_rel)


def rounding_tolerance(
    mse: torch.Tensor, outputs: int, round_tol: float = ROUND_TOL, round_rel: float = 0.0
) -> torch.Tensor:
    """The largest rounding scale (..., 1) a deployed fit may have: round_tol, or round_rel times
    the per-output validation RMS error of the best candidate (mse (..., L), summed over outputs)
    where that is larger (`rbfn.round_rel`). A network whose own error is 1e-2 rad gains nothing
    from rounding held at 2e-6: there the absolute rule forces ridges far larger than float32
    needs (it doubled the UR5's k-means error at M = 2000)."""
    best = torch.nan_to_num(mse, nan=torch.inf).amin(-1, keepdim=True).clamp(max=torch.finfo(mse.dtype).max)
    return (round_rel * (best / outputs).sqrt()).clamp(min=round_tol)


@dataclass(frozen=True)
class RoundingRule:
    """The float32-stability rule of `ridge_fit` as one value: a fit deployed in `dtype` may have a
    rounding scale (`rounding_scale`) of at most `rounding_tolerance(mse, outputs, round_tol,
    round_rel)` (output units: rad, m)."""

    dtype: torch.dtype = torch.float32
    round_tol: float = ROUND_TOL
    round_rel: float = 0.0


def ridge_choose(
    gram: torch.Tensor,
    rhs: torch.Tensor,
    score,
    ridges: tuple[float, ...] = DEFAULT_RIDGES,
    deploy: torch.dtype | None = None,
    round_tol: float = ROUND_TOL,
    round_rel: float = 0.0,
) -> RidgeFit:
    """`ridge_fit` from the normal equations: gram (..., P, P), rhs (..., P, out).

    score(weights (..., L, P, out)) -> validation MSE (..., L) and, with a deployment dtype
    `deploy`, rounding scale (..., L), max over validation rows and outputs (else None); how it
    gets them (whole design matrices, row blocks) is the caller's.
    """
    evals, evecs = torch.linalg.eigh(gram)
    proj = evecs.transpose(-1, -2) @ rhs  # (..., P, out)
    scale = gram.diagonal(dim1=-2, dim2=-1).mean(-1, keepdim=True)  # (..., 1)

    def candidates(rel: torch.Tensor):
        """Weights (..., L, P, out), validation MSE (..., L) and rounding scale (..., L) or None."""
        lam = rel * scale  # (..., L)
        coef = proj.unsqueeze(-3) / (evals.unsqueeze(-2) + lam.unsqueeze(-1)).unsqueeze(-1)  # (..., L, P, out)
        # One product for every ridge, (P, P) @ (P, L out): broadcasting evecs over L copies it
        # L times (about 9x slower at P = 44, 18x at P = 2010).
        n_l, p, n_out = coef.shape[-3:]
        flat = coef.movedim(-3, -2).reshape(*coef.shape[:-3], p, n_l * n_out)
        weights = (evecs @ flat).unflatten(-1, (n_l, n_out)).movedim(-2, -3)  # (..., L, P, out)
        mse, bnd = score(weights)
        mse = torch.nan_to_num(mse, nan=torch.inf)
        return weights, mse, None if bnd is None else torch.nan_to_num(bnd, nan=torch.inf)

    def choose(mse: torch.Tensor, bound: torch.Tensor | None) -> torch.Tensor:
        """Index (...,) of the best candidate: lowest MSE among the stable ones, else most stable."""
        if bound is None:
            return mse.argmin(-1)
        stable = bound <= tol
        fallback = torch.where(bound == bound.amin(-1, keepdim=True), mse, torch.inf)
        return torch.where(stable.any(-1, keepdim=True), torch.where(stable, mse, torch.inf), fallback).argmin(-1)

    def take(t: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        return t.gather(-1, i.unsqueeze(-1)).squeeze(-1)

    grid = torch.as_tensor(ridges, dtype=gram.dtype, device=gram.device).expand(*scale.shape[:-1], -1)
    weights, mse, bound = candidates(grid)
    tol = rounding_tolerance(mse, rhs.shape[-1], round_tol, round_rel)  # (..., 1)
    best = choose(mse, bound)
    ridge, best_mse = take(grid, best), take(mse, best)
    best_bound = None if bound is None else take(bound, best)
    best_w = weights.gather(-3, best[..., None, None, None].expand(*best.shape, 1, *weights.shape[-2:]))
    best_w = best_w.squeeze(-3)
    del weights
    if bound is not None and best_bound is not None and len(ridges) > 1:
        # The constraint binds where the next smaller grid ridge fits better but is unstable:
        # try ridges between the two (log-spaced) and keep the best stable one, if better than
        # the grid's (already scored).
        ordered = all(a < b for a, b in itertools.pairwise(ridges))
        lower = take(grid, (best - 1).clamp(min=0))
        binds = (best > 0) & (take(mse, (best - 1).clamp(min=0)) < best_mse) & (best_bound <= tol[..., 0])
        if ordered and bool(binds.any()):
            steps = torch.arange(1, 4, dtype=gram.dtype, device=gram.device) / 4
            fine = torch.exp(lower.log().unsqueeze(-1) + (ridge / lower).log().unsqueeze(-1) * steps)  # (..., 3)
            w2, mse2, bound2 = candidates(fine)
            assert bound2 is not None  # candidates give bounds where the grid's did
            b2 = choose(mse2, bound2)
            use = binds & (take(bound2, b2) <= tol[..., 0]) & (take(mse2, b2) <= best_mse)
            ridge = torch.where(use, take(fine, b2), ridge)
            best_mse = torch.where(use, take(mse2, b2), best_mse)
            best_bound = torch.where(use, take(bound2, b2), best_bound)
            w2 = w2.gather(-3, b2[..., None, None, None].expand(*b2.shape, 1, *w2.shape[-2:])).squeeze(-3)
            best_w = torch.where(use[..., None, None], w2, best_w)
    return RidgeFit(weights=best_w, ridge=ridge, val_mse=best_mse, rounding=best_bound)


def ridge_solve(a: torch.Tensor, y: torch.Tensor, ridge: float | torch.Tensor) -> torch.Tensor:
    """Weights (..., P, out) of the ridge problem with relative ridge `ridge`; differentiable."""
    gram = a.transpose(-1, -2) @ a
    scale = gram.diagonal(dim1=-2, dim2=-1).mean(-1)[..., None, None]
    eye = torch.eye(gram.shape[-1], dtype=gram.dtype, device=gram.device)
    return torch.linalg.solve(gram + torch.as_tensor(ridge, dtype=gram.dtype) * scale * eye, a.transpose(-1, -2) @ y)
