import copy

import pytest
import torch

from rbfn.layer import RBFNetwork, assemble, gaussian, gaussian_features, sq_distances


def test_shapes_and_scaling():
    c = torch.randn(7, 3, dtype=torch.float64)
    net = RBFNetwork(
        c,
        torch.ones(7, dtype=torch.float64),
        2,
        offset=torch.tensor([1.0, 2.0, 3.0]),
        scale=torch.tensor([2.0, 2.0, 2.0]),
    )
    x = torch.randn(5, 3, dtype=torch.float64)
    assert net(x).shape == (5, 2)
    assert net.features(x).shape == (5, 7)
    z = (x - torch.tensor([1.0, 2.0, 3.0])) / 2.0
    assert torch.allclose(net.scaled(x), z)
    # A centre placed exactly at a scaled input gives activation 1.
    net.centers[0] = z[0]
    assert torch.isclose(net.features(x)[0, 0], torch.tensor(1.0, dtype=torch.float64))


def test_gaussian_value():
    z = torch.tensor([[0.0, 0.0]])
    phi = gaussian_features(z, torch.tensor([[1.0, 0.0]]), torch.tensor([2.0]))
    assert torch.isclose(phi, torch.exp(torch.tensor(-1.0 / 8.0))).all()


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_gaussian_is_the_equation_bit_for_bit_in_place_or_not(dtype):
    """gaussian's d2 / (-2 sigma^2) is -d2 / (2 sigma^2) exactly, in place or not."""
    g = torch.Generator().manual_seed(1)
    z, c = torch.randn(2, 50, 3, generator=g, dtype=dtype), torch.randn(2, 20, 3, generator=g, dtype=dtype)
    w = torch.rand(2, 20, generator=g, dtype=dtype) + 0.1
    d2 = sq_distances(z, c)
    want = torch.exp(-d2 / (2.0 * w.unsqueeze(-2).square()))
    assert torch.equal(gaussian(d2, w), want) and torch.equal(gaussian_features(z, c, w), want)
    assert torch.equal(gaussian(d2.clone(), w, inplace=True), want)


def test_assemble_matches_design_matrix():
    from rbfn.fit import design_matrix

    c, w = torch.randn(4, 3, dtype=torch.float64), torch.rand(4, dtype=torch.float64) + 0.5
    weights = torch.randn(4 + 3 + 1, 2, dtype=torch.float64)
    off, sc = torch.randn(3, dtype=torch.float64), torch.rand(3, dtype=torch.float64) + 0.5
    net = assemble(c, w, weights, off, sc, tail=True)
    x = torch.randn(9, 3, dtype=torch.float64)
    assert torch.allclose(net(x), design_matrix((x - off) / sc, c, w) @ weights, atol=1e-12)


def test_negative_width_rejected():
    import pytest

    with pytest.raises(ValueError, match="widths must be >= "):
        RBFNetwork(torch.zeros(2, 3), torch.tensor([1.0, -0.5]), 1)


def test_workspace_flag():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(200, 3, generator=g, dtype=torch.float64)
    net = RBFNetwork(x[:20].clone(), torch.full((20,), 0.3, dtype=torch.float64), 1)
    with torch.no_grad():  # predicts y = x_1 exactly, through the tail
        net.head.weight.zero_()
        net.head.bias.zero_()
        net.tail.weight.copy_(torch.tensor([[1.0, 0.0, 0.0]]))
    net.set_domain(x, x[:, :1])
    assert net.in_workspace(x).all()
    far = torch.tensor([[5.0, 5.0, 5.0], [0.5, 0.5, -3.0]], dtype=torch.float64)
    assert not net.in_workspace(far).any()
    # Inside the box but far from every centre: flagged by the cover radius.
    net.cover_radius.fill_(0.01)
    assert not net.in_workspace(x[100:110]).all()
    net.set_domain(x, x[:, :1])
    y, mask = copy.deepcopy(net).float().solve(x.float())
    assert y.dtype == torch.float32 and mask.all()


