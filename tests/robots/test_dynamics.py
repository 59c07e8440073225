"""URDF dynamics (rbfn.robots.dynamics): the loader on many URDFs, and properties.

Pinocchio (an independent C++ implementation) checks M, C qd, G, C and RNEA on
example-robot-data's serial arms (UR3/5/10, Panda, Kinova j2s6s200, xArm7, Z1, SO-100, SO-101; joints
beyond the end link locked at zero) and on chains of the robots whose visual textures or
transmissions pytorch-kinematics' URDF parser refuses (iCub, PR2, Romeo). The packaged robots and
a test arm with everything the loader has to lump (fixed links along the chain, off-chain bodies,
fixed bodies and a finger joint beyond the end link, rotated origins, unaligned and unnormalised
axes, a prismatic and a continuous joint) are rows of tests/robots/test_dynamics_backends.py,
which checks every form of the dynamics (the simulator's, the SCARA's closed form, Pinocchio,
MuJoCo) against `Arm`. The property tests need no Pinocchio: M symmetric positive definite,
dM/dt - 2C skew, C the Christoffel matrix of M (by autograd), energy conserved with gravity off,
G the gradient of the potential energy.
"""

from __future__ import annotations

import importlib.metadata
import os
import re
import reprlib
from pathlib import Path

import pytest
import torch

from rbfn.robots.arm_terms import ArmTerms
from rbfn.robots.dynamics import load_arm
from rbfn.robots.kinematics import read_urdf, urdf_path
from tests.guarded import run_guarded

torch.set_num_threads(1)

# Off-diagonal inertias, rotated inertial frames, a fixed link mid-chain, an off-chain camera,
# a prismatic and a continuous joint, unaligned axes, and beyond the end link (flange) a fixed
# tool with a finger pair (one mimicking the other) that the loader holds at zero.
TEST_URDF = """<?xml version="1.0" encoding="utf-8"?>
<robot name="test_arm">
  <link name="world"/>
  <link name="base"><inertial><mass value="3.0"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="0.1 -0.2 0.05" rpy="0 0 0.4"/></joint>
  <link name="l1"><inertial><origin xyz="0.02 0.01 0.15" rpy="0.3 -0.2 0.1"/><mass value="2.5"/>
    <inertia ixx="0.04" ixy="0.002" ixz="-0.001" iyy="0.035" iyz="0.003" izz="0.02"/>
  </inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.2" rpy="0.1 -0.05 0.3"/><axis xyz="0 0 1"/>
    <limit lower="-2.9" upper="2.9" effort="100" velocity="2"/></joint>
  <link name="camera"><inertial><origin xyz="0.01 0 0.02"/><mass value="0.4"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0015"/></inertial></link>
  <joint name="camera_mount" type="fixed"><parent link="l1"/><child link="camera"/>
    <origin xyz="0.05 0.08 0.1" rpy="0 0.5 0"/></joint>
  <link name="l2"><inertial><origin xyz="0.2 0.0 0.01" rpy="0 0 0.2"/><mass value="1.8"/>
    <inertia ixx="0.005" ixy="-0.001" ixz="0.0005" iyy="0.03" iyz="0" izz="0.03"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0.05 0.3" rpy="-1.5707963267948966 0 0"/><axis xyz="0.3 -0.5 0.8"/>
    <limit lower="-2.0" upper="2.0" effort="100" velocity="2"/></joint>
  <link name="l2_plate"><inertial><origin xyz="0.05 0 0"/><mass value="0.6"/>
    <inertia ixx="0.002" ixy="0" ixz="0" iyy="0.003" iyz="0.0004" izz="0.002"/></inertial></link>
  <joint name="plate" type="fixed"><parent link="l2"/><child link="l2_plate"/>
    <origin xyz="0.4 0 0" rpy="0.2 0.1 -0.3"/></joint>
  <link name="l3"><inertial><origin xyz="0 0 0.1"/><mass value="1.2"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.002"/></inertial></link>
  <joint name="slide" type="prismatic"><parent link="l2_plate"/><child link="l3"/>
    <origin xyz="0.1 0 0" rpy="0 0.3 0"/><axis xyz="1 0 1"/>
    <limit lower="-0.1" upper="0.25" effort="300" velocity="1"/></joint>
  <link name="l4"><inertial><origin xyz="0 0.03 0.05" rpy="0.4 0 0"/><mass value="0.9"/>
    <inertia ixx="0.003" ixy="0.0002" ixz="0" iyy="0.002" iyz="0" izz="0.0025"/></inertial></link>
  <joint name="wrist" type="continuous"><parent link="l3"/><child link="l4"/>
    <origin xyz="0 0 0.2" rpy="0 0 0"/><axis xyz="0 1 0"/></joint>
  <link name="flange"><inertial><mass value="0.2"/>
    <inertia ixx="0.0002" ixy="0" ixz="0" iyy="0.0002" iyz="0" izz="0.0003"/></inertial></link>
  <joint name="flange_joint" type="fixed"><parent link="l4"/><child link="flange"/>
    <origin xyz="0.02 0.1 0.06" rpy="0 0 0.7"/></joint>
  <link name="tool"><inertial><origin xyz="0 0 0.04"/><mass value="0.7"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.0012" iyz="0" izz="0.0008"/></inertial></link>
  <joint name="tool_joint" type="fixed"><parent link="flange"/><child link="tool"/>
    <origin xyz="0 0 0.03" rpy="0 0 -0.7"/></joint>
  <link name="finger_a"><inertial><origin xyz="0 0.01 0.02"/><mass value="0.05"/>
    <inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>
  <joint name="finger_a_joint" type="prismatic"><parent link="tool"/><child link="finger_a"/>
    <origin xyz="0 0 0.08"/><axis xyz="0 1 0"/>
    <limit lower="0" upper="0.04" effort="10" velocity="0.1"/></joint>
  <link name="finger_b"><inertial><origin xyz="0 -0.01 0.02"/><mass value="0.05"/>
    <inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>
  <joint name="finger_b_joint" type="prismatic"><parent link="tool"/><child link="finger_b"/>
    <origin xyz="0 0 0.08"/><axis xyz="0 -1 0"/>
    <limit lower="0" upper="0.04" effort="10" velocity="0.1"/>
    <mimic joint="finger_a_joint"/></joint>
</robot>
"""
TEST_END = "flange"


