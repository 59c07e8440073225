"""The "real" robots of the closed loop: rigid-body dynamics, friction, disturbance and payload,
B environments at once, stepped by RK4 or semi-implicit Euler.

M(q, m_p) qdd + C(q, qd, m_p) qd + G(q, m_p) + F(qd) + tau_d(t) = tau, with per joint j
F_j = viscous_j qd_j + coulomb_j sign(qd_j) (or tanh(qd_j / smooth_velocity)) and
tau_d,j = disturbance_j sin(frequency t) (each environment its own with `Plant.varied`); m_p the
payload (kg, per environment), held within a step like the torque (zero-order hold).

* `ScaraPlant`: the paper's SCARA in closed form (M block diagonal: its inverse a 2x2 one and a
  scalar; a step is a few dozen fused tensor operations), the plant `rbfn.robots.registry`
  chooses for exactly the packaged scara.urdf (`rbfn.robots.scara.ScaraClosedForm.plant`).
* `ArmPlant`: any URDF chain (`rbfn.robots.dynamics.Arm`), M and C qd + G by
  `rbfn.robots.arm_terms` (batch-last CRBA and RNEA; `arm_scalar`, the same in scalar form, while
  torch.compile traces), M qdd = r solved by a batched Cholesky factorisation; the payload a
  point mass at the arm's payload link.

Both give `coefficients(payload)` (what a step needs of the payload schedule, each (T, B)),
`accel(q, qd, tau - tau_d, co)`, `step(...)` and `energy(q, qd, payload)`.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

import torch

from ..config import Friction
from ..robots.arm_scalar import ArmScalarTerms, ScalarConfig
from ..robots.arm_terms import ArmTerms
from ..robots.dynamics import Arm
from ..robots.scara import ScaraParams, inertia_params, m_solve_parts, m_times, minus_c_qd

__all__ = ["Plant", "ScaraPlant", "ArmPlant"]

PerJoint = float | Sequence[float]


class Plant:
    """Friction, disturbance and the integrators; a subclass gives `n`, `coefficients` and `accel`.

    viscous N m s/rad (N s/m), coulomb N m (N), disturbance N m (N): a float for every joint or one
    value per joint; disturbance_freq rad/s; smooth_velocity rad/s (m/s) of the `smooth` friction.
    """

    n: int
    compile_chunk = 25  # control periods per torch.compile'd call (simulate(compile=True))
    # Each environment's own disturbance (`varied`): amplitude (B, n), frequency and phase (B,); None: dist's.
    per_environment: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None

    def __init__(
        self,
        viscous: PerJoint = 12.0,
        coulomb: PerJoint = 0.2,
        friction: str = "sign",
        smooth_velocity: float = 0.01,
        disturbance: PerJoint = 5.0,
        disturbance_freq: float = 2.0,
        gravity: bool = True,
    ) -> None:
        if friction not in tuple(Friction):
            raise ValueError(f"friction={friction!r} is not allowed; choose one of {[str(f) for f in Friction]}")
        if not smooth_velocity > 0:
            raise ValueError(f"smooth_velocity={smooth_velocity} must be > 0 (m/s or rad/s)")
        for key, value in (("viscous", viscous), ("coulomb", coulomb), ("disturbance", disturbance)):
            if not isinstance(value, (int, float)) and len(value) != self.n:
                raise ValueError(f"{key}={list(value)} needs one value per joint ({self.n}) or a single number")
        self.viscous, self.coulomb, self.friction = viscous, coulomb, friction
        self.smooth_velocity, self.dist, self.dist_freq, self.gravity = (
            smooth_velocity,
            disturbance,
            disturbance_freq,
            gravity,
        )
        self._joint_values: dict = {}

    def _per_joint(self, value: PerJoint, like: torch.Tensor):
        """A float as is, a per-joint list as an (n,) tensor in like's dtype and device."""
        if isinstance(value, (int, float)):
            return value
        key = (id(value), like.dtype, like.device)
        if key not in self._joint_values:
            self._joint_values[key] = torch.tensor(list(value), dtype=like.dtype, device=like.device)
        return self._joint_values[key]

    def _coulomb_sign(self, qd: torch.Tensor) -> torch.Tensor:
        return torch.sign(qd) if self.friction == "sign" else torch.tanh(qd / self.smooth_velocity)

    def friction_torque(self, qd: torch.Tensor) -> torch.Tensor:
        return self._per_joint(self.viscous, qd) * qd + self._per_joint(self.coulomb, qd) * self._coulomb_sign(qd)

    def minus_friction(self, r: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """r - F(qd) (B, n): with one viscous and one Coulomb coefficient for every joint, two
        fused x + alpha y operations (a step is overhead-bound at small B)."""
        if not (isinstance(self.viscous, (int, float)) and isinstance(self.coulomb, (int, float))):
            return r - self.friction_torque(qd)
        return torch.add(torch.add(r, qd, alpha=-self.viscous), self._coulomb_sign(qd), alpha=-self.coulomb)

    def disturbance(self, t: torch.Tensor) -> torch.Tensor:
        """Disturbance torque tau_d(t): the shape of t for a single amplitude (every joint feels
        it), else (..., n); per environment (`varied`) (..., B, n); N m (N)."""
        if self.per_environment is not None:  # amplitude (B, n), frequency and phase (B,)
            amplitude, freq, phase = self.per_environment
            return amplitude.to(t) * torch.sin(freq.to(t) * t[..., None] + phase.to(t))[..., None]
        s = torch.sin(self.dist_freq * t)
        if isinstance(self.dist, (int, float)):
            return self.dist * s
        return self._per_joint(self.dist, t) * s.unsqueeze(-1)

    def varied(self, amplitude: torch.Tensor, freq: torch.Tensor, phase: torch.Tensor) -> Plant:
        """This plant with a disturbance of its own in each of B environments,
        tau_d,bj(t) = amplitude[b, j] sin(freq[b] t + phase[b]): amplitude (B, n) N m (N), freq (B,)
        rad/s, phase (B,) rad (the closed-loop tuning's scenarios). A shallow copy: the dynamics
        are shared."""
        plant = copy.copy(self)
        plant.per_environment = (amplitude, freq, phase)
        return plant

    if TYPE_CHECKING:

        def coefficients(self, payload: torch.Tensor) -> tuple[torch.Tensor, ...]:
            """What a step needs of the payload schedule (kg, (T, B)), each (T, B); a subclass's."""

    def accel(self, q, qd, r, co) -> torch.Tensor:
        """Joint accelerations (B, n) under r = tau - tau_d (B, n), the torque less the disturbance."""
        raise NotImplementedError

    def step(
        self,
        q: torch.Tensor,
        qd: torch.Tensor,
        tau: torch.Tensor,
        dist: torch.Tensor,
        dt: float,
        co,
        method: str = "rk4",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """State (q, qd) after dt seconds, torque and payload held; dist: the disturbance torque at
        the step's start, middle and end, tau_d(t), tau_d(t + dt/2), tau_d(t + dt) (3,) or (3, n)."""
        if method == "euler":
            qd = qd + dt * self.accel(q, qd, tau - dist[0], co)
            return q + dt * qd, qd
        # x + h y as one operation (torch.add's alpha): a step is overhead-bound at small B.
        h = 0.5 * dt
        r_mid = tau - dist[1]  # the two middle stages share it
        a1 = self.accel(q, qd, tau - dist[0], co)
        v2 = torch.add(qd, a1, alpha=h)
        a2 = self.accel(torch.add(q, qd, alpha=h), v2, r_mid, co)
        v3 = torch.add(qd, a2, alpha=h)
        a3 = self.accel(torch.add(q, v2, alpha=h), v3, r_mid, co)
        v4 = torch.add(qd, a3, alpha=dt)
        a4 = self.accel(torch.add(q, v3, alpha=dt), v4, tau - dist[2], co)
        q_next = torch.add(q, qd.add(v2, alpha=2.0).add_(v3, alpha=2.0).add_(v4), alpha=dt / 6)
        qd_next = torch.add(qd, a1.add(a2, alpha=2.0).add_(a3, alpha=2.0).add_(a4), alpha=dt / 6)
        return q_next, qd_next


class ScaraPlant(Plant):
    """The paper's SCARA (closed form); parameters in SI units."""

    n = 3

    def __init__(
        self,
        params: ScaraParams = ScaraParams(),
        viscous: PerJoint = 12.0,
        coulomb: PerJoint = 0.2,
        friction: str = "sign",
        smooth_velocity: float = 0.01,
        disturbance: PerJoint = 5.0,
        disturbance_freq: float = 2.0,
        gravity: bool = True,
    ) -> None:
        super().__init__(viscous, coulomb, friction, smooth_velocity, disturbance, disturbance_freq, gravity)
        self.params = params

    def coefficients(self, payload: torch.Tensor):
        """(p1, p2, p3, m3, m3 g or 0 without gravity), each shaped like the payloads (kg)."""
        p1, p2, p3, m3 = inertia_params(payload, self.params)
        return p1, p2, p3, m3, m3 * (self.params.g if self.gravity else 0.0)

    def accel(self, q: torch.Tensor, qd: torch.Tensor, r: torch.Tensor, co) -> torch.Tensor:
        """Joint accelerations (B, 3) under r = tau - tau_d (B, 3), component by component (the
        fewest tensor operations: a step is overhead-bound at small B)."""
        q2 = q[..., 1]
        qd1, qd2, _ = qd.unbind(-1)
        r1, r2, r3 = self.minus_friction(r, qd).unbind(-1)
        r1, r2 = minus_c_qd(torch.sin(q2), co, qd1, qd2, r1, r2)
        return m_solve_parts(torch.cos(q2), co, r1, r2, r3 + co[4])  # the prismatic joint carries m3 g

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: torch.Tensor) -> torch.Tensor:
        """Kinetic plus (if gravity is on) potential energy (B,) in J, zero height at q3 = 0."""
        co = self.coefficients(payload)
        e = 0.5 * (qd * m_times(torch.cos(q[..., 1]), co, qd)).sum(-1)
        return e - co[3] * self.params.g * q[..., 2] if self.gravity else e


class ArmPlant(Plant):
    """A URDF arm (`Arm`: its chain, inertials, gravity and payload link); see `Plant` for the rest."""

    compile_chunk = 1  # one step is already thousands of fused scalar operations
    # While torch.compile traces: solve M qdd = r by the Cholesky factorisation written out in
    # scalars (`rbfn.robots.arm_scalar.ScalarConfig.solve`), fused with the step, rather than torch.linalg's batched
    # LAPACK calls, which run apart and cost as much as the whole fused step (False: keep them).
    fused_solve = True

    def __init__(
        self,
        arm: Arm,
        viscous: PerJoint = 12.0,
        coulomb: PerJoint = 0.2,
        friction: str = "sign",
        smooth_velocity: float = 0.01,
        disturbance: PerJoint = 5.0,
        disturbance_freq: float = 2.0,
        gravity: bool = True,
    ) -> None:
        arm.check_physics("ArmPlant")  # M qdd = ... needs M(q) positive definite
        self.arm, self.n = arm, arm.n
        self.terms = ArmTerms(arm)
        self.scalar_terms = ArmScalarTerms(self.terms)  # built eagerly: tracing stays on tensors of B
        super().__init__(viscous, coulomb, friction, smooth_velocity, disturbance, disturbance_freq, gravity)

    def dynamics_terms(self) -> ArmTerms | ArmScalarTerms:
        """The batch-last terms eagerly; their scalar form while torch.compile traces (it fuses)."""
        return self.scalar_terms if torch.compiler.is_compiling() else self.terms

    def coefficients(self, payload: torch.Tensor) -> tuple[torch.Tensor]:
        """(payload,): the payload masses themselves (kg)."""
        return (payload,)

    def accel(self, q: torch.Tensor, qd: torch.Tensor, r: torch.Tensor, co) -> torch.Tensor:
        """Joint accelerations (B, n): M qdd = r - C qd - G - F with r = tau - tau_d, by Cholesky."""
        cfg = self.dynamics_terms().at(q, co[0])
        r = self.minus_friction(r - cfg.coriolis_qd(qd), qd)
        if self.gravity:
            r = r - cfg.gravity()
        if self.fused_solve and torch.compiler.is_compiling():
            return cast(ScalarConfig, cfg).solve(r)  # the scalar form while tracing
        # cholesky_ex: a matrix that is not positive definite (never, for a physical arm) gives
        # non-finite accelerations, which the simulator reports, without a per-call error check.
        chol = torch.linalg.cholesky_ex(cfg.mass_matrix())[0]
        return torch.cholesky_solve(r.unsqueeze(-1), chol).squeeze(-1)

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: torch.Tensor) -> torch.Tensor:
        """Kinetic plus (if gravity is on) potential energy (B,) in J, zero height at the root."""
        e = self.arm.kinetic_energy(q, qd, payload)
        return e + self.arm.potential_energy(q, payload) if self.gravity else e
