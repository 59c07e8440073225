"""Least mean squares: the paper's iterative weight rule w <- w + alpha e a, alpha decaying.

Normalised LMS over mini-batches: w <- w + alpha(t) * mean_b(a_b e_b^T / (||a_b||^2 + eps)),
alpha(t) = alpha0 / (1 + t / decay) (t counts updates). Converges on well-conditioned bases; on
the ill-conditioned ones that accurate wide-width fits produce, least squares is the solver.
"""
from __future__ import annotations

import torch

from .online import NLMS

__all__ = ["lms_fit"]


def lms_fit(a: torch.Tensor, y: torch.Tensor, weights: torch.Tensor | None = None, alpha0: float = 0.5,
            decay: float = 1000.0, epochs: int = 50, batch_size: int = 32,
            generator: torch.Generator | None = None) -> torch.Tensor:
    """Weights (P, out) by normalised mini-batch LMS on design a (N, P) and targets y (N, out):
    `epochs` shuffled passes of rbfn.online.NLMS, its step decaying with the update count."""
    if not 0.0 < alpha0 < 2.0:
        raise ValueError(f"alpha0 must be in (0, 2) for normalised LMS to be stable, got {alpha0}")
    w = torch.zeros(a.shape[1], y.shape[1], dtype=a.dtype, device=a.device) if weights is None else weights
    learner = NLMS(w[None], alpha0, decay, eps=1e-12)
    t = 0
    for _ in range(epochs):
        perm = torch.randperm(a.shape[0], generator=generator).to(a.device)
        for idx in perm.split(batch_size):
            learner.update(a[None, idx], y[None, idx], float(t))
            t += 1
    return learner.w[0]