def _erd_urdf(rel: str) -> Path:
    """A URDF shipped by example-robot-data (the cmeel wheel keeps it under share/)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    for base in ("cmeel.prefix/share/example-robot-data/robots", "share/example-robot-data/robots"):
        path = Path(str(dist.locate_file(f"{base}/{rel}")))
        if path.is_file():
            return path
    pytest.skip(f"example-robot-data has no {rel}")


# example-robot-data's serial arms and chains of its humanoids: test name -> (file under robots/, end link).
_PANDA, _KINOVA = "panda_description/urdf/panda.urdf", "kinova_description/robots/kinova.urdf"
ERD = {
    "erd_ur3": ("ur_description/urdf/ur3_robot.urdf", "ee_link"),
    "erd_ur5": ("ur_description/urdf/ur5_robot.urdf", "ee_link"),
    "erd_ur10": ("ur_description/urdf/ur10_robot.urdf", "ee_link"),
    "erd_panda": (_PANDA, "panda_hand"),
    "erd_panda_link8": (_PANDA, "panda_link8"),
    "erd_panda_finger": (_PANDA, "panda_leftfinger"),  # 8 joints: a finger's prismatic one
    "erd_kinova": (_KINOVA, "j2s6s200_end_effector"),
    "erd_kinova_finger_tip": (_KINOVA, "j2s6s200_link_finger_tip_1"),
    "erd_xarm7": ("xarm_description/urdf/xarm7.urdf", "link_eef"),
    "erd_z1": ("z1_description/urdf/z1.urdf", "gripperMover"),
    "erd_so100": ("so_arm_description/urdf/so100.urdf", "jaw"),
    "erd_so101": ("so_arm_description/urdf/so101.urdf", "moving_jaw_so101_v1_link"),
    # pytorch-kinematics' URDF parser refuses their visual textures (iCub, Romeo) or transmissions (PR2)
    "erd_icub": ("icub_description/robots/icub.urdf", "r_hand"),
    "erd_pr2": ("pr2_description/urdf/pr2.urdf", "r_gripper_palm_link"),
    "erd_romeo": ("romeo_description/urdf/romeo_laas_small.urdf", "RArm_effector"),
}


def _source(name: str) -> tuple[str, str]:
    """(URDF text, end link) of a test robot name."""
    if name == "test_arm":
        return TEST_URDF, TEST_END
    if name in ERD:
        rel, end = ERD[name]
        return read_urdf(_erd_urdf(rel)), end
    return read_urdf(urdf_path(name)), load_arm(name).end_link


def _arm(name: str, **kw):
    if name == "scara":
        return load_arm("scara", **kw)
    text, end = _source(name)
    return load_arm(text, end, **kw)


def _states(arm, count: int, seed: int, dtype=torch.float64):
    """q uniform within the joint limits (continuous joints within +-pi), qd ~ N(0, 1)."""
    g = torch.Generator().manual_seed(seed)
    low, high = (x.clamp(-torch.pi, torch.pi) for x in arm.joint_limits())
    q = low + (high - low) * torch.rand(count, arm.n, generator=g, dtype=torch.float64)
    qd = torch.randn(count, arm.n, generator=g, dtype=torch.float64)
    return q.to(dtype), qd.to(dtype)


def _rel(x: torch.Tensor, ref: torch.Tensor) -> float:
    """Largest per-state relative error ||x - ref|| / ||ref|| (Frobenius) over the batch."""
    d = (x - ref).reshape(len(ref), -1).norm(dim=1)
    return float((d / ref.reshape(len(ref), -1).norm(dim=1)).max())


# ----------------------------------------------------------------------------- Pinocchio
def _pinocchio(name: str, arm, payload: float):
    """Pinocchio model and data of the same URDF, off-chain joints locked at zero, the payload
    added to the end link's joint body; and a gravity-free copy for C qd."""
    pin = pytest.importorskip("pinocchio")
    import numpy as np

    text, end = _source(name)
    model = pin.buildModelFromXML(text)
    locked = [model.getJointId(n) for n in model.names[1:] if n not in arm.joint_names]
    if locked:
        model = pin.buildReducedModel(model, locked, pin.neutral(model))
    assert list(model.names[1:]) == arm.joint_names
    if payload:
        frame = model.frames[model.getFrameId(end)]
        model.inertias[frame.parentJoint] = model.inertias[frame.parentJoint] + pin.Inertia(
            payload, frame.placement.translation, np.zeros((3, 3))
        )
    free = model.copy()
    free.gravity.setZero()
    return pin, model, free


