"""The controllers' nominal model: M_hat = 0.9 M, C_hat = 0.8 C, G_hat = 0.85 G of the unloaded
robot, evaluated at a state (q, qd) (B, n).

`model.at(q, qd)` gives what a controller asks of its model at one control period:
`m_times(v)` = M_hat(q) v, `c_times(y)` = C_hat(q, qd) y, `gravity()` = G_hat(q) and
`momentum_rate()` = dM_hat/dt qd - C_hat qd - G_hat (the momentum observer's known part), each
(B, n). `ArmModel` serves any URDF arm through `rbfn.robots.arm_terms` (C the Christoffel matrix,
so dM/dt = C + C^T); `NominalModel` is the SCARA's closed form (elementwise, no matrices), which
`rbfn.robots.registry` chooses for exactly the packaged scara.urdf.
"""

from __future__ import annotations

import torch

from ..robots.arm_scalar import ArmScalarTerms
from ..robots.arm_terms import ArmTerms
from ..robots.dynamics import Arm
from ..robots.scara import ScaraParams, c_times, inertia_params, joint_vector, m_times, mass_entries

__all__ = ["NominalModel", "ArmModel"]


class NominalModel:
    """The SCARA's nominal model: scaled M, C and G of the robot carrying `payload` kg (0: the
    unloaded robot, the paper's), in closed form."""

    def __init__(
        self,
        params: ScaraParams = ScaraParams(),
        m_scale: float = 0.9,
        c_scale: float = 0.8,
        g_scale: float = 0.85,
        payload: float = 0.0,
    ) -> None:
        p1, p2, p3, m3 = inertia_params(payload, params)
        self.n = 3
        self.m_co = (m_scale * p1, m_scale * p2, m_scale * p3, m_scale * m3)
        self.c_co = (0.0, c_scale * p2, 0.0, 0.0)
        self.g3 = -g_scale * m3 * params.g
        self._gravity: dict = {}

    def gravity(self, q: torch.Tensor) -> torch.Tensor:
        """G_hat (3,): the same at every q (only the prismatic joint carries weight); broadcasts
        against (B, 3). One tensor per dtype and device, made once."""
        if torch.compiler.is_compiling():  # a constant of the graph; a cache would be a guard
            return torch.tensor([0.0, 0.0, self.g3], dtype=q.dtype, device=q.device)
        key = (q.dtype, q.device)
        if key not in self._gravity:
            self._gravity[key] = torch.tensor([0.0, 0.0, self.g3], dtype=q.dtype, device=q.device)
        return self._gravity[key]

    def at(self, q: torch.Tensor, qd: torch.Tensor) -> _ScaraAt:
        return _ScaraAt(self, q, qd)


class _ScaraAt:
    """The model at one state; what several terms share (M's entries) is computed once."""

    def __init__(self, model: NominalModel, q: torch.Tensor, qd: torch.Tensor) -> None:
        self.model, self.q, self.qd = model, q, qd
        self.s2, self.c2 = torch.sin(q[..., 1]), torch.cos(q[..., 1])
        self._entries: tuple | None = None

    def m_times(self, v: torch.Tensor) -> torch.Tensor:
        if self._entries is None:
            self._entries = mass_entries(self.c2, self.model.m_co)
        return m_times(self.c2, self.model.m_co, v, self._entries)

    def c_times(self, y: torch.Tensor) -> torch.Tensor:
        return c_times(self.s2, self.model.c_co, self.qd, y)

    def gravity(self) -> torch.Tensor:
        return self.model.gravity(self.q)

    def momentum_rate(self) -> torch.Tensor:
        # dM_hat/dt qd - C_hat qd - G_hat by component, with a = m_p2 and c = c_p2 (the models'
        # cos q2 coefficients in M and C): dM/dt qd = -a s2 qd2 (2 qd1 + qd2, qd1, 0) and
        # C qd = c s2 (-qd2 (2 qd1 + qd2), qd1^2, 0).
        m = self.model
        a, c = m.m_co[1], m.c_co[1]
        qd1, qd2, _ = self.qd.unbind(-1)
        r1 = torch.add(qd2, qd1, alpha=2.0) * qd2 * (self.s2 * (c - a))
        r2 = (self.s2 * qd1) * torch.add(qd2 * -a, qd1, alpha=-c)
        return joint_vector([r1, r2, torch.full_like(r1, -m.g3)])


class ArmModel:
    """The nominal model of a URDF arm (`Arm`, or its `ArmTerms`), carrying `payload` kg (0: none)."""

    def __init__(
        self,
        arm: Arm | ArmTerms,
        m_scale: float = 0.9,
        c_scale: float = 0.8,
        g_scale: float = 0.85,
        payload: float = 0.0,
    ) -> None:
        self.terms = arm if isinstance(arm, ArmTerms) else ArmTerms(arm)
        self.n = self.terms.n
        self.m_scale, self.c_scale, self.g_scale = m_scale, c_scale, g_scale
        self.payload = payload  # kg at the arm's payload link (0: the unloaded robot)
        self.scalar_terms = ArmScalarTerms(self.terms)  # built eagerly: tracing stays on tensors of B

    def dynamics_terms(self) -> ArmTerms | ArmScalarTerms:
        """The batch-last terms eagerly; their scalar form while torch.compile traces (it fuses)."""
        return self.scalar_terms if torch.compiler.is_compiling() else self.terms

    def at(self, q: torch.Tensor, qd: torch.Tensor) -> _ArmAt:
        return _ArmAt(self, q, qd)


class _ArmAt:
    def __init__(self, model: ArmModel, q: torch.Tensor, qd: torch.Tensor) -> None:
        self.model, self.qd = model, qd
        self.cfg = model.dynamics_terms().at(q, model.payload) if model.payload else model.dynamics_terms().at(q)
        self._mo = None

    def _motion(self):
        if self._mo is None:
            self._mo = self.cfg.motion(self.qd)
        return self._mo

    def m_times(self, v: torch.Tensor) -> torch.Tensor:
        return self.model.m_scale * self.cfg.mass_times(v)

    def c_times(self, y: torch.Tensor) -> torch.Tensor:
        return self.model.c_scale * self.cfg.coriolis_times(self.qd, y, self._motion())

    def gravity(self) -> torch.Tensor:
        return self.model.g_scale * self.cfg.gravity()

    def momentum_rate(self) -> torch.Tensor:
        # dM/dt qd = C qd + C^T qd for the Christoffel C.
        m, mo = self.model, self._motion()
        cqd = self.cfg.coriolis_qd(self.qd, mo)
        ctq = self.cfg.coriolis_transpose_qd(self.qd, mo)
        return m.m_scale * (cqd + ctq) - m.c_scale * cqd - self.gravity()
