"""MuJoCo models of the closed loop's robots are the same arms: M(q) and C(q, qd) qd + G(q) equal ours."""

import pytest
import torch

from rbfn.robots import scara
from rbfn.robots.scara.mjcf import scara_mjcf

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
        assert np.allclose(data.qfrc_passive, -12.0 * qd[0].numpy())  # viscous damping 12


@pytest.mark.parametrize("payload", [0.0, 2.5])
def test_mujoco_compiles_the_ur5_urdf_to_the_same_dynamics(payload):
    """MuJoCo reads the UR5's URDF itself: its M(q) and bias forces qfrc_bias = C(q, qd) qd + G(q)
    equal rbfn.robots.dynamics' at random states, with a payload at the end link's origin."""
    from rbfn.robots.dynamics import load_arm
    from rbfn.robots.mjcf import arm_model

    arm = load_arm("ur5")
    model = arm_model("ur5", payload=payload, payload_link=arm.end_link, viscous=2.0, coulomb=0.0)
    data = mujoco.MjData(model)
    assert model.nv == arm.n and model.nu == arm.n
    assert [model.joint(i).name for i in range(model.njnt)] == arm.joint_names
    g = torch.Generator().manual_seed(1)
    q = (torch.rand(20, 6, dtype=torch.float64, generator=g) * 2 - 1) * torch.pi
    qd = torch.randn(20, 6, dtype=torch.float64, generator=g)
    m_ref, b_ref = arm.dynamics(q, qd, payload)
    for i in range(20):
        data.qpos[:], data.qvel[:] = q[i].numpy(), qd[i].numpy()
        mujoco.mj_forward(model, data)
        m = np.zeros((6, 6))
        mujoco.mj_fullM(model, data, m)
        assert np.allclose(m, m_ref[i].numpy(), rtol=1e-10, atol=1e-12)
        assert np.allclose(data.qfrc_bias, b_ref[i].numpy(), rtol=1e-10, atol=1e-10)
        assert np.allclose(data.qfrc_passive, -2.0 * qd[i].numpy())  # viscous damping 2


@pytest.mark.parametrize(
    "name", ["erd_ur3", "erd_ur5", "erd_ur10", "erd_kinova", "erd_xarm7", "erd_z1", "erd_so100", "erd_so101"]
)
def test_mujoco_compiles_example_robot_data_arms_to_the_same_dynamics(name):
    """example-robot-data's serial arms (every joint on the chain) from their files: MuJoCo gets their
    joints and inertials only (no mesh file opened) and gives rbfn.robots.dynamics' M and bias."""
    from rbfn.robots.dynamics import load_arm
    from rbfn.robots.mjcf import arm_model
    from tests.robots.test_dynamics import ERD, _erd_urdf, _states

    rel, end = ERD[name]
    path = _erd_urdf(rel)
    arm = load_arm(path, end)
    model = arm_model(path, payload=1.5, payload_link=end)
    data = mujoco.MjData(model)
    assert [model.joint(i).name for i in range(model.njnt)] == arm.joint_names
    q, qd = _states(arm, 10, seed=2)
    m_ref, b_ref = arm.dynamics(q, qd, 1.5)
    for i in range(10):
        data.qpos[:], data.qvel[:] = q[i].numpy(), qd[i].numpy()
        mujoco.mj_forward(model, data)
        m = np.zeros((arm.n, arm.n))
        mujoco.mj_fullM(model, data, m)
        assert np.allclose(m, m_ref[i].numpy(), rtol=1e-10, atol=1e-12)
        assert np.allclose(data.qfrc_bias, b_ref[i].numpy(), rtol=1e-10, atol=1e-10)
