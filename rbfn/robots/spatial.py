"""Spatial vector algebra of the rigid-body dynamics, written once for its two forms.

Motion vectors are (angular; linear), force vectors (moment; force), both referred to one point
fixed in space; a spatial inertia about that point is (mass m, first moment h = m c, rotational
inertia J). The products every form needs:

* v x m   (motion cross motion): (w x mw; w x mv + v0 x mw)
* v x* f  (motion cross force):  (w x n + v0 x f0; w x f0)
* I v     (inertia times motion): (J w + h x v0; m v0 - h x w)

`Spatial` writes them once, on pairs (angular, linear) of 3-vectors, given four operations on
the 3-vectors of a layout. The two forms store 3-vectors in layouts that cannot share that
arithmetic, so each brings its own:

* `rbfn.robots.dynamics.Arm`, the specification: batch-first tensors, a spatial vector (..., 6)
  and a 3-vector (..., 3) (`SIX` below: the halves are views, the result one `torch.cat`).
* `rbfn.robots.arm_terms`, the simulator's fast form: batch-last pairs of (n, 3, B), where a
  cross product runs along dim -2 (unrolled into multiply-adds for wide batches) and m v0 - c is
  one fused `addcmul`; eager or compiled.

The order of the floating-point operations below is part of every form's numbers.
"""

from __future__ import annotations

import operator
from collections.abc import Callable
from typing import Any

import torch

__all__ = ["Spatial", "SIX", "cross", "dot", "matvec", "outer"]


class Spatial:
    """v x m, v x* f and I v on pairs (angular, linear) of one layout's 3-vectors.

    cross(a, b): a x b; add(a, b): a + b; matvec(J, w): J w for a rotational inertia J as the
    layout stores it; mul_sub(m, v, c): m v - c for a mass m.
    """

    def __init__(
        self,
        cross: Callable[[Any, Any], Any],
        add: Callable[[Any, Any], Any],
        matvec: Callable[[Any, Any], Any],
        mul_sub: Callable[[Any, Any, Any], Any],
    ) -> None:
        self.cross, self.add, self.matvec, self.mul_sub = cross, add, matvec, mul_sub

    def cross_motion(self, v, m):
        """v x m for motion vectors v, m."""
        return self.cross(v[0], m[0]), self.add(self.cross(v[0], m[1]), self.cross(v[1], m[0]))

    def cross_force(self, v, f):
        """v x* f for a motion vector v and a force vector f."""
        return self.add(self.cross(v[0], f[0]), self.cross(v[1], f[1])), self.cross(v[0], f[1])

    def inertia_times(self, m, h, j, v):
        """I v: the spatial inertia (m, h, J) about the reference point times a motion vector v."""
        w, v0 = v
        return self.add(self.matvec(j, w), self.cross(h, v0)), self.mul_sub(m, v0, self.cross(h, w))


# ----------------------------------------------------------------------------- batch-first tensors
def cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a x b for 3-vectors (..., 3)."""
    return torch.linalg.cross(a, b)


def matvec(a: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """a x (..., 3) for matrices a (..., 3, 3) and vectors x (..., 3)."""
    return (a @ x.unsqueeze(-1)).squeeze(-1)


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a . b (..., 1) for 3-vectors (..., 3)."""
    return (a * b).sum(-1, keepdim=True)


def outer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a b^T (..., 3, 3) for 3-vectors (..., 3)."""
    return a.unsqueeze(-1) * b.unsqueeze(-2)


class _Six(Spatial):
    """The products on spatial vectors (..., 6): on their halves (views), joined by one cat.
    Masses m are (...), first moments h (..., 3), rotational inertias J (..., 3, 3)."""

    def cross_motion(self, v: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
        return torch.cat(super().cross_motion(_halves(v), _halves(m)), -1)

    def cross_force(self, v: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        return torch.cat(super().cross_force(_halves(v), _halves(f)), -1)

    def inertia_times(self, m, h, j, v: torch.Tensor) -> torch.Tensor:
        return torch.cat(super().inertia_times(m, h, j, _halves(v)), -1)


def _halves(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return x[..., :3], x[..., 3:]


SIX = _Six(cross, operator.add, matvec, lambda m, v, c: m.unsqueeze(-1) * v - c)
