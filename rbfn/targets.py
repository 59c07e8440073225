"""IK targets and the network's input features.

Public inputs are positions (B, 3) in m, or poses (B, 7): position in m, then a unit quaternion
(w, x, y, z). Inside, a pose becomes 9 features: the position and the rotation matrix's first two
columns times `rotation_scale` (m), a continuous rotation representation (unlike Euler angles or
the quaternion itself, with its q / -q ambiguity: the matrix is quadratic in q, so q and -q give
the same features). `rotation_scale` sets how many metres one unit of rotation feature weighs in
the Gaussians' distances (0.3 m: a 10 deg turn moves the features as far as about 5 cm).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["TargetFeatures", "quaternion_columns", "UNIT_TOL"]

UNIT_TOL = 1e-3  # |q| may differ from 1 by this much (rounding, float32); farther is an error


def quaternion_columns(quat: torch.Tensor) -> torch.Tensor:
    """First two columns (B, 6) of the rotation matrices of quaternions (B, 4) (w, x, y, z),
    normalised first; the same for q and -q."""
    q = quat / quat.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y + w * z),
            2 * (x * z - w * y),
            2 * (x * y - w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z + w * x),
        ],
        -1,
    )


class TargetFeatures(nn.Module):
    """Targets (B, 3) -> features (B, 3) (identity), or (B, 7) -> (B, 9) for pose targets; with
    `redundancy` (pose targets), (B, 8) -> (B, 10): the pose and a redundant joint's value (rad, or m
    if prismatic), that value times `rotation_scale` as the last feature (a 10 deg turn of the
    joint weighs as much as a 10 deg turn of the end link)."""

    rotation_scale: torch.Tensor  # a buffer, registered for pose targets only

    def __init__(
        self,
        pose: bool = False,
        rotation_scale: float = 0.3,
        dtype: torch.dtype = torch.float64,
        device: str | torch.device = "cpu",
        redundancy: bool = False,
    ) -> None:
        super().__init__()
        if redundancy and not pose:
            raise ValueError("TargetFeatures(redundancy=True) needs pose=True: a redundant joint goes beside a pose")
        self.pose, self.redundancy = pose, redundancy
        if pose:  # position targets carry no state, so their networks' state_dicts stay as they were
            self.register_buffer("rotation_scale", torch.tensor(float(rotation_scale), dtype=dtype, device=device))

    @property
    def in_features(self) -> int:
        return (7 if self.pose else 3) + self.redundancy

    @property
    def out_features(self) -> int:
        return (9 if self.pose else 3) + self.redundancy

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.pose:
            return x
        return torch.cat(
            [x[..., :3], torch.cat([quaternion_columns(x[..., 3:7]), x[..., 7:]], -1) * self.rotation_scale], -1
        )

    def check(self, x) -> torch.Tensor:
        """`x` as a tensor (B, in_features), or ValueError/TypeError saying what is wrong with it:
        the type, the shape, a non-finite value, or a quaternion that is not unit length."""
        if isinstance(x, np.ndarray):
            x = torch.from_numpy(x)
        if not isinstance(x, torch.Tensor):
            raise TypeError(
                f"IK targets must be a torch.Tensor or numpy array of shape (B, {self.in_features}), "
                f"got {type(x).__name__}"
            )
        what = (
            "poses (B, 7): position in m, then a unit quaternion (w, x, y, z)" if self.pose else "positions (B, 3) in m"
        )
        if self.redundancy:
            what = (
                "poses and the redundant joint (B, 8): position in m, a unit quaternion (w, x, y, z), the joint's value"
            )
        if x.dim() != 2 or x.shape[1] != self.in_features:
            hint = " (a pose network takes position and quaternion)" if self.pose and x.shape[-1:] == (3,) else ""
            raise ValueError(f"IK targets must be {what}; got shape {tuple(x.shape)}{hint}")
        if not x.is_floating_point():
            raise TypeError(f"IK targets must be floating point, got {x.dtype}")
        bad = ~torch.isfinite(x).all(-1)
        if bool(bad.any()):
            i = int(bad.nonzero()[0])
            raise ValueError(f"IK targets contain non-finite values (first at row {i}: {x[i].tolist()})")
        if self.pose:
            norm = x[:, 3:7].double().norm(dim=-1)
            off = (norm - 1).abs() > UNIT_TOL
            if bool(off.any()):
                i = int(off.nonzero()[0])
                raise ValueError(
                    f"IK target quaternions must be unit length (w, x, y, z); row {i} has norm "
                    f"{float(norm[i]):.6g} ({x[i, 3:7].tolist()}); normalise it first"
                )
        return x
