"""The SCARA's closed-form dynamics against an independent computation from the URDF.

M from the link Jacobians and the URDF inertials (both Jacobians by autograd through
pytorch-kinematics' forward kinematics), C from the Christoffel symbols of M by autograd,
G from the gradient of the potential energy; all in float64 to 1e-9.
"""
import pytest
import torch
from pytorch_kinematics.urdf_parser_py.urdf import URDF

from rbfn.robots import load_serial_chain
from rbfn.robots.scara import END_LINK, URDF_PATH, ScaraParams, coriolis, gravity, mass_matrix, mass_matrix_dot

G = 9.8
LINKS = ("link1", "link2", "quill")


@pytest.fixture(scope="module")
def urdf_model():
    robot = URDF.from_xml_string(URDF_PATH.read_text())
    chain = load_serial_chain(URDF_PATH, END_LINK, torch.float64)
    inertials = {}
    for name in LINKS:
        i = robot.link_map[name].inertial
        inertia = torch.tensor([[i.inertia.ixx, i.inertia.ixy, i.inertia.ixz],
                                [i.inertia.ixy, i.inertia.iyy, i.inertia.iyz],
                                [i.inertia.ixz, i.inertia.iyz, i.inertia.izz]], dtype=torch.float64)
        inertials[name] = (i.mass, torch.tensor(i.origin.xyz, dtype=torch.float64), inertia)
    return chain, inertials


def _frames(chain, q):
    """World rotation (3, 3) and COM-frame origin of every link for one q (3,)."""
    tfs = chain.forward_kinematics(q[None], end_only=False)
    return {n: tfs[n].get_matrix()[0] for n in LINKS}


def _independent_m(model, q, payload=0.0):
    chain, inertials = model

    def com_positions(qq):
        mats = _frames(chain, qq)
        return torch.stack([mats[n][:3, :3] @ inertials[n][1] + mats[n][:3, 3] for n in LINKS])

    def rotations(qq):
        mats = _frames(chain, qq)
        return torch.stack([mats[n][:3, :3] for n in LINKS])

    jv = torch.autograd.functional.jacobian(com_positions, q, create_graph=True)   # (L, 3, n)
    dr = torch.autograd.functional.jacobian(rotations, q, create_graph=True)        # (L, 3, 3, n)
    rot = rotations(q)
    m = torch.zeros(3, 3, dtype=torch.float64)
    for k, n in enumerate(LINKS):
        mass, _, inertia = inertials[n]
        mass = mass + (payload if n == "quill" else 0.0)
        # Angular-velocity Jacobian: skew(w_i) = dR/dq_i R^T.
        w = torch.stack([torch.stack([s[2, 1], s[0, 2], s[1, 0]]) for s in
                         (dr[k, :, :, i] @ rot[k].T for i in range(3))], dim=1)
        i_world = rot[k] @ inertia @ rot[k].T
        m = m + mass * jv[k].T @ jv[k] + w.T @ i_world @ w
    return m


def _states(n, seed):
    g = torch.Generator().manual_seed(seed)
    q = torch.rand(n, 3, generator=g, dtype=torch.float64) * torch.tensor([6.0, 5.0, 2.0]) - torch.tensor([3.0, 2.5, 0.0])
    qd = torch.randn(n, 3, generator=g, dtype=torch.float64) * 2.0
    return q, qd


@pytest.mark.parametrize("payload", [0.0, 10.0])
def test_mass_matrix_matches_link_jacobians(urdf_model, payload):
    q, _ = _states(8, 0)
    for qi in q:
        ref = _independent_m(urdf_model, qi, payload)
        assert torch.allclose(mass_matrix(qi[None], payload)[0], ref, atol=1e-9, rtol=0)


def test_coriolis_matches_christoffel_symbols():
    # pytorch-kinematics is not twice differentiable, so the Christoffel symbols come from the
    # closed-form M, which the test above checks against the URDF to 1e-9.
    q, qd = _states(6, 1)
    for payload in (0.0, 10.0):
        for qi, qdi in zip(q, qd):
            dm = torch.autograd.functional.jacobian(lambda x: mass_matrix(x[None], payload)[0], qi)  # noqa: B023 - used here
            # c_ijk = 1/2 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i); C_ij = sum_k c_ijk qd_k
            chris = 0.5 * (dm + dm.transpose(1, 2) - dm.permute(2, 0, 1))
            ref = chris @ qdi
            assert torch.allclose(coriolis(qi[None], qdi[None], payload)[0], ref, atol=1e-9, rtol=0)


def test_gravity_is_the_gradient_of_potential_energy(urdf_model):
    chain, inertials = urdf_model
    q, _ = _states(6, 2)
    for payload in (0.0, 20.0):
        for qi in q:
            def potential(qq):
                mats = _frames(chain, qq)
                v = 0.0
                for n in LINKS:
                    mass = inertials[n][0] + (payload if n == "quill" else 0.0)  # noqa: B023 - used at once
                    v = v + mass * G * (mats[n][:3, :3] @ inertials[n][1] + mats[n][:3, 3])[2]
                return v
            ref = torch.autograd.functional.jacobian(potential, qi)
            assert torch.allclose(gravity(qi[None], payload)[0], ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_mass_matrix_symmetric_positive_definite(dtype):
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
    from rbfn.robots.scara import inertia_params
    p1, p2, p3, m3 = inertia_params(0.0, ScaraParams())
    assert (round(p1, 3), round(p2, 3), round(p3, 4), m3) == (2.124, 0.72, 0.4907, 0.5)