@pytest.mark.parametrize("payload", [0.0, 2.5])
@pytest.mark.parametrize("name", list(ERD))
def test_matches_pinocchio(name, payload):
    pytest.importorskip("pinocchio")
    import numpy as np

    arm = _arm(name)
    pin, model, free = _pinocchio(name, arm, payload)
    data, free_data = model.createData(), free.createData()
    q, qd = _states(arm, 1000, seed=7)
    qdd = torch.randn(1000, arm.n, generator=torch.Generator().manual_seed(8), dtype=torch.float64)
    ref = {k: [] for k in ("M", "Cqd", "G", "C", "tau")}
    neutral = pin.neutral(model)
    for qi, qdi, qddi in zip(q.numpy(), qd.numpy(), qdd.numpy()):
        qp = pin.integrate(model, neutral, qi)  # continuous joints: (cos, sin)
        m = pin.crba(model, data, qp)
        ref["M"].append(np.triu(m) + np.triu(m, 1).T)
        ref["G"].append(pin.computeGeneralizedGravity(model, data, qp).copy())
        ref["Cqd"].append(pin.rnea(free, free_data, qp, qdi, np.zeros(arm.n)).copy())
        ref["C"].append(pin.computeCoriolisMatrix(model, data, qp, qdi).copy())
        ref["tau"].append(pin.rnea(model, data, qp, qdi, qddi).copy())
    ref = {k: torch.from_numpy(np.stack(v)) for k, v in ref.items()}
    bias = arm.bias(q, qd, payload)
    g = arm.gravity(q, payload)
    errors = {
        "M": _rel(arm.mass_matrix(q, payload), ref["M"]),
        "Cqd": _rel(bias - g, ref["Cqd"]),
        "G": _rel(g, ref["G"]),
        "C": _rel(arm.coriolis(q, qd, payload), ref["C"]),
        "Cqd from C": _rel((arm.coriolis(q, qd, payload) @ qd.unsqueeze(-1)).squeeze(-1), ref["Cqd"]),
        "tau": _rel(arm.inverse_dynamics(q, qd, qdd, payload), ref["tau"]),
    }
    assert max(errors.values()) <= 1e-9, errors


