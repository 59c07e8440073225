import math

import pytest
import torch

from rbfn.fit import DEFAULT_RIDGES, design_matrix, ridge_fit, ridge_solve
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


@pytest.mark.parametrize("tail", [True, False])
def test_design_matrix_is_the_layers_gaussians_then_tail_and_bias(tail):
    """design_matrix's Gaussians (squared distances by one matmul) are rbfn.layer.gaussian_features
    (broadcast distances) to 1e-12 in float64, batched over ants; then z and the ones column."""
    from rbfn.layer import gaussian_features

    z, c, w, _true = _problem(4)
    cs, ws = torch.stack([c, c + 0.1]), torch.stack([w, w * 2])
    a = design_matrix(z, cs, ws, tail)
    assert a.shape == (2, 400, 12 + 3 * tail)
    assert (a[..., :12] - gaussian_features(z, cs, ws)).abs().max() < 1e-12
    if tail:
        assert torch.equal(a[..., 12:14], z.expand(2, -1, -1)) and torch.equal(a[..., 14], torch.ones(2, 400).double())


def test_ridge_fit_batched_over_ants_matches_single():
    z, c, w, _true = _problem(1)
    cs = torch.stack([c, c + 0.1, c - 0.2])
    ws = w.expand(3, -1)
    y = torch.sin(3 * z)
    batch = ridge_fit(design_matrix(z[:300], cs, ws), y[:300], design_matrix(z[300:], cs, ws), y[300:])
    for k in range(3):
        one = ridge_fit(design_matrix(z[:300], cs[k], ws[k]), y[:300], design_matrix(z[300:], cs[k], ws[k]), y[300:])
        assert torch.isclose(batch.val_mse[k], one.val_mse, rtol=1e-9)


def test_ridge_solve_matches_ridge_fit_weights():
    z, c, w, _true = _problem(2)
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


def _op_order_difference(net, x: torch.Tensor) -> float:
    """Max |output| difference (in-workspace rows) between the float32 module and the same network
    in float32 with |z|^2 + |c|^2 - 2 z.c distances and the head summed in reversed column order."""
    n32 = net.float()
    x = x.float()
    with torch.no_grad():
        y, inside = n32.solve(x)
        z = n32.scaled(x)
        d2 = (z.square().sum(-1, keepdim=True) + n32.centers.square().sum(-1) - 2 * z @ n32.centers.T).clamp_min(0)
        a = torch.cat([torch.exp(-d2 / (2 * n32.widths.square())), z, torch.ones_like(z[:, :1])], 1)
        y2 = a.flip(1) @ n32.output_weights().flip(0)
    net.double()
    assert inside.float().mean() > 0.9
    return float((y2 - y)[inside].abs().max())


def test_float32_fit_is_stable_under_any_op_order(small_data):
    """Wide Gaussians fit best with large cancelling weights, whose float32 output depends on the
    order of operations; the fit for a float32 deployment keeps that difference below 1e-5 rad."""
    from rbfn.centers import kmeans_centers
    from rbfn.data import input_scaling
    from rbfn.fit import deployed_design
    from rbfn.layer import assemble
    from rbfn.robots import scara

    tr, val = small_data.train, small_data.val
    off, sc = input_scaling(tr.x, "metres")
    c = kmeans_centers((tr.x - off) / sc, 30, seed=0, restarts=2)
    w = torch.full((30,), 1.5, dtype=torch.float64)
    a_tr, a_val = design_matrix((tr.x - off) / sc, c, w), design_matrix((val.x - off) / sc, c, w)
    g = torch.Generator().manual_seed(11)
    low = torch.tensor([0.0, 0.3, 0.5], dtype=torch.float64)
    high = torch.tensor([2.0, 2.0, 1.5], dtype=torch.float64)
    x = scara.fk(low + torch.rand(3000, 3, generator=g, dtype=torch.float64) * (high - low))

    def network(fit):
        net = assemble(c, w, fit.weights, off, sc, tail=True)
        net.set_domain(tr.x, tr.q)
        return net

    # Chosen on float64 validation error alone: large weights, op order matters at 1e-4 rad.
    loose = ridge_fit(a_tr, tr.q, a_val, val.q)
    assert _op_order_difference(network(loose), x) > 1e-4
    # Chosen for float32 (as training does): stable on validation rows, hence on fresh positions.
    a_val32 = deployed_design(val.x, off, sc, c, w, True, torch.float32)
    fit = ridge_fit(a_tr, tr.q, a_val, val.q, a_val_eval=a_val32)
    assert _op_order_difference(network(fit), x) < 1e-5
    from rbfn.fit import ROUND_TOL

    assert loose.rounding is None and fit.rounding <= ROUND_TOL and fit.ridge > loose.ridge
    assert torch.equal(ridge_fit(a_tr, tr.q, a_val, val.q, eval_dtype=torch.float32).ridge, fit.ridge)
    # No smaller ridge would have been stable: the constraint costs no more accuracy than needed.
    smaller = tuple(r for r in DEFAULT_RIDGES if r < float(fit.ridge))
    assert ridge_fit(a_tr, tr.q, a_val, val.q, smaller, a_val_eval=a_val32).rounding > ROUND_TOL


