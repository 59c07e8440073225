import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from rbfn.robots import forward_kinematics, load_serial_chain
from rbfn.robots import scara

joints = st.lists(st.tuples(st.floats(-3.1, 3.1), st.floats(-2.5, 2.5), st.floats(0.0, 2.0)),
                  min_size=1, max_size=16)


@settings(max_examples=30, deadline=None)
@given(joints)
def test_urdf_fk_matches_closed_form_float64(chain, qs):
    q = torch.tensor(qs, dtype=torch.float64)
    assert torch.allclose(forward_kinematics(chain, q), scara.fk(q), atol=1e-14, rtol=0)


def test_float32_chain_close_to_closed_form():
    chain32 = load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float32)
    q = torch.rand(100, 3, dtype=torch.float64) * 2
    assert (forward_kinematics(chain32, q.float()).double() - scara.fk(q)).abs().max() < 1e-6


def test_fk_convention():
    # q = 0: arm stretched along x; z = -q3 (joint 3 positive downward).
    q = torch.tensor([[0.0, 0.0, 0.7], [torch.pi / 2, 0.0, 0.0], [0.0, torch.pi / 2, 0.0]], dtype=torch.float64)
    expect = torch.tensor([[1.8, 0.0, -0.7], [0.0, 1.8, 0.0], [1.0, 0.8, 0.0]], dtype=torch.float64)
    assert torch.allclose(scara.fk(q), expect, atol=1e-12)


def test_closed_form_ik_inverts_fk_on_branch():
    g = torch.Generator().manual_seed(0)
    q = torch.tensor([0.0, 0.3, 0.5]) + torch.rand(500, 3, generator=g, dtype=torch.float64) * torch.tensor([2.0, 1.7, 1.0])
    assert torch.allclose(scara.ik(scara.fk(q)), q, atol=1e-9)


def test_bad_end_link_names_links():
    import pytest

    with pytest.raises(ValueError, match="not a link"):
        load_serial_chain(scara.URDF_PATH, "gripper")
