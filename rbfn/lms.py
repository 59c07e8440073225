"""Least mean squares and recursive least squares for a network's output weights.

The learners adapt weights W (B, P, out), batched over environments B, from design rows
a (B, n, P) and targets y (B, n, out), n recent pairs per update:
- `NLMS`, the paper's LMS rule normalised: W <- W + alpha(t) mean_i a_i e_i^T / (|a_i|^2 + eps),
  alpha(t) = alpha0 / (1 + t / decay) (the paper: alpha(0) = 0.5, decaying);
- `RLS`, recursive least squares with forgetting factor lambda, which converges in a few passes
  where LMS crawls on the ill-conditioned bases of accurate wide-width fits.
A pair with a non-finite row or target is skipped (its environment's weights are left as they
were) and counted in `rejected`. `lms_fit` is the offline solver: shuffled mini-batch passes of
NLMS over a training set. LMS converges on well-conditioned bases; on the ill-conditioned ones
that accurate wide-width fits produce, ridge least squares (rbfn.fit) is the solver.
"""

from __future__ import annotations

import torch

from .config import Learner
from .memory import check_fits

__all__ = ["NLMS", "RLS", "make_learner", "lms_fit"]


class NLMS:
    """Normalised least mean squares; weights (B, P, out)."""

    def __init__(self, weights: torch.Tensor, alpha0: float = 0.5, decay: float = 0.0, eps: float = 1e-6) -> None:
        if not 0.0 <= alpha0 < 2.0:
            raise ValueError(f"alpha0={alpha0} must be in [0, 2) for normalised LMS to be stable")
        if decay < 0:
            raise ValueError(f"decay={decay} must be >= 0 (0: no decay)")
        self.w, self.alpha0, self.decay, self.eps = weights.clone(), alpha0, decay, eps
        self.rejected = 0

    def alpha(self, t: float) -> float:
        return self.alpha0 / (1.0 + t / self.decay) if self.decay else self.alpha0

    def update(self, a: torch.Tensor, y: torch.Tensor, t: float = 0.0) -> torch.Tensor:
        """One step on pairs a (B, n, P), y (B, n, out); returns the prior errors (B, n, out)."""
        ok = _finite(a, y)
        rejected = int((~ok).sum())
        if rejected:
            a, y = torch.where(ok[..., None], a, 0.0), torch.where(ok[..., None], y, 0.0)
            e = (y - a @ self.w) * ok[..., None]
            n = ok.sum(-1).clamp_min(1)[:, None, None]
        else:  # every pair finite (the usual case): no masks
            e, n = y - a @ self.w, a.shape[1]  # type: ignore[assignment]   # n: an int here
        norm = a.square().sum(-1, keepdim=True) + self.eps
        self.w = self.w + self.alpha(t) * (a / norm).transpose(1, 2) @ e / n
        self.rejected += rejected
        return e


class RLS:
    """Recursive least squares with exponential forgetting; weights (B, P, out), P (B, P, P).

    It holds B (P, P) matrices and an update makes one more: weights whose matrices cannot fit
    in the memory available are refused when the learner is made, naming them with the estimate."""

    def __init__(self, weights: torch.Tensor, forgetting: float = 0.999, delta: float = 1e2) -> None:
        if not 0.0 < forgetting <= 1.0:
            raise ValueError(f"forgetting={forgetting} must be in (0, 1]")
        if not delta > 0:
            raise ValueError(f"delta={delta} must be > 0 (initial inverse-covariance scale)")
        b, p, _ = weights.shape
        check_fits(
            "weights",
            tuple(weights.shape),
            2 * b * p * p * weights.element_size(),
            str(weights.device),
            f"the inverse covariance, {b} ({p}, {p}) matrices of the weights' dtype, and an update's "
            "outer product of that size",
            advice="adapt fewer environments B or fewer design columns P at once",
        )
        self.w, self.lam = weights.clone(), forgetting
        self.p = delta * torch.eye(p, dtype=weights.dtype, device=weights.device).expand(b, p, p).clone()
        self.rejected = 0

    def update(self, a: torch.Tensor, y: torch.Tensor, t: float = 0.0) -> torch.Tensor:
        ok = _finite(a, y)
        errs = []
        for i in range(a.shape[1]):  # rank-one updates, pair by pair
            ai, yi, oki = a[:, i], y[:, i], ok[:, i]
            ai, yi = torch.where(oki[:, None], ai, 0.0), torch.where(oki[:, None], yi, 0.0)
            e = yi - (ai[:, None, :] @ self.w)[:, 0]
            pa = (self.p @ ai[..., None])[..., 0]  # (B, P)
            k = pa / (self.lam + (ai * pa).sum(-1, keepdim=True))
            k = k * oki[:, None]
            self.w = self.w + k[..., None] * e[:, None, :]
            lam = torch.where(oki, self.lam, 1.0)[:, None, None]
            self.p.sub_(k[..., None] * pa[:, None, :]).div_(lam)  # in place: one (B, P, P) temporary
            errs.append(e * oki[:, None])
        self.rejected += int((~ok).sum())
        return torch.stack(errs, 1)


def _finite(a: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    return torch.isfinite(a).all(-1) & torch.isfinite(y).all(-1)


def make_learner(
    name: str, weights: torch.Tensor, alpha0: float = 0.5, decay: float = 0.0, forgetting: float = 0.999
) -> NLMS | RLS:
    """The online learner `name` (nlms | rls) starting from weights (B, P, out)."""
    if name == "nlms":
        return NLMS(weights, alpha0, decay)
    if name == "rls":
        return RLS(weights, forgetting)
    raise ValueError(f"unknown learner {name!r}; choose one of {[str(v) for v in Learner]}")


def lms_fit(
    a: torch.Tensor,
    y: torch.Tensor,
    weights: torch.Tensor | None = None,
    *,
    alpha0: float = 0.5,
    decay: float = 1000.0,
    epochs: int = 50,
    batch_size: int = 32,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Weights (P, out) by normalised mini-batch LMS on design a (N, P) and targets y (N, out):
    `epochs` shuffled passes of NLMS, its step decaying with the update count."""
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
