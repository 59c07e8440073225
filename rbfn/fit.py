"""Output weights by ridge least squares, the ridge chosen on a validation split.

Everything is batched over a leading "ant" dimension K, so a colony's candidate centre sets are
fitted in one tensor computation. The design matrix is [phi(z), z, 1] (the linear tail and bias
are optional columns).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .layer import gaussian_features

__all__ = ["design_matrix", "RidgeFit", "ridge_fit", "ridge_solve", "deployed_design", "DEFAULT_RIDGES"]

# Ridge values relative to the mean diagonal of the Gram matrix.
DEFAULT_RIDGES = tuple(10.0**e for e in range(-13, -1))


def design_matrix(z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor,
                  tail: bool = True) -> torch.Tensor:
    """Design matrix (..., N, P) with P = M [+ d + 1]: features, then tail z and bias column.

    Squared distances use |z|^2 + |c|^2 - 2 z.c (one matmul), which is fast and exact enough in
    float64, the precision fitting runs in; the module evaluates by broadcasting instead.
    """
    # |z|^2 + |c|^2 - 2 z c^T, then exp(-max(., 0) / (2 sigma^2)), in place on one buffer.
    phi = (z @ centers.transpose(-1, -2)).mul_(-2.0)
    phi.add_(z.square().sum(-1, keepdim=True)).add_(centers.square().sum(-1).unsqueeze(-2))
    phi.clamp_(min=0.0).div_(widths.unsqueeze(-2).square() * -2.0).exp_()
    if not tail:
        return phi
    shape = phi.shape[:-1]
    ones = torch.ones(*shape, 1, dtype=phi.dtype, device=phi.device)
    return torch.cat([phi, z.expand(*shape, z.shape[-1]), ones], dim=-1)


def deployed_design(x: torch.Tensor, offset: torch.Tensor, scale: torch.Tensor, centers: torch.Tensor,
                    widths: torch.Tensor, tail: bool, dtype: torch.dtype) -> torch.Tensor:
    """The design matrix (N, P) exactly as an RBFNetwork in `dtype` computes it from raw inputs x."""
    cast = [t.to(dtype) for t in (x, offset, scale, centers, widths)]
    z = (cast[0] - cast[1]) / cast[2]
    phi = gaussian_features(z, cast[3], cast[4])
    if not tail:
        return phi
    return torch.cat([phi, z, torch.ones_like(z[:, :1])], dim=-1)


@dataclass
class RidgeFit:
    """Weights (..., P, out), the chosen relative ridge (...,) and validation MSE (...,)."""

    weights: torch.Tensor
    ridge: torch.Tensor
    val_mse: torch.Tensor


def ridge_fit(a_train: torch.Tensor, y_train: torch.Tensor, a_val: torch.Tensor, y_val: torch.Tensor,
              ridges: tuple[float, ...] = DEFAULT_RIDGES, eval_dtype: torch.dtype | None = None,
              a_val_eval: torch.Tensor | None = None) -> RidgeFit:
    """Ridge least squares for every ridge in `ridges`; keep the one with the lowest validation MSE.

    a_train (..., N, P), y_train (N, out), a_val (..., Nv, P), y_val (Nv, out). Solved through
    the eigendecomposition of the Gram matrix, so all ridges cost one decomposition. With
    `eval_dtype` (e.g. float32) the validation error is measured with weights and design rounded
    to that dtype, so the chosen ridge is one whose fit survives deployment in that precision.
    MSE is the mean over samples of the summed squared output error.
    """
    gram = a_train.transpose(-1, -2) @ a_train
    rhs = a_train.transpose(-1, -2) @ y_train
    evals, evecs = torch.linalg.eigh(gram)
    proj = evecs.transpose(-1, -2) @ rhs                          # (..., P, out)
    scale = gram.diagonal(dim1=-2, dim2=-1).mean(-1, keepdim=True)  # (..., 1)
    lam = torch.as_tensor(ridges, dtype=gram.dtype, device=gram.device) * scale  # (..., L)
    coef = proj.unsqueeze(-3) / (evals.unsqueeze(-2) + lam.unsqueeze(-1)).unsqueeze(-1)  # (...,L,P,out)
    weights = evecs.unsqueeze(-3) @ coef                           # (..., L, P, out)
    n_l, p, n_out = weights.shape[-3:]
    w_flat = weights.movedim(-3, -2).reshape(*weights.shape[:-3], p, n_l * n_out)
    if a_val_eval is not None:
        pred = (a_val_eval @ w_flat.to(a_val_eval.dtype)).to(gram.dtype)
    elif eval_dtype is None:
        pred = a_val @ w_flat
    else:
        pred = (a_val.to(eval_dtype) @ w_flat.to(eval_dtype)).to(gram.dtype)
    pred = pred.reshape(*pred.shape[:-1], n_l, n_out).movedim(-2, -3)   # (..., L, Nv, out)
    mse = (pred - y_val).square().sum(-1).mean(-1)                 # (..., L)
    mse = torch.nan_to_num(mse, nan=torch.inf)
    best = mse.argmin(-1)
    idx = best[..., None, None, None].expand(*best.shape, 1, *weights.shape[-2:])
    return RidgeFit(weights=weights.gather(-3, idx).squeeze(-3),
                    ridge=torch.as_tensor(ridges, dtype=gram.dtype, device=gram.device)[best],
                    val_mse=mse.gather(-1, best.unsqueeze(-1)).squeeze(-1))


def ridge_solve(a: torch.Tensor, y: torch.Tensor, ridge: float | torch.Tensor) -> torch.Tensor:
    """Weights (..., P, out) of the ridge problem with relative ridge `ridge`; differentiable."""
    gram = a.transpose(-1, -2) @ a
    scale = gram.diagonal(dim1=-2, dim2=-1).mean(-1)[..., None, None]
    eye = torch.eye(gram.shape[-1], dtype=gram.dtype, device=gram.device)
    return torch.linalg.solve(gram + torch.as_tensor(ridge, dtype=gram.dtype) * scale * eye,
                              a.transpose(-1, -2) @ y)


def lms_weights(a_train: torch.Tensor, y_train: torch.Tensor, alpha0: float, epochs: int,
                generator: torch.Generator) -> torch.Tensor:
    """The paper's solver: normalised LMS from zero weights (see rbfn.lms)."""
    from .lms import lms_fit

    return lms_fit(a_train, y_train, alpha0=alpha0, epochs=epochs, generator=generator)
