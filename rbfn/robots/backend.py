"""The one interface to an arm's equations of motion that the closed loop uses,

    M(q) qdd + C(q, qd) qd + G(q) = tau,

with the payload a point mass (kg) at the arm's payload link. `Dynamics.at(q, payload)` evaluates
the arm at joints q (B, n) and returns `Terms`, whose methods give every quantity a plant or a
controller needs at that configuration, each (B, n) unless said:

    mass_times(v) = M v, solve(r) = M^-1 r, gravity() = G, coriolis_qd(qd) = C qd,
    coriolis_times(qd, y) = C y (the Christoffel C), bias(qd) = C qd + G,
    momentum_rate(qd) = dM/dt qd - C qd - G, accel(qd, r, friction, gravity) = the forward
    dynamics M^-1 (r - F(qd) - C qd - G), mass_matrix() = M (B, n, n).

`Dynamics.load(payload)` is what the terms need of a payload (the SCARA's inertia parameters),
computed once for a whole schedule (T, B) and handed to `at(q, load=...)` a step at a time.
`motion(qd)` returns what the velocity terms share (pass it as `mo` to several calls at one
(q, qd); None where a backend shares nothing). `Dynamics.scaled(m, c, g)` is the same arm with
M, C and G scaled (a controller's nominal model), and `Dynamics.energy` the kinetic plus potential
energy.

Two backends implement it, each tested against the specification `rbfn.robots.dynamics.Arm`
(tests/robots/test_dynamics_backends.py): the URDF recursion for any arm
(`rbfn.robots.arm_terms.ArmTerms`) and the paper's SCARA in closed form
(`rbfn.robots.scara.closed_form.ScaraTerms`), which `rbfn.robots.registry.closed_form` hands out
for exactly its URDF. Each writes its payload model once.
"""

from __future__ import annotations

from typing import Any, Protocol

import torch

__all__ = ["Dynamics", "Terms", "Scaled", "Friction", "forward_dynamics", "christoffel_momentum_rate", "spd_solve"]

Payload = float | torch.Tensor


class Friction(Protocol):
    def __call__(self, r: torch.Tensor, qd: torch.Tensor) -> torch.Tensor:
        """r - F(qd) (B, n)."""
        ...


class Terms(Protocol):
    """An arm's equations of motion at one configuration q (B, n); see the module docstring."""

    def motion(self, qd: torch.Tensor) -> Any: ...

    def mass_matrix(self) -> torch.Tensor: ...

    def mass_times(self, v: torch.Tensor) -> torch.Tensor: ...

    def solve(self, r: torch.Tensor) -> torch.Tensor: ...

    def gravity(self) -> torch.Tensor: ...

    def coriolis_qd(self, qd: torch.Tensor, mo: Any = None) -> torch.Tensor: ...

    def coriolis_times(self, qd: torch.Tensor, y: torch.Tensor, mo: Any = None) -> torch.Tensor: ...

    def coriolis_transpose_qd(self, qd: torch.Tensor, mo: Any = None) -> torch.Tensor: ...

    def bias(self, qd: torch.Tensor) -> torch.Tensor: ...

    def momentum_rate(self, qd: torch.Tensor, mo: Any = None) -> torch.Tensor: ...

    def accel(self, qd: torch.Tensor, r: torch.Tensor, friction: Friction, gravity: bool = True) -> torch.Tensor: ...


def forward_dynamics(
    terms: Terms, qd: torch.Tensor, r: torch.Tensor, friction: Friction, gravity: bool
) -> torch.Tensor:
    """M^-1 (friction(r - C qd) - G) (B, n) from a backend's terms (friction(r, qd) = r - F(qd);
    without `gravity`, G left out): the forward dynamics of backends without a closed form of it."""
    r = friction(r - terms.coriolis_qd(qd), qd)
    return terms.solve(r - terms.gravity() if gravity else r)


def christoffel_momentum_rate(terms: Terms, qd: torch.Tensor, mo: Any = None) -> torch.Tensor:
    """dM/dt qd - C qd - G = C^T qd - G (B, n) from a backend's terms, C the Christoffel matrix
    (dM/dt = C + C^T); `mo`: its `motion(qd)` where already made."""
    mo = terms.motion(qd) if mo is None else mo
    cqd = terms.coriolis_qd(qd, mo)
    return (cqd + terms.coriolis_transpose_qd(qd, mo)) - cqd - terms.gravity()


