"""The Gaussian RBF network as an nn.Module: scaling -> Gaussian features -> linear head.

y(x) = W phi(z) + A z + b, z = (x - offset) / scale, phi_i(z) = exp(-||z - mu_i||^2 / (2 sigma_i^2)).
Scaling, centres and widths are buffers (chosen, not trained); the head is an nn.Linear and the
optional linear tail A z an nn.Linear without bias. Distances are taken by broadcasting, so the
module exports with a dynamic batch dimension and stays accurate in float32.
"""
from __future__ import annotations

import torch
from torch import nn

__all__ = ["RBFNetwork", "gaussian_features", "assemble"]


def gaussian_features(z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """Gaussian activations (..., N, M) of inputs z (..., N, d), centres (..., M, d), widths (..., M)."""
    d2 = (z.unsqueeze(-2) - centers.unsqueeze(-3)).square().sum(-1)
    return torch.exp(-d2 / (2.0 * widths.unsqueeze(-2).square()))


class RBFNetwork(nn.Module):
    """Gaussian RBF network mapping inputs (B, d) to outputs (B, out).

    Besides the prediction, it knows the region it was trained on: `in_workspace(x)` flags
    inputs outside the training inputs' box, farther from every centre than any training
    input was (`cover_radius`, scaled units), or whose prediction leaves the output range.
    """

    def __init__(self, centers: torch.Tensor, widths: torch.Tensor, out_features: int,
                 offset: torch.Tensor | None = None, scale: torch.Tensor | None = None,
                 tail: bool = True) -> None:
        super().__init__()
        m, d = centers.shape
        if widths.shape != (m,):
            raise ValueError(f"widths must have shape ({m},), got {tuple(widths.shape)}")
        if not bool((widths > 0).all()):
            raise ValueError(f"widths must be positive, got min {widths.min().item():.3g}")
        kw = {"dtype": centers.dtype, "device": centers.device}
        self.register_buffer("offset", torch.zeros(d, **kw) if offset is None else offset.to(**kw))
        self.register_buffer("scale", torch.ones(d, **kw) if scale is None else scale.to(**kw))
        self.register_buffer("centers", centers.clone())
        self.register_buffer("widths", widths.clone())
        self.head = nn.Linear(m, out_features, **kw)
        self.tail = nn.Linear(d, out_features, bias=False, **kw) if tail else None
        # Trained region, set by `set_domain` after fitting (defaults: unbounded).
        self.register_buffer("in_low", torch.full((d,), -torch.inf, **kw))
        self.register_buffer("in_high", torch.full((d,), torch.inf, **kw))
        self.register_buffer("out_low", torch.full((out_features,), -torch.inf, **kw))
        self.register_buffer("out_high", torch.full((out_features,), torch.inf, **kw))
        self.register_buffer("cover_radius", torch.tensor(torch.inf, **kw))

    @property
    def num_centers(self) -> int:
        return self.centers.shape[0]

    def scaled(self, x: torch.Tensor) -> torch.Tensor:
        """Scaled inputs z (B, d) for inputs x (B, d)."""
        return (x.to(self.centers.dtype) - self.offset) / self.scale

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Gaussian activations (B, M) for inputs x (B, d)."""
        return gaussian_features(self.scaled(x), self.centers, self.widths)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Outputs (B, out) for inputs x (B, d) (any float dtype; computed in the module's)."""
        z = self.scaled(x)
        y = self.head(gaussian_features(z, self.centers, self.widths))
        return y if self.tail is None else y + self.tail(z)

    def in_workspace(self, x: torch.Tensor, y: torch.Tensor | None = None) -> torch.Tensor:
        """Boolean mask (B,): True where input x (B, d) lies in the region the network was trained on."""
        z = self.scaled(x)
        y = self.forward(x) if y is None else y
        d_min = (z.unsqueeze(-2) - self.centers).square().sum(-1).min(-1).values.sqrt()
        xs = x.to(self.centers.dtype)
        ok = ((xs >= self.in_low) & (xs <= self.in_high)).all(-1)
        ok &= d_min <= self.cover_radius
        return ok & ((y >= self.out_low) & (y <= self.out_high)).all(-1)

    def solve(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(outputs (B, out), in-workspace mask (B,)) for inputs x (B, d)."""
        y = self.forward(x)
        return y, self.in_workspace(x, y)

    @torch.no_grad()
    def set_domain(self, x_train: torch.Tensor, y_train: torch.Tensor, margin: float = 0.05) -> None:
        """Record the trained region from training inputs (N, d) and targets (N, out).

        The box and output range get `margin` of their span on each side; the cover radius is
        the largest distance from a training input to its nearest centre, times (1 + margin).
        """
        x = x_train.to(self.centers.dtype)
        y = y_train.to(self.centers.dtype)
        span_x = x.amax(0) - x.amin(0)
        span_y = y.amax(0) - y.amin(0)
        self.in_low.copy_(x.amin(0) - margin * span_x)
        self.in_high.copy_(x.amax(0) + margin * span_x)
        self.out_low.copy_(y.amin(0) - margin * span_y)
        self.out_high.copy_(y.amax(0) + margin * span_y)
        z = self.scaled(x)
        d_min = torch.cdist(z, self.centers).min(-1).values
        self.cover_radius.copy_(d_min.max() * (1 + margin))


def assemble(centers: torch.Tensor, widths: torch.Tensor, weights: torch.Tensor, offset: torch.Tensor,
             scale: torch.Tensor, tail: bool) -> RBFNetwork:
    """An RBFNetwork from fitted parts; weights (P, out) ordered as rbfn.fit.design_matrix's columns."""
    m, d = centers.shape
    net = RBFNetwork(centers, widths, weights.shape[1], offset=offset, scale=scale, tail=tail)
    with torch.no_grad():
        net.head.weight.copy_(weights[:m].T)
        if tail:
            net.tail.weight.copy_(weights[m:m + d].T)
            net.head.bias.copy_(weights[m + d])
        else:
            net.head.bias.zero_()
    return net
