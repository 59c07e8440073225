import copy

import torch

from rbfn.layer import RBFNetwork, assemble, gaussian_features


def test_shapes_and_scaling():
    c = torch.randn(7, 3, dtype=torch.float64)
    net = RBFNetwork(c, torch.ones(7, dtype=torch.float64), 2, offset=torch.tensor([1.0, 2.0, 3.0]),
                     scale=torch.tensor([2.0, 2.0, 2.0]))
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

    with pytest.raises(ValueError, match="widths must be positive"):
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
