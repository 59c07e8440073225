"""The Gaussian, written once, and the faster forms of it beside it.

The reference (`gaussian_features`): h_i(z) = exp(-|z - mu_i|^2 / (2 sigma_i^2)) of scaled inputs
z (..., N, d) about centres mu (..., M, d) with widths sigma (..., M), by broadcast squared
distances (`sq_distances`, `gaussian`): the paper's features, accurate in float32, exportable.

Four places need the same numbers faster, each in a form of its own, each tested against the
reference (tests/test_gaussians.py) and each keeping its own order of operations, which what it
feeds depends on bit for bit:

- `gaussian_matrix`: fitting's design matrix (`rbfn.fit.design_matrix`), squared distances as
  |z|^2 + |mu|^2 - 2 z.mu (one product, clamped at 0) in float64, the Gaussian in place;
- `exponent_coefficients` / `gaussians_from_exponents`: the colony's objective
  (`rbfn.objectives`), every ant's exponents as one product with `distance_rows`, in base 2;
- `gaussian_product`: refinement (`rbfn.refine`), phi(z) @ w with a backward that keeps no
  (B, M) temporaries beyond phi;
- `expand` / `Expansion`: the network's fast path (`rbfn.layer.RBFNetwork`: `forward`, `solve`,
  `in_workspace`, `design`, and the exported graph), below.

The network's fast path takes all exponents in one matrix product: with u = z - (the centres'
centroid) and v = [u, 1], -||z - mu_i||^2 / (2 sigma_i^2) = [v, |v|^2] @ K_i, K from the centres
and widths (|v|^2 = |u|^2 + 1), in base 2 in eager calls (exp2 is faster than exp on CPU). `solve`
also folds the workspace flag's cover test into that product: it adds s_i = r^2 / (2 sigma_i^2) to
exponent i, so that "some centre lies within the cover radius r" reads max_i (exponent_i + s_i) >=
0, and scales head weight i by exp(-s_i), so the outputs are the same (where every s_i <=
MAX_COVER_SHIFT, so that nothing overflows float32; otherwise the squared distances are taken).

The expansion cancels: its terms are of size (|u|^2 + |mu_i - centroid|^2) / (2 sigma_i^2), the
exponent far smaller where a Gaussian is narrow beside its distance from the centroid (the `full`
refinement makes such Gaussians), and a float32 product loses 2^-24 times that size, an error that
depends on the product's order of operations (ONNX Runtime's against torch's). So v and the
product are taken in float64 whatever the module's dtype (`EXPONENT_DTYPE`), and the exponents are
cast to the module's dtype once, before exp2 / exp and the head: a float32 module then rounds only
the Gaussians and the head (the float32 rule's scale, `rbfn.fit.ROUND_TOL`), whatever the order,
and its exports agree with it within 1e-5 (docs/concepts.md, "Weights: the float32 rule"). It
needs a device with float64 (CPU, CUDA). In float64 the fast and plain paths agree to about 1e-12.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import torch

__all__ = [
    "LOG2E",
    "MIN_WIDTH",
    "EXPONENT_DTYPE",
    "MAX_COVER_SHIFT",
    "sq_distances",
    "gaussian",
    "gaussian_features",
    "distance_rows",
    "gaussian_matrix",
    "exponent_coefficients",
    "gaussians_from_exponents",
    "gaussian_product",
    "Expansion",
    "expand",
    "cover_foldable",
]

MIN_WIDTH = 1e-12
"""Smallest Gaussian width sigma (scaled input units, those of z = (x - offset) / scale) a network
or checkpoint may hold. Below it exp(-d^2 / (2 sigma^2)) underflows to 0 in float64 for every input
farther than 4e-11 from the centre (d^2 / (2 sigma^2) > 745), far inside the 6e-8 resolution of
float32 inputs of order 1, so the Gaussian answers 0 everywhere but at its centre (and far enough
below, 1 / (2 sigma^2) overflows float32 and the network returns NaN). Training never makes one:
the smallest width it gives is rbfn.widths' floor 1e-9 times the smallest scale tried, 0.25."""


