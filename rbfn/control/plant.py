"""The simulated SCARA: rigid-body dynamics plus friction and disturbance, B environments at once.

M(q) qdd + C(q, qd) qd + G(q) + F(qd) + tau_d(t) = tau, with F = viscous qd + coulomb sign(qd)
(or tanh(qd / smooth_velocity)) and tau_d = amplitude sin(frequency t) on every joint. The
payload (kg, per environment) adds to m3 and is held constant within a step; the torque is held
too (zero-order hold). The matrices are written out elementwise (M is block diagonal, so its
inverse is a 2x2 one and a scalar): one step is a few dozen fused tensor operations.
"""
from __future__ import annotations

import torch

from ..robots.scara import ScaraParams, inertia_params

__all__ = ["ScaraPlant", "INTEGRATORS", "FRICTION_MODELS", "m_times", "c_times", "mdot_times", "m_solve"]

INTEGRATORS = ("rk4", "euler")          # euler: semi-implicit (symplectic) Euler
FRICTION_MODELS = ("sign", "smooth")


def m_times(c2, co, v: torch.Tensor) -> torch.Tensor:
    """M(q) v (B, 3) from c2 = cos q2 (B,), co = (p1, p2, p3, m3) and v (B, 3)."""
    p1, p2, p3, m3 = co
    m12 = p3 + p2 * c2
    v1, v2, v3 = v.unbind(-1)
    return torch.stack([(p1 + 2 * p2 * c2) * v1 + m12 * v2, m12 * v1 + p3 * v2, m3 * v3], -1)


def c_times(s2, co, qd: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """C(q, qd) v (B, 3) from s2 = sin q2 (B,)."""
    h = co[1] * s2
    qd1, qd2, _ = qd.unbind(-1)
    v1, v2, v3 = v.unbind(-1)
    return torch.stack([-h * (qd2 * v1 + (qd1 + qd2) * v2), h * qd1 * v1, torch.zeros_like(v3)], -1)


def mdot_times(s2, co, qd: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """dM/dt v (B, 3) along the motion."""
    d = -co[1] * s2 * qd[..., 1]
    v1, v2, v3 = v.unbind(-1)
    return torch.stack([d * (2 * v1 + v2), d * v1, torch.zeros_like(v3)], -1)


def m_solve(c2, co, r: torch.Tensor) -> torch.Tensor:
    """M(q)^-1 r (B, 3): the 2x2 block in closed form, the prismatic joint by division."""
    p1, p2, p3, m3 = co
    m11, m12 = p1 + 2 * p2 * c2, p3 + p2 * c2
    r1, r2, r3 = r.unbind(-1)
    det = m11 * p3 - m12 * m12
    return torch.stack([(p3 * r1 - m12 * r2) / det, (m11 * r2 - m12 * r1) / det, r3 / m3], -1)


class ScaraPlant:
    """The "real" robot of the closed-loop scenario; parameters in SI units."""

    def __init__(self, params: ScaraParams = ScaraParams(), viscous: float = 12.0, coulomb: float = 0.2,
                 friction: str = "sign", smooth_velocity: float = 0.01, disturbance: float = 5.0,
                 disturbance_freq: float = 2.0, gravity: bool = True) -> None:
        if friction not in FRICTION_MODELS:
            raise ValueError(f"friction={friction!r} is not allowed; choose one of {list(FRICTION_MODELS)}")
        if not smooth_velocity > 0:
            raise ValueError(f"smooth_velocity={smooth_velocity} must be > 0 (m/s or rad/s)")
        self.params, self.viscous, self.coulomb, self.friction = params, viscous, coulomb, friction
        self.smooth_velocity, self.dist, self.dist_freq, self.gravity = (smooth_velocity, disturbance,
                                                                          disturbance_freq, gravity)

    def coefficients(self, payload: torch.Tensor):
        """(p1, p2, p3, m3), each (B,), for payloads (B,) kg."""
        return inertia_params(payload, self.params)

    def friction_torque(self, qd: torch.Tensor) -> torch.Tensor:
        sgn = torch.sign(qd) if self.friction == "sign" else torch.tanh(qd / self.smooth_velocity)
        return self.viscous * qd + self.coulomb * sgn

    def disturbance(self, t: torch.Tensor) -> torch.Tensor:
        """Disturbance torque tau_d(t) (same shape as t), N m (N), applied to every joint."""
        return self.dist * torch.sin(self.dist_freq * t)

    def accel(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dist, co) -> torch.Tensor:
        """Joint accelerations (B, 3) under torques tau (B, 3) and disturbance torque `dist`."""
        s2, c2 = torch.sin(q[..., 1]), torch.cos(q[..., 1])
        r = tau - c_times(s2, co, qd, qd) - self.friction_torque(qd) - dist
        if self.gravity:
            r = r + torch.stack([torch.zeros_like(co[3]), torch.zeros_like(co[3]), co[3] * self.params.g], -1)
        return m_solve(c2, co, r)

    def step(self, q: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, dist: torch.Tensor, dt: float, co,
             method: str = "rk4") -> tuple[torch.Tensor, torch.Tensor]:
        """State (q, qd) after dt seconds, torque and payload held; dist (2,): the disturbance
        torque at the step's start and middle, tau_d(t) and tau_d(t + dt/2) (RK4's end stage
        uses the next step's start value, passed as dist[2] when given)."""
        if method == "euler":
            qd = qd + dt * self.accel(q, qd, tau, dist[0], co)
            return q + dt * qd, qd
        a1 = self.accel(q, qd, tau, dist[0], co)
        v2 = qd + 0.5 * dt * a1
        a2 = self.accel(q + 0.5 * dt * qd, v2, tau, dist[1], co)
        v3 = qd + 0.5 * dt * a2
        a3 = self.accel(q + 0.5 * dt * v2, v3, tau, dist[1], co)
        v4 = qd + dt * a3
        a4 = self.accel(q + dt * v3, v4, tau, dist[2], co)
        q_next = q + dt / 6 * (qd + 2 * v2 + 2 * v3 + v4)
        qd_next = qd + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        return q_next, qd_next

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: torch.Tensor) -> torch.Tensor:
        """Kinetic plus (if gravity is on) potential energy (B,) in J, zero height at q3 = 0."""
        co = self.coefficients(payload)
        e = 0.5 * (qd * m_times(torch.cos(q[..., 1]), co, qd)).sum(-1)
        return e - co[3] * self.params.g * q[..., 2] if self.gravity else e
