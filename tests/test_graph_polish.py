"""rbfn.graph_polish's pieces written out for the exporters: the rotation vector of a rotation
below half a turn is the axis times the angle it was made from (the polish's end-to-end agreement with the solver: tests/studies/test_charted_runs.py)."""

import torch
from pytorch_kinematics import transforms as tf

from rbfn.graph_polish import _rotation_vector


def test_rotation_vector_is_the_axis_angle():
    g = torch.Generator().manual_seed(1)
    axis = torch.nn.functional.normalize(torch.randn(200, 3, generator=g, dtype=torch.float64), dim=-1)
    angle = torch.rand(200, 1, generator=g, dtype=torch.float64) * 3.0  # below half a turn
    angle[0] = 0.0
    r = tf.quaternion_to_matrix(tf.axis_angle_to_quaternion(axis * angle))
    assert torch.allclose(_rotation_vector(r), axis * angle, atol=1e-9)