LOG2E = math.log2(math.e)
"""log2(e): an exponent in base e times LOG2E is the same exponent in base 2, exp(t) = exp2(t LOG2E)
(the fast forms here, in the colony's objective and in refinement take exp2, faster than exp on CPU)."""


def sq_distances(z: torch.Tensor, centers: torch.Tensor) -> torch.Tensor:
    """Squared distances |z - mu|^2 (..., N, M) of inputs z (..., N, d) to centres (..., M, d), by
    broadcasting (accurate in float32, exportable)."""
    return (z.unsqueeze(-2) - centers.unsqueeze(-3)).square().sum(-1)


def gaussian(d2: torch.Tensor, widths: torch.Tensor, inplace: bool = False) -> torch.Tensor:
    """The Gaussian exp(-d2 / (2 sigma^2)) (..., N, M) of squared distances d2 (..., N, M) to
    centres of widths sigma (..., M) (scaled units, those of z). With `inplace`, computed in d2's
    storage (fitting's (N, M) float64 matrices: no temporaries of that size).

    Written d2 / (-2 sigma^2): in IEEE arithmetic x / (-y) = -(x / y) exactly, so this is
    bit for bit -d2 / (2 sigma^2)."""
    two_var = widths.unsqueeze(-2).square() * -2.0  # -2 sigma^2 (..., 1, M)
    return d2.div_(two_var).exp_() if inplace else (d2 / two_var).exp_()