# ----------------------------------------------------------------------------- batch-last terms
def test_batch_last_terms_float32():
    arm = _arm("panda")
    q, qd = _states(arm, 64, seed=14)
    cfg64, cfg32 = ArmTerms(arm).at(q, 2.0), ArmTerms(arm).at(q.float(), 2.0)
    assert cfg32.mass_matrix().dtype == torch.float32
    assert _rel(cfg32.mass_matrix().double(), cfg64.mass_matrix()) < 1e-5
    assert _rel(cfg32.bias(qd.float()).double(), cfg64.bias(qd)) < 1e-5
    with pytest.raises(ValueError, match=r"expected joint values \(B, 7\)"):
        ArmTerms(arm).at(q[:, :3])


# ----------------------------------------------------------------------------- properties
PROPERTY_ARMS = ["scara", "test_arm", "ur5", "panda"]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("name", PROPERTY_ARMS)
def test_mass_matrix_symmetric_positive_definite(name, dtype):
    arm = _arm(name)
    q, _ = _states(arm, 2000, seed=1, dtype=dtype)
    payload = torch.rand(2000, generator=torch.Generator().manual_seed(2)).to(dtype) * 5
    m = arm.mass_matrix(q, payload)
    assert m.dtype == dtype and m.shape == (2000, arm.n, arm.n)
    assert torch.equal(m, m.transpose(1, 2))
    assert bool((torch.linalg.eigvalsh(m.double()) > 0).all())


@pytest.mark.parametrize("name", PROPERTY_ARMS)
def test_mdot_minus_2c_skew_and_c_is_christoffel(name):
    arm = _arm(name)
    q, qd = _states(arm, 200, seed=3)
    # dM/dt by forward-mode autograd along qd, independent of mass_matrix_dot.
    mdot = torch.func.jvp(lambda x: arm.mass_matrix(x, 1.5), (q,), (qd,))[1]
    scale = mdot.abs().amax()
    assert (arm.mass_matrix_dot(q, qd, 1.5) - mdot).abs().max() <= 1e-12 * scale
    c = arm.coriolis(q, qd, 1.5)
    n = mdot - 2 * c
    assert (n + n.transpose(1, 2)).abs().max() <= 1e-12 * scale
    # C is the Christoffel matrix: Gamma_ijk = (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i) / 2.
    for qi, qdi in zip(q[:4], qd[:4]):
        dm = torch.func.jacfwd(lambda x: arm.mass_matrix(x[None], 1.5)[0])(qi)  # (n, n, n)
        gamma = 0.5 * (dm + dm.transpose(1, 2) - dm.permute(2, 0, 1))
        ref = gamma @ qdi
        assert (arm.coriolis(qi[None], qdi[None], 1.5)[0] - ref).abs().max() <= 1e-12 * scale


