"""The Gaussian RBF network as an nn.Module: scaling -> Gaussian features -> linear head.

    z = (x - offset) / scale                               scaled inputs (B, d)
    h_i = exp(-|z - mu_i|^2 / (2 sigma_i^2))               Gaussian features (B, M): `gaussian_features`
    y = W h + A z + b                                      outputs (B, out): `RBFNetwork.forward`

Scaling, centres mu and widths sigma are buffers (chosen, not trained); the head (W, b) is an
nn.Linear and the optional linear tail A z an nn.Linear without bias. The Gaussian is written once,
in `rbfn.gaussians`, with its faster forms beside it: `forward` shows the equation as written
above (`fast = False`, the plain path) beside the path predictions take by default
(`fast = True`): every exponent by one float64 matrix product (`rbfn.gaussians.expand`), the
workspace flag's cover test folded into it in `solve`. Eager calls of the fast path process rows
in blocks of about `block_elements` exponents, which stay in cache; traced and exported graphs
are one piece with a dynamic batch dimension. `features` takes the plain broadcast distances.

The output weights as one matrix: net(x) = net.design(x) @ net.output_weights(), the design
columns being the M Gaussians, then z (d) and a ones column with the tail, or a ones column
without it (the order of rbfn.fit.design_matrix, which builds them in float64 for fitting).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import nn

from .gaussians import (  # the Gaussian and its fast form; re-exported: rbfn.layer's API
    EXPONENT_DTYPE,
    LOG2E,
    MIN_WIDTH,
    Expansion,
    cover_foldable,
    distance_rows,
    expand,
    gaussian,
    gaussian_features,
    sq_distances,
)
from .targets import TargetFeatures

__all__ = [
    "RBFNetwork",
    "gaussian",
    "gaussian_features",
    "sq_distances",
    "distance_rows",
    "assemble",
    "row_blocks",
    "MIN_WIDTH",
    "LOG2E",
]


def row_blocks(fn: Callable, rows: int, *xs: torch.Tensor):
    """fn applied to blocks of `rows` rows of tensors xs (B, ...) and concatenated: fn's tensor, or
    tuple of tensors, (B, ...). One call where B <= rows. So a row-wise computation holds its
    temporaries for `rows` rows at a time, whatever B (the network's eager calls, `rbfn.solver`)."""
    n = xs[0].shape[0]
    if n <= rows:
        return fn(*xs)
    outs = [fn(*parts) for parts in zip(*(t.split(rows) for t in xs))]
    if isinstance(outs[0], tuple):
        return tuple(torch.cat(o) for o in zip(*outs))
    return torch.cat(outs)


def _within(x: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """Rows (B,) of x (B, k) with low <= x <= high (k,) throughout: the gaps [x - low, high - x] by
    one matrix product, all >= 0 (fl(x - low) >= 0 exactly when x >= low; NaN fails). One product
    instead of broadcast comparisons, which ONNX Runtime runs ~10x slower on (B, 3)."""
    eye = torch.eye(x.shape[-1], dtype=x.dtype, device=x.device)
    return torch.addmm(torch.cat([-low, high]), x, torch.cat([eye, -eye], 1)).amin(-1) >= 0


class RBFNetwork(nn.Module):
    """Gaussian RBF network mapping inputs (B, d) to outputs (B, out); for IK, positions (B, 3) in m
    to joints (B, 3) (rad, rad, m).

    Inputs may be torch tensors or numpy arrays (converted with torch.as_tensor onto the module's
    device; the outputs are tensors), of any real dtype (computed in the module's dtype).

    Besides the prediction, it knows the region it was trained on: `in_workspace(x)` flags
    inputs outside the training inputs' box, farther from every centre than any training
    input was (`cover_radius`, scaled units), or whose prediction leaves the output range.
    """

    # Which way `forward` computes: True, the Gaussians' exponents by one matrix product
    # (`_expansion`); False, the plain equation (a reference: it holds (rows, M, d) differences).
    # Both in row blocks. `solve`, `in_workspace` and `design` take the fast path either way.
    fast: bool = True
    # Rows per block in eager calls; None: about `block_elements` (rows, M) exponents a block
    # (2 MB in float32: fastest measured at M = 80 and M = 2000, twice as fast as 16384 rows at M = 2000).
    block_rows: int | None = None
    block_elements: int = 1 << 19
    # Whether traced graphs (torch.compile, torch.export, ONNX) fold the cover test into the
    # exponents: set by `for_export` from the eager check (`cover_foldable`), which a graph cannot take.
    traced_cover_fold: bool = False
    # Buffers (registered in __init__), for type checkers.
    offset: torch.Tensor
    scale: torch.Tensor
    centers: torch.Tensor
    widths: torch.Tensor
    in_low: torch.Tensor
    in_high: torch.Tensor
    out_low: torch.Tensor
    out_high: torch.Tensor
    cover_radius: torch.Tensor

    def __init__(
        self,
        centers: torch.Tensor,
        widths: torch.Tensor,
        out_features: int,
        offset: torch.Tensor | None = None,
        scale: torch.Tensor | None = None,
        tail: bool = True,
        inputs: TargetFeatures | None = None,
    ) -> None:
        super().__init__()
        # Public inputs -> features (d): pose targets (B, 7) become 9 features; None: inputs are features.
        self.inputs = inputs
        for name, t in (("centers", centers), ("widths", widths)):
            if not isinstance(t, torch.Tensor) or not t.is_floating_point():
                got = f"dtype {t.dtype}" if isinstance(t, torch.Tensor) else type(t).__name__
                raise TypeError(f"{name} must be a floating-point torch.Tensor, got {got}")
            if not bool(torch.isfinite(t).all()):
                raise ValueError(f"{name} must be finite, got {int((~torch.isfinite(t)).sum())} non-finite values")
        if centers.dim() != 2 or centers.shape[0] < 1 or centers.shape[1] < 1:
            raise ValueError(f"centers must have shape (M, d) with M, d >= 1, got {tuple(centers.shape)}")
        m, d = centers.shape
        if widths.shape != (m,):
            raise ValueError(f"widths must have shape ({m},), got {tuple(widths.shape)}")
        if not bool((widths >= MIN_WIDTH).all()):
            raise ValueError(f"widths must be >= {MIN_WIDTH:g} (scaled units), got min {widths.min().item():.3g}")
        if isinstance(out_features, bool) or not isinstance(out_features, int) or out_features < 1:
            raise ValueError(f"out_features={out_features!r} must be a positive integer")
        kw: dict[str, Any] = {"dtype": centers.dtype, "device": centers.device}
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
        self._expansion_cache: tuple | None = None  # see `_expansion`

    @property
    def rows_per_block(self) -> int:
        """Rows per block in eager calls and in the ONNX graph: `block_rows`, or about
        `block_elements` exponents (rows, M) a block."""
        return self.block_rows or max(1, self.block_elements // self.num_centers)

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
            if self.inputs is not None and self.inputs.redundancy:
                hint += (
                    ", then the redundant joint's value (the 8th column; IKSolver.solve takes it from "
                    "near= or redundancy=)"
                )
            raise ValueError(f"{name} must be {want}{hint}, got shape {tuple(x.shape)}")
        if x.dtype == torch.bool or x.is_complex():
            raise TypeError(f"{name} must be real numbers, got dtype {x.dtype}")
        if torch.compiler.is_compiling() or torch.compiler.is_exporting():
            return x  # data checks: eager only
        if self.inputs is not None and self.inputs.pose and not leading:
            self.inputs.check(x)  # unit quaternions, finite values
        elif x.is_floating_point() and not bool(x.sum().isfinite()):
            # A finite sum means every value is finite (NaN and inf propagate): one pass without a mask,
            # 15 against 445 us at B = 1e5. Only a non-finite sum (or one that overflowed) looks at rows.
            bad = ~torch.isfinite(x).all(-1)
            if bool(bad.any()):
                i = tuple(int(k) for k in bad.nonzero()[0])
                raise ValueError(f"{name} must be finite; row {i[0] if len(i) == 1 else i} is {x[i].tolist()}")
        return x

    def check_inputs(self, x) -> torch.Tensor:
        """`x` as a tensor (B, in_features), or a clear TypeError/ValueError naming what is wrong."""
        return self._inputs(x)

    def _feat(self, x: torch.Tensor, dtype: torch.dtype | None = None) -> torch.Tensor:
        """Features (..., d) of public inputs (..., in_features), in `dtype` (default the module's)."""
        x = x.to(dtype or self.centers.dtype)
        return x if self.inputs is None else self.inputs(x)

    def _blocks(self, fn: Callable, *xs: torch.Tensor):
        """fn applied to blocks of `rows_per_block` rows of xs and concatenated (one call when traced)."""
        if torch.compiler.is_compiling():
            return fn(*xs)
        return row_blocks(fn, self.rows_per_block, *xs)

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
        """Design rows (B, P) by `forward`'s matrix product (z = u + centroid)."""
        v, a, e = self._exponents(x)
        cols = [e.gaussians(a)]
        if self.tail is not None:
            cols.append(v[:, :-1] + e.centroid)
        return torch.cat([*cols, v[:, -1:]], -1)  # v's last column is the ones

    def output_weights(self) -> torch.Tensor:
        """Output weights W (P, out) ordered as `design`'s columns (a detached copy)."""
        parts = [self.head.weight.T]
        if self.tail is not None:
            parts.append(self.tail.weight.T)
        return torch.cat([*parts, self.head.bias[None]], 0).detach().clone()

    @torch.no_grad()
    def set_output_weights(self, w: torch.Tensor) -> None:
        """Set the head (and tail) from W (P, out) ordered as `design`'s columns."""
        p, m, out = self.num_design, self.num_centers, self.out_features
        if not isinstance(w, torch.Tensor):
            raise TypeError(f"output weights must be a torch.Tensor ({p}, {out}), got {type(w).__name__}")
        if tuple(w.shape) != (p, out):
            tail = f" + {self.centers.shape[1]} tail" if self.tail is not None else ""
            rows = f"{m} Gaussians{tail} + bias"
            raise ValueError(f"output weights must be ({p}, {out}) (rows: {rows}), got shape {tuple(w.shape)}")
        if not w.is_floating_point() or not bool(torch.isfinite(w).all()):
            raise ValueError(
                f"output weights must be finite floating-point numbers, got dtype {w.dtype} with "
                f"{int((~torch.isfinite(w)).sum()) if w.is_floating_point() else 0} non-finite values"
            )
        self.head.weight.copy_(w[:m].T)
        if self.tail is not None:
            self.tail.weight.copy_(w[m:-1].T)
        self.head.bias.copy_(w[-1])

    # ------------------------------------------------------------------------------ prediction
    def _expansion(self) -> Expansion:
        """The exponents' matrix form for the centres, widths and input scaling as they are now.

        Eager calls take base 2 (torch's exp2 is ~2.7x faster than exp on CPU) and reuse it while
        the buffers stay the same tensors, unmodified (identity, version counter and storage
        checked). Traced graphs compute it in the graph in base e: ONNX has Exp, not Exp2.
        """
        bufs = (self.centers, self.widths, self.offset, self.scale, self.cover_radius)
        if torch.compiler.is_compiling() or torch.compiler.is_exporting():
            return expand(*bufs, base2=False, fold=self.traced_cover_fold)

        def eager() -> Expansion:
            return expand(*bufs, base2=True, fold=cover_foldable(self.widths, self.cover_radius))

        if any(t.is_inference() or t.requires_grad for t in bufs):
            return eager()  # no version counter, or a graph to keep
        key = [(t._version, t.data_ptr()) for t in bufs]
        hit = self._expansion_cache
        if hit is None or any(a is not b for a, b in zip(hit[0], bufs)) or hit[1] != key:
            hit = self._expansion_cache = (bufs, key, eager())
        return hit[2]

    def _exponents(self, x: torch.Tensor, cover: bool = False) -> tuple[torch.Tensor, torch.Tensor, Expansion]:
        """[u, 1] (B, d + 1) and the Gaussian exponents (B, M), -||z - mu_i||^2 / (2 sigma_i^2) in
        the expansion's base, for public inputs x (B, in_features); and the expansion. With `cover`
        and a folded cover test, the exponents carry the cover shift (see the module docstring).
        Computed in EXPONENT_DTYPE from the inputs' features in it, returned in the module's dtype."""
        e = self._expansion()
        dtype = self.centers.dtype
        v = torch.addmm(e.in_bias, self._feat(x, EXPONENT_DTYPE), e.in_weight)  # (B, d + 1) float64
        weight = e.cover_weight if cover and e.cover_weight is not None else e.weight
        a = torch.cat([v, (v * v).sum(-1, keepdim=True)], -1) @ weight  # (B, M) float64 (v * v: square is slow in it)
        return v.to(dtype), a.to(dtype), e

    def _head(self, v: torch.Tensor, phi: torch.Tensor, e: Expansion, cover: bool = False) -> torch.Tensor:
        """Outputs (B, out) from [u, 1] (B, d + 1) and the activations phi (B, M) of
        `_exponents(x, cover)`'s exponents (cover-shifted ones: the head weights scaled back)."""
        w = self.head.weight * e.head_scale if cover and e.head_scale is not None else self.head.weight
        if self.tail is None:
            return torch.addmm(self.head.bias, phi, w.T)
        a = self.tail.weight  # A z = A u + A centroid
        linear = torch.cat([a.T, (a @ e.centroid + self.head.bias).unsqueeze(0)])
        return torch.addmm(v @ linear, phi, w.T)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Outputs y (B, out) for inputs x (B, d) (e.g. joints for positions in m):
        y = W h + A z + b, h_i = exp(-|z - mu_i|^2 / (2 sigma_i^2)), z = (x - offset) / scale.

        The plain path (`fast = False`) is that equation. The fast path (default) computes the same
        exponents as one matrix product (in float64) in row blocks (`_forward_rows`; see the module
        docstring): within 1e-12 of the plain path in float64, and in float32 both within 1e-5
        (rad, m) of float64 on networks fitted by the float32 rule (tested), with exp2 and no
        (B, M, d) differences. Training, evaluation and the exports take the fast path."""
        x = self._inputs(x)
        return self._blocks(self._forward_rows if self.fast else self._plain_rows, x)

    def _plain_rows(self, x: torch.Tensor) -> torch.Tensor:
        """`forward`'s plain equation on rows (B, d) in one piece (it holds (B, M, d) differences)."""
        z = self._scaled(x)  # (B, d)
        h = gaussian_features(z, self.centers, self.widths)  # (B, M)
        y = self.head(h)  # W h + b (B, out)
        return y if self.tail is None else y + self.tail(z)  # + A z

    def _forward_rows(self, x: torch.Tensor) -> torch.Tensor:
        """`forward` on rows (B, d) in one piece (no blocks, no checks): the exported graph's path."""
        v, a, e = self._exponents(x)
        return self._head(v, e.gaussians(a), e)

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
            raise ValueError(
                f"outputs y must be ({x.shape[0]}, {self.out_features}) for {x.shape[0]} inputs, got {got}"
            )
        if y.dtype == torch.bool or y.is_complex():
            raise TypeError(f"outputs y must be real numbers, got dtype {y.dtype}")
        y = y.to(self.centers.dtype)  # compared in the module's dtype, as its own outputs are

        def rows(xb: torch.Tensor, yb: torch.Tensor) -> torch.Tensor:
            _, a, e = self._exponents(xb, cover=True)
            return self._mask(xb, self._covered(a, e), yb)

        return self._blocks(rows, x, y)

    def solve(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(outputs (B, out), in-workspace mask (B,)) for inputs x (B, d)."""
        return self._blocks(self._solve_rows, self._inputs(x))

    def for_export(self) -> RBFNetwork:
        """A frozen float32 copy in eval mode for the exporters (torch.export, ONNX: `rbfn.export`),
        whose `solve_rows` is then the graph. The cover test's folding is decided here, by the
        eager check (`cover_foldable`) that a traced graph cannot take."""
        net = copy.deepcopy(self).float().eval().requires_grad_(False)
        net.traced_cover_fold = cover_foldable(net.widths, net.cover_radius)
        return net

    def solve_rows(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`solve` for inputs x (B, d) in one piece: the exported graph's path (`rbfn.export`).
        No blocks (one graph for any B), and the inputs' data checks only in eager mode (shape
        and dtype are checked always)."""
        return self._solve_rows(self._inputs(x))

    def _solve_rows(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`solve` on rows (B, d) in one piece, the exponents computed once for the features and
        the mask (no blocks, no checks): the exported graph's path."""
        v, a, e = self._exponents(x, cover=True)
        covered = self._covered(a, e)  # before the activations overwrite the exponents
        y = self._head(v, e.gaussians(a), e, cover=True)
        return y, self._mask(x, covered, y)

    def _covered(self, a: torch.Tensor, e: Expansion) -> torch.Tensor:
        """Rows (B,) with some centre within the cover radius, from `_exponents(..., cover=True)`'s
        exponents a (B, M): a shifted exponent >= 0 where the test is folded, else the nearest
        centre's squared distance."""
        if e.cover_weight is not None:
            return a.amax(-1) >= 0
        return (a * e.to_sq_dist).amin(-1).clamp(min=0.0).sqrt() <= self.cover_radius

    def _mask(self, x: torch.Tensor, covered: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """In-workspace mask (B,) from inputs (B, d), the cover test (B,) and outputs (B, out)."""
        ok = _within(self._feat(x), self.in_low, self.in_high) & covered
        return ok & _within(y, self.out_low, self.out_high)

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


def assemble(
    centers: torch.Tensor,
    widths: torch.Tensor,
    weights: torch.Tensor,
    offset: torch.Tensor,
    scale: torch.Tensor,
    tail: bool,
    inputs: TargetFeatures | None = None,
) -> RBFNetwork:
    """An RBFNetwork from fitted parts; weights (P, out) ordered as `RBFNetwork.design`'s columns,
    which are rbfn.fit.design_matrix's. Without the tail, weights may also be (M, out) (design_matrix
    has no bias column then): the bias is zero."""
    m = centers.shape[0]
    net = RBFNetwork(
        centers,
        widths,
        weights.shape[-1],
        offset=offset,
        scale=scale,
        tail=tail,
        inputs=None if inputs is None or not inputs.pose else inputs.to(centers.dtype),
    )
    if not tail and weights.dim() == 2 and weights.shape[0] == m:
        weights = torch.cat([weights, weights.new_zeros(1, weights.shape[1])])
    net.set_output_weights(weights.to(net.centers.dtype))
    return net
