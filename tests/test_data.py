"""Data streams: an evaluation set never repeats a training, validation or test set."""

import torch

from rbfn.data import EVALUATION, TRAIN_VAL_TEST, evaluation_split, make_dataset, stream


def test_evaluation_streams_never_coincide_with_training_streams():
    seeds = [*list(range(0, 50)), 4242, 2**32 - 1]
    training = {stream(s, k) for s in seeds for k in TRAIN_VAL_TEST}
    assert not training & {stream(s, EVALUATION) for s in seeds}


def test_evaluation_set_of_the_training_seed_shares_no_sample(scara_robot):
    data = make_dataset(scara_robot, (200, 100, 100), seed=0)
    ev = evaluation_split(scara_robot, 100, seed=0)
    for split in (data.train, data.val, data.test):
        assert not torch.isclose(ev.q[:, None], split.q[None]).all(-1).any()