@pytest.mark.parametrize("name", PROPERTY_ARMS)
def test_energy_conserved_without_gravity(name):
    arm = _arm(name, gravity=0.0)
    q, qd = _states(arm, 8, seed=4)
    assert torch.equal(arm.gravity(q), torch.zeros_like(q))

    def f(x):
        p, v = x
        m, b = arm.dynamics(p, v, 1.0)
        return v, torch.linalg.solve(m, -b)

    e0 = arm.kinetic_energy(q, qd, 1.0)
    dt, x = 1e-3, (q, qd)
    for _ in range(500):  # 0.5 s of RK4
        k1 = f(x)
        k2 = f(tuple(a + 0.5 * dt * k for a, k in zip(x, k1)))
        k3 = f(tuple(a + 0.5 * dt * k for a, k in zip(x, k2)))
        k4 = f(tuple(a + dt * k for a, k in zip(x, k3)))
        x = tuple(a + dt / 6 * (p1 + 2 * p2 + 2 * p3 + p4) for a, p1, p2, p3, p4 in zip(x, k1, k2, k3, k4))
    drift = ((arm.kinetic_energy(*x, 1.0) - e0).abs() / e0).max()
    assert drift < 1e-8, drift


@pytest.mark.parametrize("name", PROPERTY_ARMS)
def test_gravity_is_gradient_of_potential_energy(name):
    arm = _arm(name)
    q, _ = _states(arm, 100, seed=5)
    payload = torch.linspace(0.0, 4.0, 100, dtype=torch.float64)
    q.requires_grad_(True)
    (grad,) = torch.autograd.grad(arm.potential_energy(q, payload).sum(), q)
    g = arm.gravity(q.detach(), payload)
    assert (g - grad).abs().max() <= 1e-12 * g.abs().max()


def test_potential_energy_is_sum_of_m_g_z():
    # The SCARA: links 1 and 2 move in the plane z = 0; m3 plus payload sits at z = -q3.
    arm = load_arm("scara")
    q = torch.tensor([[0.3, -1.0, 0.7]], dtype=torch.float64)
    assert torch.allclose(arm.potential_energy(q, 2.0), torch.tensor([-(0.5 + 2.0) * 9.8 * 0.7], dtype=torch.float64))


def test_inverse_dynamics_payloads_shapes_and_dtypes():
    text, end = _source("test_arm")
    arm = load_arm(text, end)
    q, qd = _states(arm, 6, seed=6)
    qdd = torch.randn(6, arm.n, dtype=torch.float64)
    m, b = arm.dynamics(q, qd, 2.0)
    assert torch.allclose(m, arm.mass_matrix(q, 2.0), atol=0, rtol=0)
    assert torch.allclose(b, arm.bias(q, qd, 2.0), atol=0, rtol=0)
    tau = arm.inverse_dynamics(q, qd, qdd, 2.0)
    assert torch.allclose(tau, (m @ qdd.unsqueeze(-1)).squeeze(-1) + b, atol=1e-12, rtol=1e-12)
    # A (B,) payload is the per-state float payload.
    payload = torch.tensor([0.0, 0.5, 1.0, 2.0, 3.0, 4.0], dtype=torch.float64)
    rows = torch.cat([arm.bias(q[i : i + 1], qd[i : i + 1], float(p)) for i, p in enumerate(payload)])
    assert torch.allclose(arm.bias(q, qd, payload), rows, atol=1e-12, rtol=0)
    # Any leading batch shape; float32 inputs give float32 outputs close to float64.
    c2 = arm.coriolis(q.reshape(2, 3, -1), qd.reshape(2, 3, -1))
    assert c2.shape == (2, 3, arm.n, arm.n)
    assert torch.allclose(c2.reshape(6, arm.n, arm.n), arm.coriolis(q, qd))
    m32 = arm.mass_matrix(q.float(), 2.0)
    assert m32.dtype == torch.float32 and torch.allclose(m32.double(), m, rtol=1e-5, atol=1e-6)


