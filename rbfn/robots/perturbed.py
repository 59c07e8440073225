"""Forward kinematics of a serial arm whose real links and joint zeros differ from its URDF, batched
over several such arms: the "real" robot of the online adaptation scenario.

Links are counted between moving joints: link k (k = 1..n) runs from joint k's frame to joint
k+1's (to the end link's frame for k = n), fixed joints in between lumped in; the root's placement
of joint 1 (the mounting) is not a link. A link error e_k scales that link's translation by
(1 + e_k) and keeps its rotation; a joint offset is added to the joint's value before the
transform (rad, or m for a prismatic joint). On the SCARA, links 1 and 2 are l1 and l2.
"""

from __future__ import annotations

from typing import Any

import torch

from .dynamics import Arm

__all__ = ["PerturbedChain"]


def _skew(axis: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices (n, 3, 3) of unit axes (n, 3)."""
    k = torch.zeros(*axis.shape[:-1], 3, 3, dtype=axis.dtype, device=axis.device)
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    return k - k.transpose(-1, -2)


class PerturbedChain:
    """End-link poses of R variants of `arm`: link errors (R, L) (relative, L <= n, missing links
    exact) and joint offsets (R, n) for the chain's n moving joints."""

    def __init__(self, arm: Arm, link_error: torch.Tensor, offset: torch.Tensor) -> None:
        placement, axis, prismatic, end = arm.frames()
        kw: dict[str, Any] = {"dtype": link_error.dtype, "device": link_error.device}
        n, r = arm.n, link_error.shape[0]
        if link_error.ndim != 2 or link_error.shape[1] > n:
            raise ValueError(
                f"link errors of shape {tuple(link_error.shape)}: need (R, L) with L <= {n}, "
                f"the links of the chain to {arm.end_link!r}"
            )
        if offset.shape != (r, n):
            raise ValueError(
                f"joint offsets of shape {tuple(offset.shape)}: need ({r}, {n}), one per joint of {arm.joint_names}"
            )
        scale = torch.ones(r, n, **kw)
        scale[:, : link_error.shape[1]] += link_error
        # Link k is the translation of placement k (k = 1..n-1) and of the end frame (k = n).
        frames = torch.cat([placement[1:], end[None]]).to(**kw)  # (n, 4, 4)
        self.base_rot, self.base_pos = placement[0, :3, :3].to(**kw), placement[0, :3, 3].to(**kw)
        self.link_rot = frames[:, :3, :3]  # (n, 3, 3)
        self.link_pos = frames[None, :, :3, 3] * scale[..., None]  # (R, n, 3)
        self.axis, self.prismatic = axis.to(**kw), prismatic.tolist()
        self.skew = _skew(self.axis)  # Rodrigues: I + s K + (1 - c) K^2
        self.skew2 = self.skew @ self.skew
        self.eye = torch.eye(3, **kw)
        self.offset, self.n = offset, n

    def pose(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(rotation (..., R, 3, 3), position (..., R, 3) in m) of the end link at the chain's
        joints q (..., R, n); variant r takes q[..., r, :]."""
        q = q + self.offset
        rot = self.base_rot.expand(*q.shape[:-1], 3, 3)
        pos = self.base_pos.expand(*q.shape[:-1], 3)
        for j in range(self.n):
            if self.prismatic[j]:
                pos = pos + (rot @ self.axis[j]) * q[..., j, None]
            else:
                s, c = torch.sin(q[..., j, None, None]), torch.cos(q[..., j, None, None])
                rot = rot @ (self.eye + s * self.skew[j] + (1 - c) * self.skew2[j])
            pos = pos + (rot @ self.link_pos[:, j, :, None]).squeeze(-1)
            rot = rot @ self.link_rot[j]
        return rot, pos
