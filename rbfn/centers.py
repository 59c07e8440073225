"""Baseline centre selectors: random training points, k-means (scikit-learn), OLS forward selection.

All work on scaled inputs z (N, d) and return centres (M, d) in the same units.
"""

from __future__ import annotations

import numpy as np
import torch

from .fit import design_matrix
from .layer import gaussian_features

__all__ = ["random_centers", "kmeans_centers", "ols_centers"]


def random_centers(z: torch.Tensor, m: int, generator: torch.Generator) -> torch.Tensor:
    """m distinct training inputs chosen uniformly at random."""
    idx = torch.randperm(z.shape[0], generator=generator)[:m].to(z.device)
    return z[idx].clone()


# Largest N * M * d (summed over restarts) k-means runs restarts for; above it fewer restarts, at
# least one. At the UR5's N = 20000, M = 2000, d = 9 one restart costs about a tenth of ten, and
# three restarts ended at the same inertia as one.
KMEANS_WORK_MAX = 2e8


def kmeans_restarts(n: int, m: int, d: int, restarts: int) -> int:
    """Restarts k-means runs: `restarts`, capped so restarts * N * M * d <= KMEANS_WORK_MAX."""
    return max(1, min(restarts, int(KMEANS_WORK_MAX // max(n * m * d, 1))))


def kmeans_centers(z: torch.Tensor, m: int, seed: int, restarts: int = 10) -> torch.Tensor:
    """k-means++ initialised Lloyd iterations, best of `restarts` (scikit-learn's KMeans), fewer
    restarts on large problems (`kmeans_restarts`)."""
    restarts = kmeans_restarts(z.shape[0], m, z.shape[1], restarts)
    # Imported here, not with the module: scikit-learn and SciPy take a second to import, which
    # evaluate.py's forked parts then pay side by side instead of before the fork.
    from sklearn.cluster import KMeans

    km = KMeans(n_clusters=m, init="k-means++", n_init=restarts, random_state=seed)
    km.fit(z.detach().cpu().numpy().astype(np.float64))
    return torch.as_tensor(km.cluster_centers_, dtype=z.dtype, device=z.device)


def ols_centers(
    z: torch.Tensor, y: torch.Tensor, m: int, widths: torch.Tensor, candidates: torch.Tensor, tail: bool = True
) -> torch.Tensor:
    """Orthogonal least squares forward selection (Chen, Cowan & Grant 1991), batched over widths.

    Candidates (C, d) are candidate centres; widths (S,) are global widths tried side by side.
    At each step the candidate with the largest error reduction ratio is added and the remaining
    candidate columns are orthogonalised against it. The tail and bias columns, if any, are
    always in the model (targets and candidates are projected off them first).
    Returns centres (S, m, d), one set per width.
    """
    s, c = widths.shape[0], candidates.shape[0]
    if not 1 <= m <= c:
        raise ValueError(f"OLS needs 1 <= M <= candidates ({c}), got M={m}")
    cols = gaussian_features(z, candidates.expand(s, c, -1), widths[:, None].expand(s, c))  # (S, N, C)
    target = y.expand(s, *y.shape).clone()
    if tail:
        base = design_matrix(z, candidates[:0], widths[:0], tail=True)  # (N, d + 1)
        q, _ = torch.linalg.qr(base)
        cols = cols - q @ (q.T @ cols)
        target = target - q @ (q.T @ target)
    chosen = torch.zeros(s, c, dtype=torch.bool, device=z.device)
    picks = []
    for _ in range(m):  # sequential by nature: each pick changes the residual candidates
        norm2 = cols.square().sum(1)  # (S, C)
        err = (cols.transpose(1, 2) @ target).square().sum(-1) / norm2.clamp_min(1e-300)
        err = err.masked_fill(chosen | (norm2 < 1e-24), -1.0)
        j = err.argmax(-1)  # (S,)
        picks.append(j)
        chosen[torch.arange(s), j] = True
        w = cols[torch.arange(s), :, j].unsqueeze(-1)  # (S, N, 1)
        wn = w / w.square().sum(1, keepdim=True).sqrt().clamp_min(1e-300)
        cols = cols - wn @ (wn.transpose(1, 2) @ cols)
        target = target - wn @ (wn.transpose(1, 2) @ target)
    return candidates[torch.stack(picks, dim=1)]  # (S, m, d)