def test_lumping_does_not_depend_on_the_end_link_past_the_last_joint():
    text, _ = _source("test_arm")
    q, qd = _states(load_arm(text, TEST_END), 5, seed=9)
    flange, tool = load_arm(text, "flange"), load_arm(text, "tool")
    assert flange.joint_names == tool.joint_names == ["j1", "j2", "slide", "wrist"]
    assert torch.allclose(flange.mass_matrix(q), tool.mass_matrix(q), atol=1e-14, rtol=0)
    assert torch.allclose(flange.bias(q, qd), tool.bias(q, qd), atol=1e-13, rtol=0)
    # The payload at another link: a point mass at a finger's origin (held at zero).
    finger = load_arm(text, TEST_END, payload_link="finger_a")
    assert not torch.allclose(finger.gravity(q, 1.0), flange.gravity(q, 1.0))


def test_loader_errors():
    text, _ = _source("test_arm")
    with pytest.raises(ValueError, match=r"URDF text: end_link 'nope' is not a link.*'flange'"):
        load_arm(text, "nope")
    with pytest.raises(ValueError, match="payload link 'ghost' is not a link"):
        load_arm(text, TEST_END, payload_link="ghost")
    for kind in ("floating", "planar"):
        bad = text.replace('name="j2" type="revolute"', f'name="j2" type="{kind}"')
        with pytest.raises(ValueError, match=f"joint 'j2' on the chain.*'{kind}'"):
            load_arm(bad, TEST_END)
    # An unsupported joint off the chain is held at zero like any other.
    load_arm(text.replace('"finger_a_joint" type="prismatic"', '"finger_a_joint" type="floating"'), TEST_END)
    with pytest.raises(ValueError, match="end_link=None is allowed for a preset only; allowed for URDF text: one"):
        load_arm(text)
    with pytest.raises(
        ValueError,
        match=r"name_or_urdf='no_such_robot' is neither a preset nor URDF text; allowed: "
        r"scara, ur5, panda, the URDF's text or bytes, or a pathlib\.Path",
    ):
        load_arm("no_such_robot")
    with pytest.raises(TypeError, match=r"urdf=42 is a int; allowed: a pathlib\.Path"):
        load_arm(42, TEST_END)


_UR5_WRIST3 = 'ixx="0.00039459" ixy="0" ixz="0" iyy="0.00039459" iyz="0" izz="0.00033822"'
_UR5_FOREARM = 'ixx="0.004194" ixy="0" ixz="0" iyy="0.050638666667" iyz="0" izz="0.050638666667"'
_UR5_BASE = 'ixx="0.004433333333" ixy="0" ixz="0" iyy="0.004433333333" iyz="0" izz="0.0072"'
_NO_INERTIA = 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'


