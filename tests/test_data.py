"""Data streams: an evaluation set never repeats a training, validation or test set."""

import torch

from rbfn.data import EVALUATION, FULL_RANGE, TRAIN_VAL_TEST, evaluation_split, make_dataset, stream
from rbfn.robots.robot import load_robot

from .conftest import compose_config


def test_evaluation_streams_never_coincide_with_training_streams():
    seeds = [*list(range(0, 50)), 4242, 2**32 - 1]
    training = {stream(s, k) for s in seeds for k in TRAIN_VAL_TEST}
    assert not training & {stream(s, EVALUATION) for s in seeds}
    assert len({stream(s, k) for s in seeds for k in (*TRAIN_VAL_TEST, EVALUATION, *FULL_RANGE)}) == 6 * len(seeds)


def test_evaluation_set_of_the_training_seed_shares_no_sample(scara_robot):
    data = make_dataset(scara_robot, (200, 100, 100), seed=0)
    ev = evaluation_split(scara_robot, 100, seed=0)
    for split in (data.train, data.val, data.test):
        assert not torch.isclose(ev.q[:, None], split.q[None]).all(-1).any()


def test_the_full_range_split_spans_the_urdf_limits_beyond_the_box():
    from rbfn.data import full_range_split
    from rbfn.robots.kinematics import joint_limits

    robot = load_robot(compose_config("train", "robot=ur5").robot)
    split = full_range_split(robot, 2000, seed=0)
    low, high = (t[robot.free] for t in joint_limits(robot.chain))
    assert bool(((split.q >= low) & (split.q <= high)).all())
    outside = (split.q < robot.low) | (split.q > robot.high)
    assert float(outside.any(-1).double().mean()) > 0.99  # almost every sample leaves the trained box
    assert float((split.q.amax(0) - split.q.amin(0)).min()) > 0.9 * float((high - low).min())
    assert torch.allclose(robot.inputs(split.q), split.x)
    again, evaluation = full_range_split(robot, 2000, seed=0), full_range_split(robot, 2000, 0, evaluation=True)
    assert torch.equal(again.q, split.q) and not torch.equal(evaluation.q, split.q)