def gaussian_features(z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """Gaussian activations h (..., N, M) = exp(-|z - mu|^2 / (2 sigma^2)) of inputs z (..., N, d),
    centres mu (..., M, d), widths sigma (..., M): the paper's features, the reference for every
    faster form."""
    return gaussian(sq_distances(z, centers), widths)


def distance_rows(z: torch.Tensor) -> torch.Tensor:
    """[z, |z|^2, 1] (N, d + 2) of inputs z (N, d): times a centre's column [-2 mu, 1, |mu|^2] it is
    |z|^2 + |mu|^2 - 2 z.mu = |z - mu|^2, so every squared distance (scaled by any per-centre
    factor: an exponent) is one matrix product. Exact enough in float64 (where the colony's
    objective and refinement use it); cancellation costs float32 more than `sq_distances`."""
    return torch.cat([z, z.square().sum(-1, keepdim=True), torch.ones_like(z[:, :1])], 1)


def gaussian_matrix(z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """Gaussians (..., N, M) of z (..., N, d) about centres (..., M, d), widths (..., M), as fitting
    takes them (`rbfn.fit.design_matrix`): squared distances as |z|^2 + |c|^2 - 2 z.c (one matmul,
    clamped at 0) instead of by broadcasting, no (..., N, M, d) differences, exact enough in
    float64, the precision fitting runs in; then `gaussian` in place on that one buffer."""
    d2 = (z @ centers.transpose(-1, -2)).mul_(-2.0)
    d2.add_(z.square().sum(-1, keepdim=True)).add_(centers.square().sum(-1).unsqueeze(-2))
    return gaussian(d2.clamp_(min=0.0), widths, inplace=True)


# --------------------------------------------- the network's fast path: exponents by one product
class Expansion(NamedTuple):
    """Gaussian exponents of features x (B, d) as matrix products, in base 2 (eager) or e (traced):
    v = [u, 1] = x @ in_weight + in_bias with u = z - centroid, then [v, |v|^2] @ weight, both in
    EXPONENT_DTYPE (float64). The fast path's form of `gaussian_features` (this module's
    docstring), tested against the plain path; it keeps its own rounding order, which the trained
    metrics and the exports carry."""

    centroid: torch.Tensor  # (d,) the centres' mean, the origin of u (the module's dtype)
    in_weight: torch.Tensor  # (d, d + 1): [diag(1 / scale), 0] (float64, as are the weights below)
    in_bias: torch.Tensor  # (d + 1,): [-offset / scale - centroid, 1]
    weight: torch.Tensor  # (d + 2, M): rows mu_i' / sigma_i^2, (1 - |mu_i'|^2) / (2 sigma_i^2) and
    # -1 / (2 sigma_i^2), times log_base(e), mu_i' = mu_i - centroid
    to_sq_dist: torch.Tensor  # (M,): exponents -> squared distances (-2 sigma_i^2 ln(base)), module dtype
    gaussians: Callable[[torch.Tensor], torch.Tensor]  # exponents -> activations (eager: in place)
    cover_weight: torch.Tensor | None  # (d + 2, M): weight with the cover shift s_i (base units) added
    # to the constant row; None where the cover test is not folded
    head_scale: torch.Tensor | None  # (M,): base^-s_i, the head weights' factor for cover_weight's exponents
    # (module dtype)


EXPONENT_DTYPE = torch.float64
"""The dtype of the fast path's input transform and exponent product whatever the module's own
(the module docstring): the exponents are cast to the module's dtype after the product."""

MAX_COVER_SHIFT = 60.0  # largest cover shift s_i folded (natural units): e^60 and e^-60 are normal float32


def cover_foldable(widths: torch.Tensor, cover_radius: torch.Tensor) -> bool:
    """Whether `solve` folds the cover test into the exponents: a finite cover radius with every
    shift r^2 / (2 sigma_i^2) <= MAX_COVER_SHIFT (an eager check; `RBFNetwork.for_export` records it)."""
    r = float(cover_radius)
    return math.isfinite(r) and r * r * 0.5 / float(widths.min()) ** 2 <= MAX_COVER_SHIFT


def expand(
    centers: torch.Tensor,
    widths: torch.Tensor,
    offset: torch.Tensor,
    scale: torch.Tensor,
    cover_radius: torch.Tensor,
    base2: bool,
    fold: bool,
) -> Expansion:
    """The exponents' matrix form for centres (M, d), widths (M,), the input scaling (d,) and,
    with `fold`, the cover radius (0-dim): the products' factors in float64 whatever the buffers'
    dtype (this module's docstring), what multiplies the float32 exponents and head in theirs."""
    dtype = centers.dtype
    centers, widths, offset, scale, cover_radius = (
        t.to(EXPONENT_DTYPE) for t in (centers, widths, offset, scale, cover_radius)
    )
    centroid = centers.mean(0)
    mu = centers - centroid
    log_e = LOG2E if base2 else 1.0
    inv = log_e / widths.square()  # log_base(e) / sigma^2
    weight = torch.stack([*(mu.T * inv), 0.5 * (1.0 - mu.square().sum(-1)) * inv, -0.5 * inv])
    in_weight = torch.cat([torch.diag(1.0 / scale), torch.zeros_like(scale)[:, None]], 1)
    in_bias = torch.cat([-offset / scale - centroid, torch.ones_like(scale[:1])])
    cover_weight = head_scale = None
    if fold:
        shift = 0.5 * cover_radius.square() * inv  # (M,) in base units
        d = centers.shape[1]
        cover_weight = torch.cat([weight[:d], (weight[d] + shift)[None], weight[d + 1 :]])
        head_scale = (torch.exp2(-shift) if base2 else torch.exp(-shift)).to(dtype)
    return Expansion(
        centroid.to(dtype),
        in_weight,
        in_bias,
        weight,
        (-2.0 / log_e * widths.square()).to(dtype),
        torch.Tensor.exp2_ if base2 else torch.exp,
        cover_weight,
        head_scale,
    )


# --------------------------------------------------------------- the colony's form (rbfn.objectives)
def exponent_coefficients(centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """[-2 mu, 1, |mu|^2] / (-2 sigma^2 ln 2) (K, M, d + 2) of ants' centres (K, M, d) and widths
    (K, M): times `rbfn.objectives`' exponent rows (d + 2, N), the Gaussians' exponents in base 2,
    -|z - mu|^2 / (2 sigma^2 ln 2) (K, M, N)."""
    s2 = widths.square().unsqueeze(-1) * (-2.0 / LOG2E)  # -2 sigma^2 ln 2 (K, M, 1)
    return torch.cat([centers * (-2.0 / s2), 1.0 / s2, centers.square().sum(-1, keepdim=True) / s2], -1)


def gaussians_from_exponents(coef: torch.Tensor, rows: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
    """Gaussians (K, M, B) of ants' exponent coefficients (K, M, d + 2) on rows (d + 2, B), by
    exp2 of their product (clamped at 0, which rounding may pass); into `out` where given, the
    exponents computed in the coefficients' dtype and exponentiated in out's (as a deployed
    network of that dtype does; float32's exp2 from float64 exponents is ~2x faster again)."""
    if out is None:
        return (coef @ rows).clamp_(max=0.0).exp2_()
    return out.copy_(coef @ rows).clamp_(max=0.0).exp2_()  # rounded, then clamped in out's dtype


# -------------------------------------------------------------- refinement's form (rbfn.refine)
class _GaussianProduct(torch.autograd.Function):
    """phi(z) @ w (B, out) for Gaussians phi (B, M) = exp(-|z - c|^2 / (2 s^2)), with a backward
    that needs no (B, M) temporaries beyond phi and one product.

    The Gaussians are `rbfn.layer.gaussian_features` (within 1e-13 in float64, tested) in another
    form, fused for speed: autograd through `design_matrix` keeps about ten (B, M) intermediates
    and walks each in the backward; here the exponent is one product of `rbfn.layer.distance_rows`
    [z, |z|^2, 1] (B, d + 2) with per-centre coefficients, in base 2 (exp2), and the gradients of
    c, s and z are products of h = (dL/dphi) * phi with [z, |z|^2, 1] and [a, a c]
    (a = 1 / (2 s^2)). Every product is written with its long side last: on a CPU the
    (M, out)-shaped ones (phi^T G) took 5-7x as long as their transposes. Its coefficients keep
    their own rounding order (not the colony's, `rbfn.objectives`): the refined networks depend on
    its bits.
    """

    @staticmethod
    def forward(ctx, z: torch.Tensor, c: torch.Tensor, s: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        a = 0.5 / s.square()  # (M,)
        rows = distance_rows(z)  # (B, d + 2)
        coef = torch.cat([2.0 * c, -torch.ones_like(a)[:, None], -c.square().sum(-1, keepdim=True)], 1)
        coef = coef * (a * LOG2E)[:, None]  # exponent in base 2
        phi = torch.exp2((rows @ coef.T).clamp_(max=0.0))  # (B, M)
        ctx.save_for_backward(rows, c, s, w, a, phi)
        return (w.T @ phi.T).T

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        rows, c, s, w, a, phi = ctx.saved_tensors
        d = c.shape[1]
        grad_w = (grad.T @ phi).T if ctx.needs_input_grad[3] else None
        h = (grad @ w.T).mul_(phi)  # (B, M)
        q = (rows.T @ h).T  # (M, d + 2)
        hz, hzz, hs = q[:, :d], q[:, d], q[:, d + 1]  # h^T z, h^T |z|^2, sum h
        grad_c = 2.0 * a[:, None] * (hz - c * hs[:, None])
        hd = hzz + c.square().sum(-1) * hs - 2.0 * (hz * c).sum(-1)  # sum_b h_bj |z_b - c_j|^2
        grad_s = hd / s.pow(3)
        grad_z = None
        if ctx.needs_input_grad[0]:
            r = (torch.cat([a[:, None], a[:, None] * c], 1).T @ h.T).T  # (B, 1 + d)
            grad_z = 2.0 * (r[:, 1:] - rows[:, :d] * r[:, :1])
        return grad_z, grad_c, grad_s, grad_w


def gaussian_product(
    z: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor, weights: torch.Tensor
) -> torch.Tensor:
    """phi(z) @ weights (B, out): Gaussians of z (B, d) about centres (M, d) with widths (M,),
    times weights (M, out); differentiable in all four at the cost of a few products."""
    return _GaussianProduct.apply(z, centers, widths, weights)
