"""The Gaussian RBF network as an nn.Module: scaling -> Gaussian features -> linear head.

y(x) = W phi(z) + A z + b, z = (x - offset) / scale, phi_i(z) = exp(-||z - mu_i||^2 / (2 sigma_i^2)).
Scaling, centres and widths are buffers (chosen, not trained); the head is an nn.Linear and the
optional linear tail A z an nn.Linear without bias. Distances are taken by broadcasting, so the
module exports with a dynamic batch dimension and stays accurate in float32. Eager calls process
rows in blocks of `block_rows`, so memory stays bounded for any batch size.

The output weights as one matrix: net(x) = net.design(x) @ net.output_weights(), the design
columns being the M Gaussians, then z (d) and a ones column with the tail, or a ones column
without it (the order of rbfn.fit.design_matrix).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn

from .targets import TargetFeatures

__all__ = ["RBFNetwork", "gaussian_features", "assemble"]


def gaussian_features(z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """Gaussian activations (..., N, M) of inputs z (..., N, d), centres (..., M, d), widths (..., M)."""
    return _gaussians(_sq_distances(z, centers), widths)


def _sq_distances(z: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Squared distances (..., N, M) by broadcasting (accurate in float32, exportable)."""
    return (z.unsqueeze(-2) - centers.unsqueeze(-3)).square().sum(-1)