@pytest.mark.parametrize(
    "changes,message",
    [
        (  # the last link massless: its joint moves nothing, M(q) is singular
            [('<mass value="0.1879"/>', '<mass value="0"/>'), (_UR5_WRIST3, _NO_INERTIA)],
            r"joint 'wrist_3_joint' moves no mass or inertia: the mass matrix M\(q\) is singular .*"
            r"\['wrist_3_link', 'tool0', 'ee_link'\]",
        ),
        (  # a URDF without inertials
            [("<inertial>", "<!--"), ("</inertial>", "-->")],
            r"joint 'shoulder_pan_joint' moves no mass or inertia",
        ),
        (
            [(_UR5_FOREARM, _UR5_FOREARM.replace('ixx="0.004194"', 'ixx="-0.004194"'))],
            r"link 'forearm_link' has an <inertia> with principal moments \[-0.004194, 0.05064, 0.05064\] kg m\^2, "
            r"one below 0 \(not positive semi-definite\) \(the body that joint 'elbow_joint' moves\); allowed: "
            r"principal moments >= 0, each at most the sum of the other two",
        ),
        (
            [(_UR5_FOREARM, _UR5_FOREARM.replace('izz="0.050638666667"', 'izz="0.5"'))],
            r"link 'forearm_link' has an <inertia> with .* the largest above the sum of the other two",
        ),
        (
            [('<mass value="2.33"/>', '<mass value="1e30"/>')],
            r"link 'forearm_link' \(moved by joint 'elbow_joint'\) has mass 1e\+30 kg; allowed: a mass in "
            r"\[0, 1e\+06\] kg",
        ),
        ([('<mass value="2.33"/>', '<mass value="-2.33"/>')], r"link 'forearm_link' .* has mass -2.33 kg"),
    ],
)
def test_unusable_inertials_are_named_and_no_closed_loop_runs_on_them(changes, message):
    """What the closed loop cannot simulate is named, link or joint, value and what is allowed:
    `Arm.problems`; the URDF backend (ArmTerms) and the control part refuse it before any step (no raw `linalg`
    error halfway through), while the kinematics still load."""
    from rbfn.config import ControlConfig, RobotConfig
    from rbfn.control.robot_setup import control_robot
    from rbfn.robots.arm_terms import ArmTerms
    from rbfn.robots.kinematics import load_serial_chain

    text = read_urdf(urdf_path("ur5"))
    for old, new in changes:
        assert old in text
        text = text.replace(old, new)
    arm = load_arm(text, "ee_link")
    assert len(arm.problems) >= 1 and re.search(message, arm.problems[0]), arm.problems
    with pytest.raises(ValueError, match="the closed loop cannot simulate this arm's dynamics: " + message):
        ArmTerms(arm)
    robot = RobotConfig(name="ur5", end_link="ee_link", target="pose", joint_low=[-1.0] * 6, joint_high=[1.0] * 6)
    with pytest.raises(ValueError, match="the closed loop cannot simulate this arm's dynamics: " + message):
        control_robot(robot, ControlConfig(), urdf_text=text)
    load_serial_chain(text, "ee_link")  # the IK needs none of it


def test_massless_frames_and_unphysical_links_that_do_not_move_pass(monkeypatch, caplog):
    """A massless base or tool frame, or a fixed-to-the-root link with an unphysical inertia, leave
    M(q) positive definite: no problem (a root link's inertia is a note). Every shipped arm and
    every example-robot-data arm of these tests passes."""
    text = read_urdf(urdf_path("ur5"))
    arm = load_arm(text.replace(_UR5_BASE, _UR5_BASE.replace('ixx="0.004433333333"', 'ixx="-1"')), "ee_link")
    assert arm.problems == [] and len(arm.notes) == 1
    assert arm.notes[0].startswith("link 'base_link' has an <inertia> with principal moments [-1.0,")
    assert arm.notes[0].endswith("(fixed to the root: no dynamics use it)")
    import logging

    import rbfn.robots.dynamics as dynamics

    monkeypatch.setattr(dynamics, "_WARNED", set())
    with caplog.at_level(logging.WARNING):
        arm.warn_notes(logging.getLogger("test"), "robot.urdf=ur5.urdf")
        load_arm(text.replace(_UR5_BASE, _UR5_BASE.replace('ixx="0.004433333333"', 'ixx="-1"')), "ee_link").warn_notes(
            logging.getLogger("test"), "again"
        )  # the same URDF loaded again (the derivation, each check of the closed loop): said once
    assert caplog.messages == ["robot.urdf=ur5.urdf: " + arm.notes[0]]
    for name in ["scara", "ur5", "panda", "test_arm", *ERD]:
        if name in ERD:
            _erd_urdf(ERD[name][0])  # skips without example-robot-data
        assert _arm(name).problems == [], name


@pytest.mark.parametrize("kind", ["fifo", "file"])
def test_a_string_naming_a_file_is_refused_unopened(tmp_path, kind):
    """A str is a preset's name or URDF text, never a file name, for the dynamics and for MuJoCo
    (a FIFO would block an open, so the loaders run in a child process with a deadline)."""
    path = tmp_path / "arm.urdf"
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.write_text(TEST_URDF)
    out = run_guarded(
        "from rbfn.robots.dynamics import load_arm\nfrom rbfn.robots.mjcf import arm_model\n"
        f"for load in (lambda: load_arm({str(path)!r}, 'flange'), lambda: arm_model({str(path)!r})):\n"
        "    try:\n        load()\n    except ValueError as e:\n        print('ValueError:', e)\n"
    )
    for arg in ("name_or_urdf", "urdf"):
        refused = f"ValueError: {arg}={reprlib.repr(str(path))} is neither a preset nor URDF text; allowed: scara"
        assert refused in out, out