def spd_solve(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """x (B, m) with a x = b for symmetric positive definite a (B, m, m) and b (B, m), written out
    for graphs: the Cholesky factor and the two triangular solves entry by entry on (B,) rows, so
    that a compiler fuses them into one loop over the batch and an exporter needs no solve (ONNX
    has none; AOTInductor would call torch's own through a slow fallback). m is small (a robot's
    joints). A pivot is floored at 1e-30 before its square root."""
    m = a.shape[-1]
    low: list[list[torch.Tensor]] = []  # row i: L_i0 .. L_ii
    for i in range(m):
        row: list[torch.Tensor] = []
        for j in range(i + 1):
            lj = row if j == i else low[j]
            s = a[:, i, j]
            for k in range(j):
                s = s - row[k] * lj[k]
            row.append(s.clamp(min=1e-30).sqrt() if i == j else s / lj[j])
        low.append(row)
    y: list[torch.Tensor] = []  # L y = b
    for i in range(m):
        s = b[:, i]
        for k in range(i):
            s = s - low[i][k] * y[k]
        y.append(s / low[i][i])
    x: list[torch.Tensor] = [y[0]] * m  # L^T x = y
    for i in reversed(range(m)):
        s = y[i]
        for k in range(i + 1, m):
            s = s - low[k][i] * x[k]
        x[i] = s / low[i][i]
    return torch.stack(x, -1)


class Dynamics(Protocol):
    """An arm's equations of motion (a backend); see the module docstring.

    n: the joints; compile_chunk: control periods per torch.compile'd call that suit this backend
    (its step's graph size). `load(payload)`: what the terms need of a payload, computed once for
    a whole schedule, as the backend's own NamedTuple (`rbfn.robots.scara.closed_form.ScaraLoad`,
    `rbfn.robots.arm_terms.PointMass`), which `at` takes back."""

    n: int
    compile_chunk: int

    def load(self, payload: Payload) -> Any: ...

    def at(self, q: torch.Tensor, payload: Payload = 0.0, load: Any = None) -> Terms: ...

    def scaled(self, m: float, c: float, g: float) -> Dynamics: ...

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload, gravity: bool = True) -> torch.Tensor: ...


class Scaled:
    """A backend's M, C and G scaled by m, c and g (M_hat = m M, C_hat = c C, G_hat = g G), for
    backends whose terms do not take the factors into their own constants (the URDF recursion)."""

    def __init__(self, dynamics: Dynamics, m: float, c: float, g: float) -> None:
        self.dynamics, self.n, self.compile_chunk = dynamics, dynamics.n, dynamics.compile_chunk
        self.m, self.c, self.g = m, c, g

    def load(self, payload: Payload) -> Any:
        return self.dynamics.load(payload)

    def at(self, q: torch.Tensor, payload: Payload = 0.0, load: Any = None) -> ScaledTerms:
        return ScaledTerms(self.dynamics.at(q, payload, load), self.m, self.c, self.g)

    def scaled(self, m: float, c: float, g: float) -> Scaled:
        return Scaled(self.dynamics, self.m * m, self.c * c, self.g * g)

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload, gravity: bool = True) -> torch.Tensor:
        raise NotImplementedError("a scaled model has no energy of its own: ask the plant's dynamics")


class ScaledTerms:
    """`Scaled`'s terms at one configuration: the backend's, times the factors."""

    def __init__(self, terms: Terms, m: float, c: float, g: float) -> None:
        self.terms, self.m, self.c, self.g = terms, m, c, g

    def motion(self, qd: torch.Tensor) -> Any:
        return self.terms.motion(qd)

    def mass_matrix(self) -> torch.Tensor:
        return self.m * self.terms.mass_matrix()

    def mass_times(self, v: torch.Tensor) -> torch.Tensor:
        return self.m * self.terms.mass_times(v)

    def solve(self, r: torch.Tensor) -> torch.Tensor:
        return self.terms.solve(r) / self.m

    def gravity(self) -> torch.Tensor:
        return self.g * self.terms.gravity()

    def coriolis_qd(self, qd: torch.Tensor, mo: Any = None) -> torch.Tensor:
        return self.c * self.terms.coriolis_qd(qd, mo)

    def coriolis_times(self, qd: torch.Tensor, y: torch.Tensor, mo: Any = None) -> torch.Tensor:
        return self.c * self.terms.coriolis_times(qd, y, mo)

    def coriolis_transpose_qd(self, qd: torch.Tensor, mo: Any = None) -> torch.Tensor:
        return self.c * self.terms.coriolis_transpose_qd(qd, mo)

    def bias(self, qd: torch.Tensor) -> torch.Tensor:
        return self.coriolis_qd(qd) + self.gravity()

    def momentum_rate(self, qd: torch.Tensor, mo: Any = None) -> torch.Tensor:
        # dM/dt qd = C qd + C^T qd for the Christoffel C, so dM_hat/dt qd = m (C qd + C^T qd).
        mo = self.terms.motion(qd) if mo is None else mo
        cqd = self.terms.coriolis_qd(qd, mo)
        ctq = self.terms.coriolis_transpose_qd(qd, mo)
        return self.m * (cqd + ctq) - self.c * cqd - self.gravity()

    def accel(self, qd: torch.Tensor, r: torch.Tensor, friction: Friction, gravity: bool = True) -> torch.Tensor:
        return forward_dynamics(self, qd, r, friction, gravity)
