"""The IK's rule on the arm: its free joints no more than its targets' degrees of freedom."""

import math

import pytest
import torch
from pytorch_kinematics import transforms as tf

from rbfn.config import ROBOT_PRESETS
from rbfn.robots.robot import check_ik_is_function, load_robot, rotation_vector

from ..conftest import compose_config


def test_a_redundant_pose_arm_is_told_to_lock_a_joint_or_give_it_as_an_input():
    with pytest.raises(
        ValueError, match=r"robot\.target=pose has 6 .* 7 free joints .* lock 1 of them .*robot\.redundancy=NAME$"
    ):
        check_ik_is_function("pose", [f"j{i}" for i in range(7)], {})
    check_ik_is_function("pose", [f"j{i}" for i in range(7)], {}, redundancy="j2")
    with pytest.raises(
        ValueError, match=r"robot\.target=pose with robot\.redundancy=j2 has 7 .* 8 free joints .* lock 1"
    ):
        check_ik_is_function("pose", [f"j{i}" for i in range(8)], {}, redundancy="j2")


@pytest.mark.parametrize("name", ROBOT_PRESETS)
def test_every_shipped_robot_passes(name):
    cfg = compose_config("train", f"robot={name}")
    check_ik_is_function(cfg.robot.target, load_robot(cfg.robot).joint_names, cfg.robot.locked, cfg.robot.redundancy)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_rotation_vector_is_the_axis_angle_up_to_half_a_turn(dtype):
    g = torch.Generator().manual_seed(1)
    axis = torch.nn.functional.normalize(torch.randn(400, 3, generator=g, dtype=torch.float64), dim=-1)
    angle = torch.rand(400, 1, generator=g, dtype=torch.float64) * math.pi
    angle[:100] = math.pi - angle[:100] * 1e-7  # within 1e-7 rad of half a turn, where the skew part vanishes
    angle[100] = 0.0
    angle[101] = math.pi / 2
    r = tf.quaternion_to_matrix(tf.axis_angle_to_quaternion(axis * angle)).to(dtype)
    v = rotation_vector(r).double()
    tol = 1e-9 if dtype == torch.float64 else 1e-5
    # at half a turn the axis and its opposite are the same rotation
    err = torch.minimum((v - axis * angle).norm(dim=-1), (v + axis * angle).norm(dim=-1))
    assert float(err[100:].max()) < tol and float(err[:100].max()) < 10 * tol
    back = tf.quaternion_to_matrix(tf.axis_angle_to_quaternion(v))
    assert torch.allclose(back, r.double(), atol=10 * tol)
