"""Desired joint trajectories, precomputed on the whole time grid (no per-step Python work)."""

from __future__ import annotations

from typing import NamedTuple

import torch

__all__ = ["Reference", "paper_trajectory", "sinusoid_trajectory", "FREQUENCY_PAIRS"]


class Reference(NamedTuple):
    """Desired joints q_d, velocities qd_d and accelerations qdd_d (rad or m, per s, per s^2):
    each (T, n) on a time grid, or one control period's (n,) or, per environment, (B, n). A
    NamedTuple, so a pytree node: torch.compile and torch.export take it as it is."""

    q_d: torch.Tensor
    qd_d: torch.Tensor
    qdd_d: torch.Tensor

    def to(self, **kw) -> Reference:
        """Each tensor `.to(**kw)` (dtype, device)."""
        return Reference(*(r.to(**kw) for r in self))


# The paper's frequency pairs (rad/s), joint j takes pair j mod 3: every joint repeats within 2 pi s.
FREQUENCY_PAIRS = ((1.0, 2.0), (2.0, 3.0), (3.0, 4.0))


def paper_trajectory(t: torch.Tensor) -> Reference:
    """The paper's desired joints, velocities and accelerations, each (T, 3), at times t (T,) in s.

    q_d1 = 1 + 0.1 (sin t + sin 2t), q_d2 = 1 + 0.1 (cos 2t + cos 3t), q_d3 = 1 + 0.1 (sin 3t + sin 4t)
    (rad, rad, m).
    """
    s, c = torch.sin, torch.cos
    q = torch.stack([1 + 0.1 * (s(t) + s(2 * t)), 1 + 0.1 * (c(2 * t) + c(3 * t)), 1 + 0.1 * (s(3 * t) + s(4 * t))], -1)
    qd = torch.stack(
        [0.1 * (c(t) + 2 * c(2 * t)), -0.1 * (2 * s(2 * t) + 3 * s(3 * t)), 0.1 * (3 * c(3 * t) + 4 * c(4 * t))], -1
    )
    qdd = torch.stack(
        [-0.1 * (s(t) + 4 * s(2 * t)), -0.1 * (4 * c(2 * t) + 9 * c(3 * t)), -0.1 * (9 * s(3 * t) + 16 * s(4 * t))], -1
    )
    return Reference(q, qd, qdd)


def sinusoid_trajectory(t: torch.Tensor, home: torch.Tensor, amplitude: torch.Tensor) -> Reference:
    """q_d_j(t) = home_j + a_j (sin w1 t + sin w2 t) with (w1, w2) = FREQUENCY_PAIRS[j mod 3], and
    its analytic velocity and acceleration, each (T, n), at times t (T,) s; home, amplitude (n,)
    in rad or m (amplitude 0: the joint is held at home)."""
    n = home.shape[0]
    w = torch.tensor([FREQUENCY_PAIRS[j % 3] for j in range(n)], dtype=t.dtype, device=t.device)  # (n, 2)
    wt = t[:, None, None] * w  # (T, n, 2)
    a = amplitude.to(t)
    q = home.to(t) + a * torch.sin(wt).sum(-1)
    qd = a * (w * torch.cos(wt)).sum(-1)
    qdd = -a * (w * w * torch.sin(wt)).sum(-1)
    return Reference(q, qd, qdd)