def _gaussians(d2: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    return torch.exp(-d2 / (2.0 * widths.unsqueeze(-2).square()))


class RBFNetwork(nn.Module):
    """Gaussian RBF network mapping inputs (B, d) to outputs (B, out); for IK, positions (B, 3) in m
    to joints (B, 3) (rad, rad, m).

    Inputs may be torch tensors or numpy arrays (converted with torch.as_tensor onto the module's
    device; the outputs are tensors), of any real dtype (computed in the module's dtype).

    Besides the prediction, it knows the region it was trained on: `in_workspace(x)` flags
    inputs outside the training inputs' box, farther from every centre than any training
    input was (`cover_radius`, scaled units), or whose prediction leaves the output range.
    """

    block_rows: int = 16384   # rows per block in eager calls (bounds the (rows, M, d) distances)

    def __init__(self, centers: torch.Tensor, widths: torch.Tensor, out_features: int,
                 offset: torch.Tensor | None = None, scale: torch.Tensor | None = None,
                 tail: bool = True, inputs: TargetFeatures | None = None) -> None:
        super().__init__()
        # Public inputs -> features (d): pose targets (B, 7) become 9 features; None: inputs are features.
        self.inputs = inputs
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

    @property
    def in_features(self) -> int:
        """Width of the public input: 3 for positions, 7 for poses (else the feature width d)."""
        return self.inputs.in_features if self.inputs is not None else self.centers.shape[1]

    @property
    def target(self) -> str:
        """The IK target kind: "pose" or "position"."""
        return "pose" if self.inputs is not None and self.inputs.pose else "position"

    @property
    def out_features(self) -> int:
        return self.head.out_features

    @property
    def num_design(self) -> int:
        """Columns P of `design`: M + d + 1 with the tail, M + 1 without."""
        return self.num_centers + (self.centers.shape[1] if self.tail is not None else 0) + 1

    # ---------------------------------------------------------------------------------- inputs
    def _inputs(self, x, leading: bool = False) -> torch.Tensor:
        """x as a tensor (B, d), or with `leading` (..., d); else a clear error naming what came."""
        d = self.in_features
        pose = self.target == "pose"
        name = "poses" if pose else {3: "positions"}.get(d, "inputs")
        want = f"(..., {d})" if leading else f"(B, {d})"
        if isinstance(x, np.ndarray):
            x = torch.as_tensor(x, device=self.centers.device)
        elif not isinstance(x, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor or numpy.ndarray {want}, got {type(x).__name__}")
        if x.dim() < 1 or x.shape[-1] != d or (not leading and x.dim() != 2):
            hint = f" (one input is (1, {d}))" if x.dim() == 1 and x.shape[0] == d else ""
            if pose:
                hint += ": position in m, then a unit quaternion (w, x, y, z)"
            raise ValueError(f"{name} must be {want}{hint}, got shape {tuple(x.shape)}")
        if x.dtype == torch.bool or x.is_complex():
            raise TypeError(f"{name} must be real numbers, got dtype {x.dtype}")
        tracing = torch.compiler.is_compiling() or torch.compiler.is_exporting()
        if self.inputs is not None and self.inputs.pose and not leading and not tracing:
            self.inputs.check(x)          # unit quaternions, finite values (data checks: eager only)
        return x

    def check_inputs(self, x) -> torch.Tensor:
        """`x` as a tensor (B, in_features), or a clear TypeError/ValueError naming what is wrong."""
        return self._inputs(x)

    def _feat(self, x: torch.Tensor) -> torch.Tensor:
        """Features (..., d) of public inputs (..., in_features), in the module's dtype."""
        x = x.to(self.centers.dtype)
        return x if self.inputs is None else self.inputs(x)

    def _blocks(self, fn: Callable, *xs: torch.Tensor):
        """fn applied to blocks of `block_rows` rows of xs and concatenated (one call when traced)."""
        n = xs[0].shape[0]
        if torch.compiler.is_compiling() or n <= self.block_rows:
            return fn(*xs)
        outs = [fn(*parts) for parts in zip(*(t.split(self.block_rows) for t in xs))]
        if isinstance(outs[0], tuple):
            return tuple(torch.cat(o) for o in zip(*outs))
        return torch.cat(outs)

    def _rows(self, fn: Callable, x: torch.Tensor) -> torch.Tensor:
        """fn (rows (N, d) -> (N, k)) on inputs (..., d) in blocks, as (..., k)."""
        x = self._inputs(x, leading=True)
        out = self._blocks(fn, x.reshape(-1, x.shape[-1]))
        return out.reshape(*x.shape[:-1], out.shape[-1])

    # -------------------------------------------------------------------------------- features
    def scaled(self, x: torch.Tensor) -> torch.Tensor:
        """Scaled inputs z (..., d) for inputs x (..., d)."""
        return self._scaled(self._inputs(x, leading=True))

    def _scaled(self, x: torch.Tensor) -> torch.Tensor:
        return (self._feat(x) - self.offset) / self.scale

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Gaussian activations (..., M) for inputs x (..., d)."""
        return self._rows(lambda xb: gaussian_features(self._scaled(xb), self.centers, self.widths), x)

    def design(self, x: torch.Tensor) -> torch.Tensor:
        """Design rows a(x) (..., P) for inputs x (..., d), with net(x) = a(x) @ output_weights():
        the M Gaussians, then the scaled inputs z (d) and a ones column with the tail, or a ones
        column without it (P = `num_design`)."""
        return self._rows(self._design_rows, x)

    def _design_rows(self, x: torch.Tensor) -> torch.Tensor:
        z = self._scaled(x)
        cols = [gaussian_features(z, self.centers, self.widths)]
        if self.tail is not None:
            cols.append(z)
        return torch.cat(cols + [torch.ones_like(z[:, :1])], -1)

    def output_weights(self) -> torch.Tensor:
        """Output weights W (P, out) ordered as `design`'s columns (a detached copy)."""
        parts = [self.head.weight.T]
        if self.tail is not None:
            parts.append(self.tail.weight.T)
        return torch.cat(parts + [self.head.bias[None]], 0).detach().clone()

    @torch.no_grad()
    def set_output_weights(self, w: torch.Tensor) -> None:
        """Set the head (and tail) from W (P, out) ordered as `design`'s columns."""
        p, m, out = self.num_design, self.num_centers, self.out_features
        if not isinstance(w, torch.Tensor):
            raise TypeError(f"output weights must be a torch.Tensor ({p}, {out}), got {type(w).__name__}")
        if tuple(w.shape) != (p, out):
            rows = f"{m} Gaussians + {self.centers.shape[1]} tail + bias" if self.tail is not None else f"{m} Gaussians + bias"
            raise ValueError(f"output weights must be ({p}, {out}) (rows: {rows}), got shape {tuple(w.shape)}")
        self.head.weight.copy_(w[:m].T)
        if self.tail is not None:
            self.tail.weight.copy_(w[m:-1].T)
        self.head.bias.copy_(w[-1])

    # ------------------------------------------------------------------------------ prediction
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Outputs (B, out) for inputs x (B, d) (e.g. joints for positions in m)."""
        return self._blocks(self._forward_rows, self._inputs(x))

    def _forward_rows(self, x: torch.Tensor) -> torch.Tensor:
        """`forward` on rows (B, d) in one piece (no blocks, no checks): the exported graph's path."""
        z = self._scaled(x)
        return self._head(z, _gaussians(_sq_distances(z, self.centers), self.widths))

    def _head(self, z: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        y = self.head(phi)
        return y if self.tail is None else y + self.tail(z)

    def in_workspace(self, x: torch.Tensor, y: torch.Tensor | None = None) -> torch.Tensor:
        """Boolean mask (B,): True where input x (B, d) lies in the region the network was trained
        on; `y` (B, out), the outputs at x if already computed."""
        x = self._inputs(x)
        if y is None:
            return self._blocks(lambda xb: self._solve_rows(xb)[1], x)
        if isinstance(y, np.ndarray):
            y = torch.as_tensor(y, device=self.centers.device)
        if not isinstance(y, torch.Tensor) or tuple(y.shape) != (x.shape[0], self.out_features):
            got = tuple(y.shape) if isinstance(y, torch.Tensor) else type(y).__name__
            raise ValueError(f"outputs y must be ({x.shape[0]}, {self.out_features}) for "
                             f"{x.shape[0]} inputs, got {got}")

        def rows(xb: torch.Tensor, yb: torch.Tensor) -> torch.Tensor:
            return self._mask(xb, _sq_distances(self._scaled(xb), self.centers), yb)
        return self._blocks(rows, x, y)

    def solve(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(outputs (B, out), in-workspace mask (B,)) for inputs x (B, d)."""
        return self._blocks(self._solve_rows, self._inputs(x))

    def _solve_rows(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`solve` on rows (B, d) in one piece, distances computed once for the features and the
        mask (no blocks, no checks): the exported graph's path."""
        z = self._scaled(x)
        d2 = _sq_distances(z, self.centers)
        y = self._head(z, _gaussians(d2, self.widths))
        return y, self._mask(x, d2, y)

    def _mask(self, x: torch.Tensor, d2: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """In-workspace mask (B,) from inputs (B, d), squared distances (B, M), outputs (B, out)."""
        xs = self._feat(x)
        ok = ((xs >= self.in_low) & (xs <= self.in_high)).all(-1)
        ok &= d2.min(-1).values.sqrt() <= self.cover_radius
        return ok & ((y >= self.out_low) & (y <= self.out_high)).all(-1)

    @torch.no_grad()
    def set_domain(self, x_train: torch.Tensor, y_train: torch.Tensor, margin: float = 0.05) -> None:
        """Record the trained region from training inputs (N, d) and targets (N, out).

        The box and output range get `margin` of their span on each side; the cover radius is
        the largest distance from a training input to its nearest centre, times (1 + margin).
        """
        x = self._feat(x_train)
        y = y_train.to(self.centers.dtype)
        span_x = x.amax(0) - x.amin(0)
        span_y = y.amax(0) - y.amin(0)
        self.in_low.copy_(x.amin(0) - margin * span_x)
        self.in_high.copy_(x.amax(0) + margin * span_x)
        self.out_low.copy_(y.amin(0) - margin * span_y)
        self.out_high.copy_(y.amax(0) + margin * span_y)
        z = (x - self.offset) / self.scale
        d_min = torch.cdist(z, self.centers).min(-1).values
        self.cover_radius.copy_(d_min.max() * (1 + margin))


def assemble(centers: torch.Tensor, widths: torch.Tensor, weights: torch.Tensor, offset: torch.Tensor,
             scale: torch.Tensor, tail: bool, inputs: TargetFeatures | None = None) -> RBFNetwork:
    """An RBFNetwork from fitted parts; weights (P, out) ordered as `RBFNetwork.design`'s columns,
    which are rbfn.fit.design_matrix's. Without the tail, weights may also be (M, out) (design_matrix
    has no bias column then): the bias is zero."""
    m = centers.shape[0]
    net = RBFNetwork(centers, widths, weights.shape[-1], offset=offset, scale=scale, tail=tail,
                     inputs=None if inputs is None or not inputs.pose else inputs.to(centers.dtype))
    if not tail and weights.dim() == 2 and weights.shape[0] == m:
        weights = torch.cat([weights, weights.new_zeros(1, weights.shape[1])])
    net.set_output_weights(weights.to(net.centers.dtype))
    return net
