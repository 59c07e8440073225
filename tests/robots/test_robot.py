"""The IK's rule on the arm (its free joints no more than its targets' degrees of freedom), the
rotation vector and angle between rotations, and `Robot.frame` against the poses and Jacobians."""

import math

import pytest
import torch
from pytorch_kinematics import transforms as tf

from rbfn.config import ROBOT_PRESETS
from rbfn.robots.robot import check_ik_is_function, load_robot, rotation_error_deg, rotation_vector

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


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_rotation_error_is_the_angle_between_the_rotations(dtype):
    g = torch.Generator().manual_seed(2)
    base = tf.quaternion_to_matrix(
        torch.nn.functional.normalize(torch.randn(300, 4, generator=g, dtype=torch.float64), dim=-1)
    )
    axis = torch.nn.functional.normalize(torch.randn(300, 3, generator=g, dtype=torch.float64), dim=-1)
    angle = torch.rand(300, generator=g, dtype=torch.float64) * math.pi
    angle[:50] = angle[:50] * 1e-6  # tiny, where the tolerances sit
    angle[50:60] = math.pi - angle[50:60] * 1e-6  # within a micro-radian of half a turn
    turn = tf.quaternion_to_matrix(tf.axis_angle_to_quaternion(axis * angle[:, None]))
    deg = rotation_error_deg((base @ turn).to(dtype), base.to(dtype)).double()
    err = (deg - torch.rad2deg(angle)).abs()
    if dtype == torch.float64:
        assert float(err[:50].max()) < 1e-12 and float(err[50:60].max()) < 1e-4 and float(err[60:].max()) < 1e-9
    else:
        assert float(err[:50].max()) < 1e-4 and float(err[60:].max()) < 1e-3


@pytest.mark.parametrize(
    "name, locked",
    [
        ("ur5", ()),
        (
            "panda",
            (
                "robot.redundancy=",
                "+robot.locked.panda_joint3=0.3",
                "robot.joint_low=[-1,-1.7,-3,-1,0.6,-0.2]",
                "robot.joint_high=[1,0.2,-1.4,1,2.5,1.7]",
            ),
        ),
    ],
)
def test_frame_is_the_pose_and_task_jacobian_in_the_joints_dtype(name, locked):
    robot = load_robot(compose_config("train", f"robot={name}", *locked).robot)
    g = torch.Generator().manual_seed(3)
    q = robot.low + (robot.high - robot.low) * torch.rand(64, len(robot.joint_names), generator=g, dtype=torch.float64)
    jac, pose = robot.jacobian(q), robot.pose(q)
    for dtype, tol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        frame = robot.frame(q.to(dtype), jacobian=True)
        assert frame.rot.dtype == frame.pos.dtype == frame.jac.dtype == dtype
        assert torch.allclose(frame.rot.double(), pose[:, :3, :3], atol=tol)
        assert torch.allclose(frame.pos.double(), pose[:, :3, 3], atol=tol)
        assert torch.allclose(frame.jac.double(), jac, atol=tol)
    assert robot.frame(q).jac is None