def _net(tail=True, m=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    c = torch.randn(m, 3, generator=g, dtype=torch.float64)
    net = RBFNetwork(
        c,
        torch.rand(m, generator=g, dtype=torch.float64) + 0.5,
        2,
        offset=torch.tensor([0.1, -0.2, 0.3]),
        scale=torch.tensor([1.5, 0.5, 2.0]),
        tail=tail,
    )
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(torch.randn(p.shape, generator=g, dtype=torch.float64))
    return net


def test_bad_inputs_name_the_shape_and_type():
    import numpy as np
    import pytest

    net = _net()
    with pytest.raises(ValueError, match=r"positions must be \(B, 3\).*got shape \(5, 2\)"):
        net(torch.zeros(5, 2, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"positions must be \(B, 3\) \(one input is \(1, 3\)\), got shape \(3,\)"):
        net.solve(torch.zeros(3))
    with pytest.raises(ValueError, match=r"got shape \(2, 4, 3\)"):
        net.in_workspace(torch.zeros(2, 4, 3))
    with pytest.raises(TypeError, match=r"torch.Tensor or numpy.ndarray.*got list"):
        net([[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"outputs y must be \(4, 2\)"):
        net.in_workspace(torch.zeros(4, 3), torch.zeros(4, 3))
    x = np.random.default_rng(0).normal(size=(4, 3)).astype(np.float32)
    y, inside = net.solve(x)
    assert isinstance(y, torch.Tensor) and torch.equal(y, net(torch.from_numpy(x)))
    assert torch.equal(inside, net.in_workspace(x))


def test_rows_in_blocks_match_one_piece(monkeypatch):
    import rbfn.layer as layer

    net = _net()
    x = torch.randn(50, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(7)) * 2
    net.set_domain(x[:30], net(x[:30]).detach())
    with torch.no_grad():
        ref = (net(x), net.solve(x), net.in_workspace(x), net.design(x), net.features(x))
    calls = []
    monkeypatch.setattr(
        layer, "sq_distances", lambda z, c: calls.append(z.shape[0]) or (z[:, None] - c).square().sum(-1)
    )
    exponents = layer.RBFNetwork._exponents
    monkeypatch.setattr(
        layer.RBFNetwork, "_exponents", lambda self, xb, **kw: calls.append(xb.shape[0]) or exponents(self, xb, **kw)
    )
    net.block_rows = 16
    with torch.no_grad():
        out = (net(x), net.solve(x), net.in_workspace(x), net.design(x), net.features(x))
    # Equal up to the matrix products' rounding, which BLAS may take differently for 16 rows than
    # for 50 (the flags, from the same exponents, equal).
    for a, b in ((out[0], ref[0]), (out[1][0], ref[1][0]), (out[3], ref[3]), (out[4], ref[4])):
        torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-13)
    assert torch.equal(out[1][1], ref[1][1]) and torch.equal(out[2], ref[2])
    assert max(calls) == 16 and not ref[2].all() and ref[2].any()
    # solve takes the exponents once per block, for the features and the workspace test alike.
    calls.clear()
    net.solve(x)
    assert calls == [16, 16, 16, 2]
    # By default a block holds about block_elements exponents (rows, M).
    calls.clear()
    net.block_rows, net.block_elements = None, 6 * 20
    net(x)
    assert calls == [20, 20, 10]


def test_design_and_output_weights_reproduce_the_network():
    import pytest

    from rbfn.fit import design_matrix

    x = torch.randn(9, 3, dtype=torch.float64)
    for tail in (True, False):
        net = _net(tail)
        a, w = net.design(x), net.output_weights()
        assert a.shape == (9, net.num_design) and w.shape == (net.num_design, 2)
        assert net.num_design == 6 + (3 if tail else 0) + 1
        assert torch.allclose(a @ w, net(x), atol=1e-12)
        assert torch.allclose(a[:, :6], net.features(x)) and torch.equal(a[:, -1], torch.ones(9, dtype=torch.float64))
        if tail:
            assert torch.allclose(a, design_matrix(net.scaled(x), net.centers, net.widths), atol=1e-12)
        # Leading batch dimensions (..., d) for the design rows.
        assert torch.allclose(net.design(x.reshape(3, 3, 3)).reshape(9, -1), a)
        other = copy.deepcopy(net)
        other.set_output_weights(2 * w)
        assert torch.allclose(other(x), 2 * net(x), atol=1e-12)
        assert not w.requires_grad and torch.equal(net.output_weights(), w)
        with pytest.raises(ValueError, match=rf"output weights must be \({net.num_design}, 2\)"):
            other.set_output_weights(w[:-1])


def test_assemble_without_tail_takes_design_matrix_weights():
    from rbfn.fit import design_matrix

    c, w = torch.randn(4, 3, dtype=torch.float64), torch.rand(4, dtype=torch.float64) + 0.5
    off, sc = torch.randn(3, dtype=torch.float64), torch.rand(3, dtype=torch.float64) + 0.5
    x = torch.randn(9, 3, dtype=torch.float64)
    weights = torch.randn(4, 2, dtype=torch.float64)  # design_matrix(tail=False): no bias column
    net = assemble(c, w, weights, off, sc, tail=False)
    assert torch.allclose(net(x), design_matrix((x - off) / sc, c, w, tail=False) @ weights, atol=1e-12)
    assert torch.equal(net.head.bias, torch.zeros(2, dtype=torch.float64))
    with_bias = torch.cat([weights, torch.ones(1, 2, dtype=torch.float64)])
    assert torch.allclose(assemble(c, w, with_bias, off, sc, tail=False)(x), net(x) + 1, atol=1e-12)


def _plain(net, x):
    """Outputs by the plain path: the equation as written in `forward`."""
    net.fast = False
    try:
        return net(x)
    finally:
        del net.fast


def _reference(net, x):
    """Outputs by the plain path and the in-workspace mask by broadcast distances (same dtype as
    the network)."""
    z = (x - net.offset) / net.scale
    d2 = (z[:, None] - net.centers).square().sum(-1)
    y = _plain(net, x)
    ok = ((x >= net.in_low) & (x <= net.in_high)).all(-1) & (d2.min(-1).values.sqrt() <= net.cover_radius)
    return y, ok & ((y >= net.out_low) & (y <= net.out_high)).all(-1)


def _wide_net(seed=3, m=40):
    """A network with uneven widths, an input offset far from the origin and centres off-centre,
    and 2000 inputs (the first 1000 its training inputs)."""
    g = torch.Generator().manual_seed(seed)
    net = RBFNetwork(
        torch.rand(m, 3, generator=g, dtype=torch.float64) * 4 - 2,
        torch.rand(m, generator=g, dtype=torch.float64) * 1.0 + 0.25,
        3,
        offset=torch.tensor([5.0, -4.0, 3.0]),
        scale=torch.tensor([0.5, 0.7, 0.3]),
    )
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(torch.randn(p.shape, generator=g, dtype=torch.float64))
    x = net.offset + net.scale * (torch.rand(2000, 3, generator=g, dtype=torch.float64) * 5 - 2.5)
    net.set_domain(x[:1000], net(x[:1000]).detach())
    net.cover_radius.mul_(0.5)  # some inputs beyond it, some inside
    return net.eval(), x


def test_matrix_product_exponents_match_broadcast_distances():
    net, x = _wide_net()
    with torch.no_grad():
        y, mask = net.solve(x)
        y_ref, mask_ref = _reference(net, x)
        assert (y - y_ref).abs().max() < 1e-12 and torch.equal(mask, mask_ref)
        assert 0.2 < mask.double().mean() < 0.9
        assert torch.equal(net.in_workspace(x), mask) and torch.equal(net.in_workspace(x, y), mask)
        # float32: within 1e-5 (output units) of the float64 reference, the tolerance the fit's
        # rounding bound (rbfn.fit.ROUND_TOL) keeps deployed networks to; measured 5e-6 here
        # (3e-6 by broadcast distances in float32).
        net32 = copy.deepcopy(net).float()
        y32, mask32 = net32.solve(x.float())
        assert y32.dtype == torch.float32 and (y32.double() - y_ref).abs().max() < 1e-5
        _y32_ref, mask32_ref = _reference(net32, x.float())
        assert (mask32 != mask32_ref).sum() <= 2  # rounding at the cover radius only
        assert (mask32 != mask_ref).sum() <= 2


def narrow_far_net(seed=0):
    """A network with a Gaussian narrow (sigma = 0.01) beside its distance from the centres'
    centroid (about 4, scaled units), and 500 float32 inputs beside that centre (its training
    inputs): an exponent expanded about the centroid in float32 loses about
    u (|z - c0|^2 + |mu - c0|^2) / (2 sigma^2) ~ 1e-2 there (u = 2^-24), the Gaussian that relative error."""
    g = torch.Generator().manual_seed(seed)
    c = torch.randn(12, 3, generator=g, dtype=torch.float64) * 0.5
    c[0] = torch.tensor([3.0, -2.5, 2.0], dtype=torch.float64)
    w = torch.full((12,), 0.6, dtype=torch.float64)
    w[0] = 0.01
    one = torch.ones(3, dtype=torch.float64)
    net = assemble(c, w, 0.1 * torch.randn(12 + 4, 3, generator=g, dtype=torch.float64), 2 * one, one, tail=True)
    x = (2 + c[0] + 0.02 * torch.randn(500, 3, generator=g, dtype=torch.float64)).float()
    net.set_domain(x.double(), net(x.double()).detach())
    return net.eval(), x


def test_float32_exponents_are_exact_beside_a_narrow_gaussian_far_from_the_centroid():
    """The fast path takes the exponents' product in float64 whatever the module's dtype and
    casts them: beside a narrow Gaussian far from the centroid the float32 module (forward and
    solve, its cover test folded) is within 1e-6 of float64 at the same inputs (measured 3e-7),
    where the product in float32 was off by 4e-3. In float64 the fast path is the plain equation to
    1e-10 here (its own expansion error, u = 2^-53 times the same factor)."""
    net, x = narrow_far_net()
    with torch.no_grad():
        y64, in64 = net.solve(x)
        assert (y64 - _plain(net, x.double())).abs().max() < 1e-10 and in64.all()
        net32 = copy.deepcopy(net).float()
        assert net32._expansion().cover_weight is not None  # the cover test folded
        y32, in32 = net32.solve(x)
        assert y32.dtype == torch.float32 and (y32.double() - y64).abs().max() < 1e-6 and torch.equal(in32, in64)
        assert (net32(x).double() - y64).abs().max() < 1e-6


def _trained(tail=True, m=60, seed=5):
    """A network fitted as training fits one (ridge least squares, the ridge chosen by the float32
    rule) to a smooth map of 3 inputs, and inputs over its domain and beyond."""
    from rbfn.fit import design_matrix, ridge_fit

    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1500, 3, generator=g, dtype=torch.float64) * torch.tensor([2.0, 1.7, 1.0]) + torch.tensor(
        [0, 0.3, 0.5]
    )
    y = torch.stack([x[:, 0].sin() + x[:, 1].cos(), (x[:, 0] * x[:, 1]).cos(), -x[:, 2]], 1)
    off, sc = x.mean(0), torch.ones(3, dtype=torch.float64)
    c = (x[torch.randperm(1000, generator=g)[:m]] - off) / sc
    w = torch.full((m,), 0.4, dtype=torch.float64)
    z = (x - off) / sc
    fit = ridge_fit(
        design_matrix(z[:1000], c, w, tail),
        y[:1000],
        design_matrix(z[1000:], c, w, tail),
        y[1000:],
        eval_dtype=torch.float32,
    )
    net = assemble(c, w, fit.weights, off, sc, tail=tail)
    net.set_domain(x[:1000], y[:1000])
    return net.eval(), x * 1.1 - 0.05


@pytest.mark.parametrize("tail", [True, False])
def test_plain_and_fast_paths_agree(tail):
    """`forward`'s plain equation (fast = False) and its fast matrix-product path give the same
    outputs, to 1e-12 in float64, and within 1e-5 of the float64 outputs in float32, on random
    and on trained networks."""
    g = torch.Generator().manual_seed(0)
    nets = [(_net(tail, m=30, seed=s), torch.randn(400, 3, dtype=torch.float64, generator=g) * 2) for s in (0, 1)]
    nets.append(_trained(tail))
    if tail:
        nets.append(_wide_net())
    for net, x in nets:
        with torch.no_grad():
            fast, plain = net(x), _plain(net, x)
            scale = 1 + fast.abs().max()
            assert (fast - plain).abs().max() < 1e-12 * scale
            net32 = copy.deepcopy(net).float()
            assert (net32(x.float()).double() - plain).abs().max() < 1e-5 * scale
            assert (_plain(net32, x.float()).double() - plain).abs().max() < 1e-5 * scale
            net.block_rows = 64
            assert torch.equal(net(x), fast) and torch.equal(_plain(net, x), plain)
    assert RBFNetwork.fast and nets[0][0].fast  # the default, restored


def test_for_export_is_a_frozen_float32_copy_with_the_cover_fold_decided():
    net, x = _wide_net()
    exported = net.for_export()
    assert exported is not net and exported.centers.dtype == torch.float32 and net.centers.dtype == torch.float64
    assert not exported.training and not any(p.requires_grad for p in exported.parameters())
    assert exported.traced_cover_fold and not net.traced_cover_fold
    with torch.no_grad():
        y, mask = exported.solve_rows(x.float())
        assert (y.double() - net(x)).abs().max() < 1e-5 and torch.equal(mask, exported.solve(x.float())[1])


def test_cover_test_folded_into_the_exponents_or_not_matches_the_reference():
    """solve folds the cover test into the exponents where every shift r^2 / (2 sigma_i^2) is at
    most MAX_COVER_SHIFT, and takes the squared distances otherwise: the same outputs and mask."""
    from rbfn.gaussians import MAX_COVER_SHIFT, cover_foldable

    net, x = _wide_net()
    assert cover_foldable(net.widths, net.cover_radius)
    with torch.no_grad():
        assert net._expansion().cover_weight is not None
        narrow = copy.deepcopy(net)
        r = float(narrow.cover_radius)
        narrow.widths[0] = r / (2 * MAX_COVER_SHIFT) ** 0.5 * 0.99  # shift just over the limit
        assert not cover_foldable(narrow.widths, narrow.cover_radius)
        assert narrow._expansion().cover_weight is None
        unbounded = copy.deepcopy(net)
        unbounded.cover_radius.fill_(float("inf"))
        assert not cover_foldable(unbounded.widths, unbounded.cover_radius)
        for model in (net, narrow, unbounded):
            y, mask = model.solve(x)
            y_ref, mask_ref = _reference(model, x)
            assert (y - y_ref).abs().max() < 1e-12 and torch.equal(mask, mask_ref)
            assert (model(x) - y).abs().max() < 1e-12 and torch.equal(model.in_workspace(x), mask)
        assert not net.solve(x)[1].all() and unbounded.solve(x)[1].sum() > net.solve(x)[1].sum()


def test_exponents_follow_changed_buffers():
    """The matrix form is reused between calls, never after a buffer changed."""
    net, x = _wide_net()
    fresh = lambda n: assemble(n.centers, n.widths, n.output_weights(), n.offset, n.scale, tail=True)  # noqa: E731
    with torch.no_grad():
        y0 = net(x)
        assert torch.equal(net(x), y0)
        net.centers[3] += 0.5  # in place
        net.widths.mul_(1.1)
        net.scale[1] = 0.9
        net.offset.add_(0.01)
        y1 = net(x)
        assert (y1 - y0).abs().max() > 1e-3 and (y1 - fresh(net)(x)).abs().max() < 1e-12
        other, _ = _wide_net(seed=4)
        net.load_state_dict(other.state_dict())  # copied in place
        assert (net(x) - other(x)).abs().max() < 1e-12
        net.centers = net.centers.flip(0).contiguous()  # a new tensor
        net.widths = net.widths.flip(0).contiguous()
        net.head.weight.copy_(net.head.weight.flip(1))
        assert (net(x) - other(x)).abs().max() < 1e-12
        net.float()
        assert net(x).dtype == torch.float32 and (net(x).double() - other(x)).abs().max() < 1e-5
    with torch.inference_mode():  # inference tensors: no version counter
        infer = copy.deepcopy(other).float()
        y = infer(x)
        infer.centers[0] += 1.0
        assert (infer(x) - y).abs().max() > 1e-6


def test_gradients_through_the_matrix_product_match_broadcast_distances():
    """Autograd through forward (inputs and head), in place activations included."""
    net, x = _wide_net()
    x = x[:20].clone().requires_grad_(True)
    jac = torch.autograd.functional.jacobian(net, x[:3].detach())
    ref = torch.autograd.functional.jacobian(lambda t: _reference(net, t)[0], x[:3].detach())
    assert (jac - ref).abs().max() < 1e-12
    net.solve(x)[0].square().sum().backward()
    grads = (x.grad.clone(), net.head.weight.grad.clone())
    x.grad, net.head.weight.grad = None, None
    _reference(net, x)[0].square().sum().backward()
    assert (grads[0] - x.grad).abs().max() < 1e-10 and (grads[1] - net.head.weight.grad).abs().max() < 1e-10


def test_non_finite_inputs_are_refused_by_every_entry_point():
    net = RBFNetwork(torch.rand(4, 3), torch.ones(4), 2)
    bad = torch.tensor([[0.1, 0.2, 0.3], [0.1, float("nan"), 0.3]])
    for call in (net, net.solve, net.in_workspace, net.features, net.design, net.scaled):
        with pytest.raises(ValueError, match=r"positions must be finite; row 1 is \[0.1.*nan"):
            call(bad)
    with pytest.raises(ValueError, match="finite"):
        net(torch.tensor([[float("inf"), 0.0, 0.0]]).numpy())
    assert net(torch.tensor([[3e38, 3e38, 3e38]])).shape == (1, 2)  # finite, though their sum overflows


def test_in_workspace_takes_outputs_of_another_float_dtype():
    net = RBFNetwork(torch.rand(4, 3), torch.ones(4), 2)
    x = torch.rand(5, 3)
    assert torch.equal(net.in_workspace(x, net(x).double()), net.in_workspace(x, net(x)))


@pytest.mark.parametrize(
    "centers,widths,out,message",
    [
        (torch.full((2, 3), float("nan")), torch.ones(2), 3, "centers must be finite"),
        (torch.zeros(2, 3), torch.tensor([1.0, float("inf")]), 3, "widths must be finite"),
        (torch.zeros(2, 3), torch.tensor([1.0, 1e-30]), 3, "widths must be >= 1e-12"),
        (torch.zeros(2, 3, dtype=torch.int64), torch.ones(2), 3, "floating-point"),
        (torch.zeros(3), torch.ones(3), 3, r"shape \(M, d\)"),
        (torch.zeros(2, 3), torch.ones(2), 0, "out_features=0"),
    ],
)
def test_the_constructor_checks_its_arguments(centers, widths, out, message):
    with pytest.raises((ValueError, TypeError), match=message):
        RBFNetwork(centers, widths, out)


def test_non_finite_output_weights_are_refused():
    net = RBFNetwork(torch.rand(4, 3), torch.ones(4), 2)
    with pytest.raises(ValueError, match="output weights must be finite"):
        net.set_output_weights(torch.full((net.num_design, 2), float("nan")))


def test_the_plain_path_runs_in_blocks_too(monkeypatch):
    """`fast = False` holds (rows, M, d) differences a block, not (B, M, d): any batch is bounded."""
    from rbfn import gaussians

    net = _net()
    x = torch.randn(50, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    ref = _plain(net, x)
    calls = []
    sq = gaussians.sq_distances
    monkeypatch.setattr(gaussians, "sq_distances", lambda z, c: calls.append(z.shape[0]) or sq(z, c))
    net.block_rows = 16
    assert torch.allclose(_plain(net, x), ref, rtol=0, atol=1e-12)
    assert calls == [16, 16, 16, 2]
