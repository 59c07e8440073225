"""rbfn.robots.backend's written-out solve (the rest of the interface: tests/robots/test_dynamics_backends.py)."""

import torch

from rbfn.robots.backend import spd_solve


def test_spd_solve_equals_linalg_solve():
    g = torch.Generator().manual_seed(0)
    for m in (1, 3, 6, 7):
        j = torch.randn(50, m, m, generator=g, dtype=torch.float64)
        a = j @ j.transpose(1, 2) + 0.1 * torch.eye(m, dtype=torch.float64)
        b = torch.randn(50, m, generator=g, dtype=torch.float64)
        assert torch.allclose(spd_solve(a, b), torch.linalg.solve(a, b), rtol=0, atol=1e-10)


def test_spd_solve_takes_a_permuted_view():
    """The URDF backend hands it a (B, n, n) view of batch-last storage."""
    g = torch.Generator().manual_seed(1)
    j = torch.randn(6, 6, 20, generator=g, dtype=torch.float64)
    a = torch.einsum("ikb,jkb->ijb", j, j) + 0.1 * torch.eye(6, dtype=torch.float64)[:, :, None]
    b = torch.randn(20, 6, generator=g, dtype=torch.float64)
    view = a.permute(2, 0, 1)
    assert torch.allclose(spd_solve(view, b), torch.linalg.solve(view, b), rtol=0, atol=1e-10)