def test_rounding_constraint_batched_over_ants():
    from rbfn.fit import rounding_scale

    z, c, w, _true = _problem(3, n=500, m=16)
    cs = torch.stack([c, c * 0.9, c + 0.05])
    ws = torch.stack([w * 2.5, w * 3.0, w])
    y = torch.sin(3 * z)
    tol = 1e-6
    a_tr, a_val = design_matrix(z[:350], cs, ws), design_matrix(z[350:], cs, ws)
    batch = ridge_fit(a_tr, y[:350], a_val, y[350:], eval_dtype=torch.float32, round_tol=tol)
    assert batch.weights.shape == (3, 16 + 3, 2) and batch.rounding.shape == (3,)
    for k in range(3):
        one = ridge_fit(a_tr[k], y[:350], a_val[k], y[350:], eval_dtype=torch.float32, round_tol=tol)
        assert torch.isclose(batch.ridge[k], one.ridge, rtol=1e-12)
        assert torch.allclose(batch.weights[k], one.weights, rtol=1e-8, atol=1e-10)
        bound = rounding_scale(a_val[k], batch.weights[k], torch.float32).amax()
        assert torch.isclose(bound, batch.rounding[k]) and bound <= tol
        # Without the constraint the same ant would pick a smaller ridge with larger weights.
        free = ridge_fit(a_tr[k], y[:350], a_val[k], y[350:])
        assert free.ridge <= one.ridge and free.val_mse <= one.val_mse * (1 + 1e-12)


def test_relative_rounding_bound_follows_the_fit_error():
    """round_rel lets the bound grow to a fraction of the best fit's validation RMS error per
    output: it is met, it lets a smaller ridge in, and 0 is the absolute rule alone. The objective
    batched over ants chooses the same."""
    from rbfn.fit import rounding_scale, rounding_tolerance
    from rbfn.objectives import FitObjective

    z, c, w, _true = _problem(3, n=500, m=16)
    y = torch.sin(3 * z)
    a_tr, a_val = design_matrix(z[:350], c, w * 2.5), design_matrix(z[350:], c, w * 2.5)
    absolute = ridge_fit(a_tr, y[:350], a_val, y[350:], eval_dtype=torch.float32, round_tol=1e-7)
    assert torch.equal(
        ridge_fit(a_tr, y[:350], a_val, y[350:], eval_dtype=torch.float32, round_tol=1e-7, round_rel=0.0).ridge,
        absolute.ridge,
    )
    free = ridge_fit(a_tr, y[:350], a_val, y[350:])
    rel = 1e-3
    tol = float(rounding_tolerance(free.val_mse[None], 2, 1e-7, rel))
    assert tol == pytest.approx(rel * math.sqrt(float(free.val_mse) / 2), rel=1e-9) and tol > 1e-7
    relative = ridge_fit(a_tr, y[:350], a_val, y[350:], eval_dtype=torch.float32, round_tol=1e-7, round_rel=rel)
    assert relative.rounding <= tol < rounding_scale(a_val, free.weights, torch.float32).amax()
    assert relative.ridge < absolute.ridge and relative.val_mse < absolute.val_mse
    obj = FitObjective(z[:350], y[:350], z[350:], y[350:], eval_dtype=torch.float32, round_tol=1e-7, round_rel=rel)
    assert torch.allclose(obj(c[None], (w * 2.5)[None]), relative.val_mse[None], rtol=1e-4)
    # (float32 predictions summed in another order: at this ridge they differ by about round_rel)


def test_no_stable_ridge_keeps_the_most_stable():
    z, c, w, _true = _problem(4)
    a = design_matrix(z, c, w * 3)
    y = torch.sin(3 * z)
    fit = ridge_fit(
        a[:300], y[:300], a[300:], y[300:], ridges=(1e-12, 1e-8, 1e-4), eval_dtype=torch.float32, round_tol=0.0
    )
    assert float(fit.ridge) == 1e-4 and fit.rounding > 0


@pytest.mark.parametrize("gain, expected", [(1.005, 10**-2.25), (1.009, 1e-2)])
def test_binding_constraint_refines_between_the_grid_ridges(gain, expected):
    """One weight w = gain / (1 + ridge) (a 1 x 1 problem), its error falling and its rounding scale
    rising with |w|: the stable ridges are those >= gain - 1. Where the grid's best stable ridge
    (1e-2) has an unstable, better neighbour (1e-3), the three ridges between them are tried and
    the best stable one kept; where none of them is stable, the grid's."""
    from rbfn.fit import ridge_choose

    def score(weights):
        w = weights[..., 0, 0].abs()
        return 2.0 - w, w  # (mse, rounding scale), each (..., L)

    gram = torch.ones(1, 1, dtype=torch.float64)
    fit = ridge_choose(gram, gain * gram, score, ridges=(1e-4, 1e-3, 1e-2), deploy=torch.float32, round_tol=1.0)
    assert math.isclose(float(fit.ridge), expected, rel_tol=1e-9)
    assert math.isclose(float(fit.weights[0, 0]), gain / (1 + expected), rel_tol=1e-12)
    assert math.isclose(float(fit.val_mse), 2.0 - gain / (1 + expected), rel_tol=1e-12) and float(fit.rounding) <= 1.0
