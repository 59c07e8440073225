"""The IK's rule on the arm: its free joints no more than its targets' degrees of freedom."""

import pytest

from rbfn.config import ROBOT_PRESETS
from rbfn.robots.robot import check_ik_is_function, load_robot

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
