"""Width rules: the paper's d_max / sqrt(2M), per-centre nearest-neighbour widths, and scales.

Every rule returns a base width per centre (M,); a scale s multiplies it. The paper's rule is
s = 1 with the global base; "validation" chooses s on the validation split (see `fit_widths`).
"""

from __future__ import annotations

import torch

from .config import MIN_WIDTH_SCALE, WidthRule

__all__ = ["paper_widths", "nearest_widths", "base_widths", "check_max_width", "SCALE_GRID"]

# Scales tried on validation (log-spaced, 0.25x to 64x the base width).
SCALE_GRID = tuple(2.0 ** (e / 2) for e in range(-4, 13))


def paper_widths(centers: torch.Tensor) -> torch.Tensor:
    """sigma = d_max / sqrt(2M) for every centre; centres (..., M, d) -> (..., M)."""
    m = centers.shape[-2]
    d_max = torch.cdist(centers, centers).amax(dim=(-1, -2))
    return (d_max / (2.0 * m) ** 0.5).unsqueeze(-1).expand(*centers.shape[:-1]).clone()


def nearest_widths(centers: torch.Tensor, k: int = 2) -> torch.Tensor:
    """Per-centre widths (..., M): mean distance to the k nearest other centres."""
    m = centers.shape[-2]
    if m < 2:
        return torch.ones(centers.shape[:-1], dtype=centers.dtype, device=centers.device)
    d = torch.cdist(centers, centers)
    d = d + torch.diag_embed(torch.full(centers.shape[:-1], torch.inf, dtype=d.dtype, device=d.device))
    kk = min(k, m - 1)
    return d.topk(kk, dim=-1, largest=False).values.mean(-1).clamp_min(1e-9)


def base_widths(centers: torch.Tensor, rule: str) -> torch.Tensor:
    """Base widths (..., M) for `rule` (a WidthRule) ("paper" and "global" share the paper's base)."""
    if rule in ("paper", "global"):
        return paper_widths(centers)
    if rule == "per_center":
        return nearest_widths(centers)
    raise ValueError(f"unknown width rule {rule!r}; allowed: {[str(r) for r in WidthRule]}")


def check_max_width(z: torch.Tensor, max_width: float, m: int) -> None:
    """ValueError naming rbfn.max_width where it caps every width below MIN_WIDTH_SCALE / 2 of the
    paper's rule for M = m centres among the scaled inputs z (N, d): a lenient reference, the box
    diagonal of z / sqrt(2M) (centres' d_max is at most the diagonal), so a useful cap is never refused."""
    diag = float((z.amax(0) - z.amin(0)).norm())
    floor = 0.5 * MIN_WIDTH_SCALE * diag / (2.0 * m) ** 0.5
    if max_width < floor:
        raise ValueError(
            f"rbfn.max_width={max_width!r} is not allowed: it caps every width below {floor:.3g} "
            f"(1/{1 / (0.5 * MIN_WIDTH_SCALE):g} of the paper's width d_max / sqrt(2M) = "
            f"{diag / (2.0 * m) ** 0.5:.3g} scaled units for these inputs at M = {m}), where "
            f"the Gaussians vanish between centres; use at least {floor:.3g}"
        )
