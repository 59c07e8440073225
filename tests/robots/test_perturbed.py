"""The real robot of the online scenario: a chain with scaled links and offset joints, against
pytorch-kinematics on the URDF (unperturbed, and with the same changes written into the URDF
text) and against the SCARA's closed form."""

import re

import pytest
import torch

from rbfn.control.task_space import RealRobot
from rbfn.robots import forward_kinematics_pose, load_serial_chain, urdf_path
from rbfn.robots.dynamics import load_arm
from rbfn.robots.perturbed import PerturbedChain
from rbfn.robots.scara import ScaraClosedForm

from ..conftest import compose_config


def _joints(robot: str, n: int, seed: int = 0) -> torch.Tensor:
    cfg = compose_config("train", f"robot={robot}").robot
    low, high = torch.tensor(cfg.joint_low, dtype=torch.float64), torch.tensor(cfg.joint_high, dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    q = low + (high - low) * torch.rand(n, low.shape[0], generator=g, dtype=torch.float64)
    names = load_arm(robot).joint_names
    full = torch.zeros(n, len(names), dtype=torch.float64)  # locked joints held at their value
    free = [i for i, j in enumerate(names) if j not in cfg.locked]
    full[:, free] = q
    for j, v in cfg.locked.items():
        full[:, names.index(j)] = v
    return full


@pytest.mark.parametrize("robot,end", [("ur5", "ee_link"), ("panda", "panda_hand"), ("scara", "quill")])
def test_unperturbed_chain_is_the_urdf(robot, end):
    arm = load_arm(robot)
    q = _joints(robot, 64)
    rot, pos = PerturbedChain(
        arm, torch.zeros(64, 0, dtype=torch.float64), torch.zeros(64, arm.n, dtype=torch.float64)
    ).pose(q)
    ref = forward_kinematics_pose(load_serial_chain(urdf_path(robot), end, torch.float64), q)
    assert torch.allclose(pos, ref[:, :3, 3], atol=1e-12, rtol=0)
    assert torch.allclose(rot, ref[:, :3, :3], atol=1e-12, rtol=0)


def _scaled_origin(urdf: str, joint: str, factor: float) -> str:
    """The URDF text with the xyz of `joint`'s origin scaled by factor."""
    block = re.search(rf'<joint name="{joint}".*?</joint>', urdf, re.S).group(0)
    xyz = re.search(r'xyz="([^"]*)"', block).group(1)
    scaled = " ".join(repr(float(v) * factor) for v in xyz.split())
    return urdf.replace(block, block.replace(f'xyz="{xyz}"', f'xyz="{scaled}"'))


def test_perturbed_ur5_equals_the_edited_urdf():
    """Link 2 (elbow_joint's origin, the upper arm) +5 %, link 6 (the end link's fixed origin)
    -10 %, and joint offsets: the same as pytorch-kinematics on a URDF with those origins."""
    arm = load_arm("ur5")
    text = urdf_path("ur5").read_text()
    text = _scaled_origin(_scaled_origin(text, "elbow_joint", 1.05), "ee_fixed_joint", 0.9)
    offset = torch.tensor([0.02, -0.01, 0.0, 0.03, 0.0, -0.05], dtype=torch.float64)
    q = _joints("ur5", 50, seed=1)
    link = torch.tensor([[0.0, 0.05, 0.0, 0.0, 0.0, -0.1]], dtype=torch.float64).expand(50, -1)
    rot, pos = PerturbedChain(arm, link, offset.expand(50, -1)).pose(q)
    ref = forward_kinematics_pose(load_serial_chain(text, "ee_link", torch.float64), q + offset)
    assert torch.allclose(pos, ref[:, :3, 3], atol=1e-12, rtol=0)
    assert torch.allclose(rot, ref[:, :3, :3], atol=1e-12, rtol=0)
    # and the change is not nothing: the upper arm is 0.425 m
    unperturbed = forward_kinematics_pose(load_serial_chain(urdf_path("ur5"), "ee_link", torch.float64), q)
    assert (pos - unperturbed[:, :3, 3]).norm(dim=-1).min() > 1e-3


def test_perturbed_scara_equals_the_closed_form():
    """Per environment link errors and offsets (batched) against the SCARA's own FK formula."""
    arm = load_arm("scara")
    g = torch.Generator().manual_seed(2)
    link = torch.randn(5, 2, generator=g, dtype=torch.float64) * 0.05
    offset = torch.randn(5, 3, generator=g, dtype=torch.float64) * 0.03
    q = _joints("scara", 7 * 5).view(7, 5, 3)  # (T, B, n)
    _, pos = PerturbedChain(arm, link, offset).pose(q)
    assert torch.allclose(pos, RealRobot(ScaraClosedForm(), link, offset).fk(q), atol=1e-12, rtol=0)


def test_bad_shapes_are_named():
    arm = load_arm("scara")
    with pytest.raises(ValueError, match=r"link errors of shape \(2, 4\): need \(R, L\) with L <= 3"):
        PerturbedChain(arm, torch.zeros(2, 4, dtype=torch.float64), torch.zeros(2, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"joint offsets of shape \(2, 2\): need \(2, 3\)"):
        PerturbedChain(arm, torch.zeros(2, 1, dtype=torch.float64), torch.zeros(2, 2, dtype=torch.float64))
