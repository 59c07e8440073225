"""Pose targets: features equal for q and -q, match the rotation matrix, and bad targets are named."""

import numpy as np
import pytest
import torch
from pytorch_kinematics import transforms as tf

from rbfn.targets import TargetFeatures, quaternion_columns


def _unit_quaternions(n, seed=0):
    q = torch.randn(n, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    return q / q.norm(dim=-1, keepdim=True)


def test_columns_are_the_rotation_matrix_and_sign_invariant():
    q = _unit_quaternions(500)
    r = tf.quaternion_to_matrix(q)
    cols = quaternion_columns(q)
    assert torch.allclose(cols, torch.cat([r[:, :, 0], r[:, :, 1]], -1), atol=1e-12)
    assert torch.equal(quaternion_columns(-q), cols)


def test_pose_features_scale_rotation_against_metres():
    f = TargetFeatures(pose=True, rotation_scale=0.5)
    x = torch.cat([torch.randn(4, 3, dtype=torch.float64), _unit_quaternions(4)], -1)
    z = f(x)
    assert z.shape == (4, 9) and torch.equal(z[:, :3], x[:, :3])
    assert torch.allclose(z[:, 3:6].norm(dim=-1), torch.full((4,), 0.5, dtype=torch.float64))


@pytest.mark.parametrize(
    "pose,x,err,match",
    [
        (True, torch.zeros(2, 3), ValueError, r"poses \(B, 7\).*got shape \(2, 3\).*position and quaternion"),
        (True, torch.tensor([[0.0, 0, 0, 1.0, 0.1, 0, 0]]), ValueError, "unit length.*row 0 has norm 1.00499"),
        (False, torch.zeros(3), ValueError, r"positions \(B, 3\) in m; got shape \(3,\)"),
        (False, torch.zeros(4, 2), ValueError, r"got shape \(4, 2\)"),
        (False, [[1.0, 2.0, 3.0]], TypeError, "got list"),
        (False, torch.tensor([[0.0, float("nan"), 1.0]]), ValueError, "non-finite values .first at row 0"),
        (False, torch.zeros(2, 3, dtype=torch.long), TypeError, "floating point"),
    ],
)
def test_bad_targets_are_named(pose, x, err, match):
    with pytest.raises(err, match=match):
        TargetFeatures(pose=pose).check(x)


def test_numpy_targets_are_accepted():
    x = TargetFeatures().check(np.zeros((5, 3)))
    assert isinstance(x, torch.Tensor) and x.shape == (5, 3)