def test_a_fifo_path_is_refused_by_what_it_is(tmp_path):
    fifo = tmp_path / "arm.urdf"
    os.mkfifo(fifo)
    out = run_guarded(
        "from pathlib import Path\nfrom rbfn.config import ControlConfig, RobotConfig\n"
        "from rbfn.control import control_robot\nfrom rbfn.robots.dynamics import load_arm\n"
        f"robot = RobotConfig(name='t', urdf={str(fifo)!r}, end_link='flange')\n"
        f"for load in (lambda: load_arm(Path({str(fifo)!r}), 'flange'),\n"
        "             lambda: control_robot(robot, ControlConfig())):\n"
        "    try:\n        load()\n    except ValueError as e:\n        print('ValueError:', e)\n"
    )
    is_fifo = f"{fifo} is a FIFO, not a regular file; allowed: a regular file"
    assert f"ValueError: {is_fifo}" in out, out
    assert f"ValueError: robot.urdf='{fifo}' (robot.name='t', robot.end_link='flange'): {is_fifo}" in out, out


def test_the_control_path_loads_what_the_kinematics_loads():
    """robot.urdf names a file whose visual textures pytorch-kinematics' URDF parser refuses (the
    iCub): the closed loop's arm is its chain, as the kinematics reads it."""
    from rbfn.config import ControlConfig, RobotConfig
    from rbfn.control import control_robot
    from rbfn.robots import joint_limits, load_serial_chain

    rel, end = ERD["erd_icub"]
    path = _erd_urdf(rel)
    chain = load_serial_chain(path, end)
    low, high = joint_limits(chain)
    robot = RobotConfig(
        name="icub",
        urdf=str(path),
        end_link=end,
        joint_low=(0.75 * low + 0.25 * high).tolist(),
        joint_high=(0.25 * low + 0.75 * high).tolist(),
    )
    setup = control_robot(robot, ControlConfig())
    assert setup.joint_names == chain.get_joint_parameter_names() and setup.n == 10
    q, _ = _states(load_arm(path, end), 4, seed=18)
    assert torch.equal(setup.dynamics.arm.mass_matrix(q), load_arm(path, end).mass_matrix(q))


def test_a_declared_encoding_is_decoded(tmp_path):
    """A latin-1 URDF (declared ISO-8859-1, a link named flangé) gives the same arm from its file,
    its bytes and its decoded text (whose declaration still says ISO-8859-1)."""
    text = TEST_URDF.replace('encoding="utf-8"', 'encoding="ISO-8859-1"').replace('"flange"', '"flangé"')
    path = tmp_path / "arm.urdf"
    path.write_bytes(text.encode("latin-1"))
    ref = load_arm(TEST_URDF, TEST_END)
    q, qd = _states(ref, 5, seed=17)
    for urdf in (path, text.encode("latin-1"), text):
        arm = load_arm(urdf, "flangé")
        assert arm.end_link == "flangé" and arm.joint_names == ref.joint_names
        assert torch.equal(arm.mass_matrix(q, 1.0), ref.mass_matrix(q, 1.0))
        assert torch.equal(arm.bias(q, qd, 1.0), ref.bias(q, qd, 1.0))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_follows_inputs():
    text, end = _source("test_arm")
    arm = load_arm(text, end)
    q, qd = _states(arm, 64, seed=10)
    payload = torch.full((64,), 1.5, device="cuda", dtype=torch.float64)
    m, b = arm.dynamics(q.cuda(), qd.cuda(), payload)
    assert m.is_cuda and b.is_cuda
    assert torch.allclose(m.cpu(), arm.mass_matrix(q, 1.5), atol=1e-12)
    assert torch.allclose(b.cpu(), arm.bias(q, qd, 1.5), atol=1e-12)
