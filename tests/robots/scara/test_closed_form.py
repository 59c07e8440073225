"""The SCARA's closed-form dynamics (rbfn.robots.scara.closed_form): what only they have.

Their M, C and G equal the URDF's (`rbfn.robots.dynamics.Arm`, itself checked against Pinocchio)
in tests/robots/test_dynamics_backends.py; here: float32 in, float32 out with M symmetric positive
definite, dM/dt by autograd and dM/dt - 2C skew, and the design's inertia parameters.
"""

import torch

from rbfn.robots.scara.closed_form import ScaraParams, coriolis, inertia_params, mass_matrix, mass_matrix_dot


def _states(n, seed):
    g = torch.Generator().manual_seed(seed)
    q = torch.rand(n, 3, generator=g, dtype=torch.float64) * torch.tensor([6.0, 5.0, 2.0]) - torch.tensor(
        [3.0, 2.5, 0.0]
    )
    qd = torch.randn(n, 3, generator=g, dtype=torch.float64) * 2.0
    return q, qd


def test_mass_matrix_float32_symmetric_positive_definite():
    dtype = torch.float32
    q, _ = _states(2000, 3)
    payload = torch.rand(2000, generator=torch.Generator().manual_seed(4), dtype=torch.float64) * 30
    m = mass_matrix(q.to(dtype), payload.to(dtype))
    assert m.dtype == dtype and m.shape == (2000, 3, 3)
    assert torch.equal(m, m.transpose(1, 2))
    assert bool((torch.linalg.eigvalsh(m.double()) > 0).all())


def test_mdot_minus_2c_is_skew_symmetric():
    q, qd = _states(500, 5)
    # dM/dt by autograd (a directional derivative along qd), independent of mass_matrix_dot.
    mdot = torch.func.jvp(lambda x: mass_matrix(x, 3.0), (q,), (qd,))[1]
    assert torch.allclose(mass_matrix_dot(q, qd, 3.0), mdot, atol=1e-12)
    n = mdot - 2 * coriolis(q, qd, 3.0)
    assert torch.allclose(n, -n.transpose(1, 2), atol=1e-12)


def test_no_payload_parameters_match_the_design():
    p1, p2, p3, m3 = inertia_params(0.0, ScaraParams())
    assert (round(p1, 3), round(p2, 3), round(p3, 4), m3) == (2.124, 0.72, 0.4907, 0.5)
