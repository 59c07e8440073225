import torch

from rbfn.fit import design_matrix, ridge_fit, ridge_solve
from rbfn.lms import lms_fit


def _problem(seed=0, n=400, m=12):
    g = torch.Generator().manual_seed(seed)
    z = torch.rand(n, 2, generator=g, dtype=torch.float64) * 2 - 1
    c = torch.rand(m, 2, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.full((m,), 0.6, dtype=torch.float64)
    true = torch.randn(m + 3, 2, generator=g, dtype=torch.float64)
    return z, c, w, true


def test_least_squares_exact_on_representable_problem():
    z, c, w, true = _problem()
    a = design_matrix(z, c, w)
    y = a @ true
    fit = ridge_fit(a[:300], y[:300], a[300:], y[300:])
    assert fit.val_mse < 1e-12
    assert torch.allclose(a @ fit.weights, y, atol=1e-6)


def test_ridge_fit_batched_over_ants_matches_single():
    z, c, w, true = _problem(1)
    cs = torch.stack([c, c + 0.1, c - 0.2])
    ws = w.expand(3, -1)
    y = torch.sin(3 * z)
    batch = ridge_fit(design_matrix(z[:300], cs, ws), y[:300], design_matrix(z[300:], cs, ws), y[300:])
    for k in range(3):
        one = ridge_fit(design_matrix(z[:300], cs[k], ws[k]), y[:300], design_matrix(z[300:], cs[k], ws[k]), y[300:])
        assert torch.isclose(batch.val_mse[k], one.val_mse, rtol=1e-9)


def test_ridge_solve_matches_ridge_fit_weights():
    z, c, w, true = _problem(2)
    a = design_matrix(z, c, w)
    y = torch.cos(2 * z)
    fit = ridge_fit(a, y, a, y, ridges=(1e-6,))
    assert torch.allclose(ridge_solve(a, y, 1e-6), fit.weights, atol=1e-8)


def test_lms_converges_to_least_squares_on_well_conditioned_basis():
    g = torch.Generator().manual_seed(0)
    a = torch.randn(500, 5, generator=g, dtype=torch.float64)
    true = torch.randn(5, 2, generator=g, dtype=torch.float64)
    w = lms_fit(a, a @ true, alpha0=0.5, epochs=60, generator=g)
    assert torch.allclose(w, true, atol=1e-4)
