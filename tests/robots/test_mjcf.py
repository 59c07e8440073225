"""The generated MJCF is the same arm: MuJoCo's M(q) and C(q, qd) qd + G(q) equal the closed forms."""
import pytest
import torch

from rbfn.robots import scara
from rbfn.robots.mjcf import scara_mjcf

mujoco = pytest.importorskip("mujoco")
np = pytest.importorskip("numpy")


@pytest.mark.parametrize("payload", [0.0, 10.0])
def test_mujoco_dynamics_match_closed_form(payload):
    model = mujoco.MjModel.from_xml_string(scara_mjcf(payload=payload))
    data = mujoco.MjData(model)
    g = torch.Generator().manual_seed(0)
    low, high = torch.tensor([-3.0, -2.5, 0.0]), torch.tensor([3.0, 2.5, 2.0])
    for _ in range(5):
        q = low + torch.rand(1, 3, dtype=torch.float64, generator=g) * (high - low)
        qd = torch.randn(1, 3, dtype=torch.float64, generator=g)
        data.qpos[:], data.qvel[:] = q[0].numpy(), qd[0].numpy()
        mujoco.mj_forward(model, data)
        m = np.zeros((3, 3))
        mujoco.mj_fullM(model, data, m)
        bias = scara.coriolis(q, qd, payload)[0] @ qd[0] + scara.gravity(q, payload)[0]
        assert np.allclose(m, scara.mass_matrix(q, payload)[0].numpy(), atol=1e-8)
        assert np.allclose(data.qfrc_bias, bias.numpy(), atol=1e-8)
        assert np.allclose(data.qfrc_passive, -12.0 * qd[0].numpy())   # viscous damping 12
