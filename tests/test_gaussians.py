"""The Gaussian's faster forms against the reference `gaussian_features` (broadcast distances)."""

import math

import torch

from rbfn.gaussians import (
    LOG2E,
    distance_rows,
    expand,
    exponent_coefficients,
    gaussian_features,
    gaussian_matrix,
    gaussian_product,
    gaussians_from_exponents,
)


def _problem(seed=3, k=5, m=30, n=700, d=3):
    g = torch.Generator().manual_seed(seed)
    z = torch.rand(n, d, generator=g, dtype=torch.float64) * 2 - 1
    c = torch.rand(k, m, d, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.rand(k, m, generator=g, dtype=torch.float64) * 0.6 + 0.2
    return z, c, w


def test_fittings_matrix_is_the_reference_batched_over_ants():
    z, c, w = _problem()
    assert (gaussian_matrix(z, c, w) - gaussian_features(z, c, w)).abs().max() < 1e-12


def test_the_colonys_base_2_gaussians_are_the_reference():
    """Every ant's Gaussians by one product of the data's rows with its coefficients, to 1e-12 in
    float64, and in float32 where exponentiated there."""
    z, c, w = _problem()
    coef, rows = exponent_coefficients(c, w), distance_rows(z).T
    want = gaussian_features(z, c, w).transpose(-1, -2)  # (K, M, N)
    assert (gaussians_from_exponents(coef, rows) - want).abs().max() < 1e-12
    out = torch.empty(want.shape, dtype=torch.float32)
    assert (gaussians_from_exponents(coef, rows, out=out).double() - want).abs().max() < 1e-6


def test_refinements_product_is_the_reference_and_its_gradients_are_exact():
    g = torch.Generator().manual_seed(1)
    z = torch.randn(30, 4, dtype=torch.float64, generator=g).requires_grad_(True)
    c = torch.randn(6, 4, dtype=torch.float64, generator=g).requires_grad_(True)
    s = (torch.rand(6, dtype=torch.float64, generator=g) + 0.5).requires_grad_(True)
    w = torch.randn(6, 3, dtype=torch.float64, generator=g).requires_grad_(True)
    ref = gaussian_features(z, c, s) @ w
    assert torch.allclose(gaussian_product(z, c, s, w), ref, atol=1e-13)
    assert torch.autograd.gradcheck(gaussian_product, (z, c, s, w))
    # Without the input's gradient (fixed input scales) the others are unchanged.
    grads = torch.autograd.grad(gaussian_product(z.detach(), c, s, w).sin().sum(), (c, s, w))
    want = torch.autograd.grad((gaussian_features(z.detach(), c, s) @ w).sin().sum(), (c, s, w))
    assert all(torch.allclose(a, b, atol=1e-12) for a, b in zip(grads, want))


def test_the_networks_expansion_is_the_reference():
    """The fast path's exponents, [v, |v|^2] @ weight with v = [x @ in_weight + in_bias], are the
    reference's in base 2 (eager) and base e (traced), the input scaling included."""
    z, c, w = _problem(k=1)
    c, w = c[0], w[0]
    offset, scale = torch.tensor([0.1, -0.2, 0.3]).double(), torch.tensor([2.0, 0.5, 1.5]).double()
    x = z * scale + offset  # raw inputs whose scaled form is z
    want = gaussian_features(z, c, w)
    for base2 in (True, False):
        e = expand(c, w, offset, scale, torch.tensor(float("inf")).double(), base2, fold=False)
        v = x @ e.in_weight + e.in_bias
        exponents = torch.cat([v, v.square().sum(-1, keepdim=True)], -1) @ e.weight
        got = torch.exp2(exponents) if base2 else torch.exp(exponents)
        assert (got - want).abs().max() < 1e-12
        d2 = exponents * e.to_sq_dist  # back to squared distances
        assert (d2 - torch.cdist(z, c).square()).abs().max() < 1e-10
    assert abs(LOG2E * math.log(2.0) - 1.0) < 1e-15
