"""The "real" robot of the closed loop: rigid-body dynamics, friction, disturbance and payload,
B environments at once, stepped by RK4 or semi-implicit Euler.

M(q, m_p) qdd + C(q, qd, m_p) qd + G(q, m_p) + F(qd) + tau_d(t) = tau, with per joint j
F_j = viscous_j qd_j + coulomb_j sign(qd_j) (or tanh(qd_j / smooth_velocity)) and
tau_d,j = disturbance_j sin(frequency t) (each environment its own with `Plant.varied`); m_p the
payload (kg, per environment), held within a step like the torque (zero-order hold).

The rigid-body part is a backend of `rbfn.robots.backend.Dynamics` (the URDF recursion
`rbfn.robots.arm_terms.ArmTerms` for any arm, or a robot's closed form such as the SCARA's
`rbfn.robots.scara.ScaraTerms`); the plant adds friction, the disturbance and the integrators:
`accel(q, qd, tau - tau_d, load)`, `step(...)` and `energy(q, qd, load)`.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch

from ..config import Friction
from ..robots.backend import Dynamics

__all__ = ["Plant"]

PerJoint = float | Sequence[float]


class Plant:
    """The arm's `dynamics` with friction, disturbance and the integrators.

    viscous N m s/rad (N s/m), coulomb N m (N), disturbance N m (N): a float for every joint or one
    value per joint; disturbance_freq rad/s; smooth_velocity rad/s (m/s) of the `smooth` friction;
    gravity: whether it acts.
    """

    # Each environment's own disturbance (`varied`): amplitude (B, n), frequency and phase (B,); None: dist's.
    per_environment: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None

    def __init__(
        self,
        dynamics: Dynamics,
        *,
        viscous: PerJoint = 12.0,
        coulomb: PerJoint = 0.2,
        friction: str = "sign",
        smooth_velocity: float = 0.01,
        disturbance: PerJoint = 5.0,
        disturbance_freq: float = 2.0,
        gravity: bool = True,
    ) -> None:
        self.dynamics, self.n = dynamics, dynamics.n
        self.compile_chunk = dynamics.compile_chunk  # control periods per torch.compile'd call
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

    def load(self, payload: torch.Tensor) -> tuple:
        """What a step needs of the payload (kg, any shape, e.g. a schedule (T, B)): the dynamics'
        `load`, computed once for the whole schedule; `step` and `accel` take it a step at a time."""
        return self.dynamics.load(payload)

    def accel(self, q: torch.Tensor, qd: torch.Tensor, r: torch.Tensor, load: tuple) -> torch.Tensor:
        """Joint accelerations (B, n) under r = tau - tau_d (B, n), the torque less the disturbance,
        carrying the payload whose `load` (each (B,)) is given."""
        return self.dynamics.at(q, load=load).accel(qd, r, self.minus_friction, self.gravity)

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: torch.Tensor) -> torch.Tensor:
        """Kinetic plus (if gravity is on) potential energy (B,) in J."""
        return self.dynamics.energy(q, qd, payload, self.gravity)

    def step(
        self,
        q: torch.Tensor,
        qd: torch.Tensor,
        tau: torch.Tensor,
        dist: torch.Tensor,
        dt: float,
        load: tuple,
        method: str = "rk4",
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """State (q, qd) after dt seconds, torque and payload (its `load`, each (B,)) held; dist: the
        disturbance torque at the step's start, middle and end, tau_d(t), tau_d(t + dt/2),
        tau_d(t + dt) (3,) or (3, n)."""
        if method == "euler":
            qd = qd + dt * self.accel(q, qd, tau - dist[0], load)
            return q + dt * qd, qd
        # x + h y as one operation (torch.add's alpha): a step is overhead-bound at small B.
        h = 0.5 * dt
        r_mid = tau - dist[1]  # the two middle stages share it
        a1 = self.accel(q, qd, tau - dist[0], load)
        v2 = torch.add(qd, a1, alpha=h)
        a2 = self.accel(torch.add(q, qd, alpha=h), v2, r_mid, load)
        v3 = torch.add(qd, a2, alpha=h)
        a3 = self.accel(torch.add(q, v2, alpha=h), v3, r_mid, load)
        v4 = torch.add(qd, a3, alpha=dt)
        a4 = self.accel(torch.add(q, v3, alpha=dt), v4, tau - dist[2], load)
        q_next = torch.add(q, qd.add(v2, alpha=2.0).add_(v3, alpha=2.0).add_(v4), alpha=dt / 6)
        qd_next = torch.add(qd, a1.add(a2, alpha=2.0).add_(a3, alpha=2.0).add_(a4), alpha=dt / 6)
        return q_next, qd_next
