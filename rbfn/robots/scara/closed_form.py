"""The paper's 3-DOF SCARA in closed form: parameters, kinematics and corrected dynamics, a
second form of what `rbfn.robots.kinematics` and `rbfn.robots.dynamics` compute from scara.urdf
(faster: elementwise, no chain walk), tested equal to it.

Joints q = (q1, q2, q3): rad, rad, m. Base frame at joint 1's axis, in the arm's plane:
x = l1 cos q1 + l2 cos(q1 + q2), y = l1 sin q1 + l2 sin(q1 + q2), z = -q3.

Dynamics M(q) qdd + C(q, qd) qd + G(q) = tau (DESIGN section 5, the paper's typos corrected):
links 1 and 2 are uniform rods in the horizontal plane, m3 plus any payload a point mass on the
vertical axis through the tip of link 2. With c2 = cos q2, s2 = sin q2 and
p1 = l1^2 (m1/3 + m2 + m3) + l2^2 (m2/3 + m3), p2 = l1 l2 (m2/2 + m3), p3 = l2^2 (m2/3 + m3):
M = [[p1 + 2 p2 c2, p3 + p2 c2, 0], [p3 + p2 c2, p3, 0], [0, 0, m3]],
C = [[-p2 s2 qd2, -p2 s2 (qd1 + qd2), 0], [p2 s2 qd1, 0, 0], [0, 0, 0]], G = [0, 0, -m3 g].
Every function takes `payload` (kg, a float or a (B,) tensor) added to m3, is batched over the
leading dimension, and keeps the dtype and device of q.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import torch

__all__ = [
    "ScaraParams",
    "with_link_errors",
    "fk",
    "ik",
    "inertia_params",
    "mass_matrix",
    "mass_matrix_dot",
    "coriolis",
    "gravity",
    "kinetic_energy",
    "joint_vector",
    "mass_entries",
    "m_times",
    "minus_c_qd",
    "c_times",
    "m_solve",
    "m_solve_parts",
    "ScaraTerms",
    "ScaraAt",
]


@dataclass(frozen=True)
class ScaraParams:
    """Link lengths (m), masses (kg) and gravity (m/s^2); defaults are the paper's: l1, l2, m1, m2
    and m3 those of scara.urdf, g that of conf/robot/scara.yaml (l3, the quill's length, is in
    neither kinematics: only MuJoCo's model draws it)."""

    l1: float = 1.0
    l2: float = 0.8
    l3: float = 0.6
    m1: float = 1.0
    m2: float = 0.8
    m3: float = 0.5
    g: float = 9.8


def with_link_errors(p: ScaraParams, link_error: Sequence) -> ScaraParams:
    """p with l1 and l2 scaled by (1 + link_error[0]) and (1 + link_error[1]): relative errors,
    floats or (B,) tensors (then l1, l2 are (B,) too, one robot per row)."""
    return replace(p, l1=p.l1 * (1 + link_error[0]), l2=p.l2 * (1 + link_error[1]))


def fk(q: torch.Tensor, p: ScaraParams = ScaraParams()) -> torch.Tensor:
    """Closed-form end-effector positions (B, 3) in m from joints q (B, 3)."""
    q1, q2, q3 = q.unbind(-1)
    x = p.l1 * torch.cos(q1) + p.l2 * torch.cos(q1 + q2)
    y = p.l1 * torch.sin(q1) + p.l2 * torch.sin(q1 + q2)
    return torch.stack([x, y, -q3], dim=-1)


def ik(pos: torch.Tensor, p: ScaraParams = ScaraParams(), elbow: int = 1) -> torch.Tensor:
    """Closed-form IK: joints (B, 3) for positions (B, 3) in m; elbow=+1 gives q2 >= 0.

    Unreachable radii are clamped to the nearest reachable one.
    """
    x, y, z = pos.unbind(-1)
    c2 = ((x * x + y * y - p.l1**2 - p.l2**2) / (2 * p.l1 * p.l2)).clamp(-1.0, 1.0)
    q2 = elbow * torch.acos(c2)
    q1 = torch.atan2(y, x) - torch.atan2(p.l2 * torch.sin(q2), p.l1 + p.l2 * torch.cos(q2))
    return torch.stack([q1, q2, -z], dim=-1)


def inertia_params(payload: float | torch.Tensor = 0.0, p: ScaraParams = ScaraParams()):
    """(p1, p2, p3, m3) in kg m^2, kg m^2, kg m^2, kg for a payload (kg, float or (B,))."""
    m3 = p.m3 + payload
    p1 = p.l1**2 * (p.m1 / 3 + p.m2 + m3) + p.l2**2 * (p.m2 / 3 + m3)
    p2 = p.l1 * p.l2 * (p.m2 / 2 + m3)
    p3 = p.l2**2 * (p.m2 / 3 + m3)
    return p1, p2, p3, m3


def _full(x, like: torch.Tensor) -> torch.Tensor:
    """x (float or (B,) tensor) broadcast to the batch shape of `like` (B,)."""
    return torch.as_tensor(x, dtype=like.dtype, device=like.device).expand_as(like)


def mass_matrix(q: torch.Tensor, payload: float | torch.Tensor = 0.0, p: ScaraParams = ScaraParams()) -> torch.Tensor:
    """Inertia matrix M(q) (B, 3, 3) for joints q (B, 3)."""
    p1, p2, p3, m3 = inertia_params(payload, p)
    c2 = torch.cos(q[..., 1])
    zero = torch.zeros_like(c2)
    m12 = p3 + p2 * c2
    rows = [
        torch.stack([p1 + 2 * p2 * c2, m12, zero], -1),
        torch.stack([m12, _full(p3, c2), zero], -1),
        torch.stack([zero, zero, _full(m3, c2)], -1),
    ]
    return torch.stack(rows, -2)


def mass_matrix_dot(
    q: torch.Tensor, qd: torch.Tensor, payload: float | torch.Tensor = 0.0, p: ScaraParams = ScaraParams()
) -> torch.Tensor:
    """Time derivative of M along the motion, dM/dt (B, 3, 3), for q, qd (B, 3)."""
    _, p2, _, _ = inertia_params(payload, p)
    d = -p2 * torch.sin(q[..., 1]) * qd[..., 1]
    zero = torch.zeros_like(d)
    rows = [torch.stack([2 * d, d, zero], -1), torch.stack([d, zero, zero], -1), torch.stack([zero, zero, zero], -1)]
    return torch.stack(rows, -2)


def coriolis(
    q: torch.Tensor, qd: torch.Tensor, payload: float | torch.Tensor = 0.0, p: ScaraParams = ScaraParams()
) -> torch.Tensor:
    """Coriolis and centrifugal matrix C(q, qd) (B, 3, 3), with dM/dt - 2C skew-symmetric."""
    _, p2, _, _ = inertia_params(payload, p)
    h = p2 * torch.sin(q[..., 1])
    zero = torch.zeros_like(h)
    rows = [
        torch.stack([-h * qd[..., 1], -h * (qd[..., 0] + qd[..., 1]), zero], -1),
        torch.stack([h * qd[..., 0], zero, zero], -1),
        torch.stack([zero, zero, zero], -1),
    ]
    return torch.stack(rows, -2)


def gravity(q: torch.Tensor, payload: float | torch.Tensor = 0.0, p: ScaraParams = ScaraParams()) -> torch.Tensor:
    """Gravity torques G(q) (B, 3): (0, 0, -m3 g) N m, N m, N (q3 is positive downward)."""
    _, _, _, m3 = inertia_params(payload, p)
    zero = torch.zeros_like(q[..., 0])
    return torch.stack([zero, zero, -_full(m3, zero) * p.g], -1)


def kinetic_energy(
    q: torch.Tensor, qd: torch.Tensor, payload: float | torch.Tensor = 0.0, p: ScaraParams = ScaraParams()
) -> torch.Tensor:
    """Kinetic energy 1/2 qd^T M qd (B,) in J."""
    return 0.5 * torch.einsum("bi,bij,bj->b", qd, mass_matrix(q, payload, p), qd)


# Elementwise products for the simulator's hot path: co = (p1, p2, p3, m3) from inertia_params,
# c2 = cos q2, s2 = sin q2 (B,); no (B, 3, 3) matrix is formed.
def joint_vector(parts: list[torch.Tensor]) -> torch.Tensor:
    """Components (B,) as one (B, n) vector stored joints-first (a view of an (n, B) tensor):
    stacking rows is a plain copy, where stacking along the last dimension interleaves, and
    each component read back (v[..., j]) is contiguous."""
    v = torch.stack(parts, 0)
    return v.T if v.dim() == 2 else v.movedim(0, -1)


def mass_entries(c2, co) -> tuple:
    """(M11, M12) (B,) of the revolute 2x2 block from c2 = cos q2 (B,) and co; M22 = p3, M33 = m3."""
    pc = co[1] * c2
    m11 = torch.add(co[0], pc, alpha=2.0) if isinstance(co[0], torch.Tensor) else (pc + pc) + co[0]
    return m11, co[2] + pc


def m_times(c2, co, v: torch.Tensor, entries: tuple | None = None) -> torch.Tensor:
    """M(q) v (B, 3) from c2 = cos q2 (B,), co = (p1, p2, p3, m3) and v (B, 3); `entries`:
    `mass_entries(c2, co)` if already computed."""
    m11, m12 = entries or mass_entries(c2, co)
    v1, v2, v3 = v.unbind(-1)
    return joint_vector([m11 * v1 + m12 * v2, m12 * v1 + co[2] * v2, co[3] * v3])


def minus_c_qd(
    s2, co, qd1: torch.Tensor, qd2: torch.Tensor, r1: torch.Tensor, r2: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(r1, r2) minus the two nonzero components (B,) of C(q, qd) qd, -h qd2 (2 qd1 + qd2) and
    h qd1^2 with h = p2 sin q2 (the third is 0): `c_times(s2, co, qd, qd)` without forming vectors."""
    h = co[1] * s2
    return r1 + h * qd2 * torch.add(qd2, qd1, alpha=2.0), r2 - h * qd1 * qd1


def c_times(s2, co, qd: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """C(q, qd) v (B, 3) from s2 = sin q2 (B,)."""
    h = co[1] * s2
    qd1, qd2, _ = qd.unbind(-1)
    v1, v2, v3 = v.unbind(-1)
    return joint_vector([-h * (qd2 * v1 + (qd1 + qd2) * v2), h * qd1 * v1, torch.zeros_like(v3)])


def m_solve(c2, co, r: torch.Tensor) -> torch.Tensor:
    """M(q)^-1 r (B, 3): the 2x2 block in closed form, the prismatic joint by division."""
    return m_solve_parts(c2, co, *r.unbind(-1))


def m_solve_parts(c2, co, r1: torch.Tensor, r2: torch.Tensor, r3: torch.Tensor) -> torch.Tensor:
    """M(q)^-1 r (B, 3) from the components of r, each (B,)."""
    p3, m3 = co[2], co[3]
    m11, m12 = mass_entries(c2, co)
    det = m11 * p3 - m12 * m12
    return joint_vector([(p3 * r1 - m12 * r2) / det, (m11 * r2 - m12 * r1) / det, r3 / m3])


class ScaraLoad(NamedTuple):
    """A payload as the SCARA's terms take it (`ScaraTerms.load`): `inertia_params`' coefficients
    with it, kg m^2 (p1, p2, p3) and kg (m3), and m3 g, N; each shaped like the payload."""

    p1: Any
    p2: Any
    p3: Any
    m3: Any
    m3g: Any


class ScaraTerms:
    """The SCARA's closed form as a backend of `rbfn.robots.backend.Dynamics`: elementwise terms
    (no (B, 3, 3) matrix, no chain walk), with M, C and G scaled by `scales` (m, c, g) folded into
    the coefficients (a nominal model: `scaled`). The payload model is `inertia_params`'s."""

    n = 3
    # Integration steps per compiled call (a step is a few dozen fused operations): a longer chunk
    # builds longer and costs less per call; docs/benchmarks.md measures the trade-off.
    compile_chunk = 10

    def __init__(self, params: ScaraParams = ScaraParams(), scales: tuple[float, float, float] = (1.0, 1.0, 1.0)):
        self.params, self.scales = params, scales
        self._gravity: dict = {}

    def load(self, payload: float | torch.Tensor) -> ScaraLoad:
        """What the terms need of a payload (kg, float or any shape, e.g. a whole schedule (T, B)),
        each part shaped like it."""
        p1, p2, p3, m3 = inertia_params(payload, self.params)
        return ScaraLoad(p1, p2, p3, m3, m3 * self.params.g)

    def at(self, q: torch.Tensor, payload: float | torch.Tensor = 0.0, load: ScaraLoad | None = None) -> ScaraAt:
        """The arm at joints q (B, 3) carrying `payload` kg (float or (B,)) at the quill, or the
        payload's `load` (each (B,)) where the caller computed it beforehand."""
        return ScaraAt(self, q, self.load(payload) if load is None else load)

    def scaled(self, m: float, c: float, g: float) -> ScaraTerms:
        s = self.scales
        return ScaraTerms(self.params, (s[0] * m, s[1] * c, s[2] * g))

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload, gravity: bool = True) -> torch.Tensor:
        """Kinetic plus (with `gravity`) potential energy (B,) in J, zero height at q3 = 0."""
        co = inertia_params(payload, self.params)
        e = 0.5 * (qd * m_times(torch.cos(q[..., 1]), co, qd)).sum(-1)
        return e - co[3] * self.params.g * q[..., 2] if gravity else e

    def gravity_vector(self, g3, like: torch.Tensor) -> torch.Tensor:
        """G (3,) = (0, 0, g3), the same at every q: it broadcasts against (B, 3). For a float g3
        one tensor per dtype and device, made once (while torch.compile traces, a constant of the
        graph: a cache would be a guard)."""
        if isinstance(g3, torch.Tensor):
            return joint_vector([torch.zeros_like(g3), torch.zeros_like(g3), g3])
        if torch.compiler.is_compiling():
            return torch.tensor([0.0, 0.0, g3], dtype=like.dtype, device=like.device)
        key = (g3, like.dtype, like.device)
        if key not in self._gravity:
            self._gravity[key] = torch.tensor([0.0, 0.0, g3], dtype=like.dtype, device=like.device)
        return self._gravity[key]


class ScaraAt:
    """`ScaraTerms` at joints q (B, 3) with a payload (kg, float or (B,)); the interface of
    `rbfn.robots.backend.Terms`. What several terms share (M's entries) is computed once."""

    def __init__(self, terms: ScaraTerms, q: torch.Tensor, load: ScaraLoad) -> None:
        self.terms, self.q = terms, q
        p1, p2, p3, m3, self.m3g = load.p1, load.p2, load.p3, load.m3, load.m3g
        ms, cs, gs = terms.scales
        if terms.scales == (1.0, 1.0, 1.0):
            self.m_co, self.c_co, self.g3 = (p1, p2, p3, m3), (0.0, p2, 0.0, 0.0), -self.m3g
        else:
            self.m_co = (ms * p1, ms * p2, ms * p3, ms * m3)
            self.c_co, self.g3 = (0.0, cs * p2, 0.0, 0.0), -gs * m3 * terms.params.g
        self.s2, self.c2 = torch.sin(q[..., 1]), torch.cos(q[..., 1])
        self._entries: tuple | None = None

    def motion(self, qd: torch.Tensor) -> None:
        return None  # nothing the velocity terms share

    def _mass_entries(self) -> tuple:
        if self._entries is None:
            self._entries = mass_entries(self.c2, self.m_co)
        return self._entries

    def mass_matrix(self) -> torch.Tensor:
        m11, m12 = self._mass_entries()
        p3, m3 = (torch.as_tensor(x, dtype=self.q.dtype, device=self.q.device).expand_as(m11) for x in self.m_co[2:])
        zero = torch.zeros_like(m11)
        rows = [torch.stack([m11, m12, zero], -1), torch.stack([m12, p3, zero], -1), torch.stack([zero, zero, m3], -1)]
        return torch.stack(rows, -2)

    def mass_times(self, v: torch.Tensor) -> torch.Tensor:
        return m_times(self.c2, self.m_co, v, self._mass_entries())

    def solve(self, r: torch.Tensor) -> torch.Tensor:
        return m_solve(self.c2, self.m_co, r)

    def gravity(self) -> torch.Tensor:
        return self.terms.gravity_vector(self.g3, self.q)

    def coriolis_qd(self, qd: torch.Tensor, mo=None) -> torch.Tensor:
        return c_times(self.s2, self.c_co, qd, qd)

    def coriolis_times(self, qd: torch.Tensor, y: torch.Tensor, mo=None) -> torch.Tensor:
        return c_times(self.s2, self.c_co, qd, y)

    def coriolis_transpose_qd(self, qd: torch.Tensor, mo=None) -> torch.Tensor:
        # C^T qd = (0, -h qd1 (qd1 + qd2), 0) with h = c p2 s2: column j of C times qd.
        h = self.c_co[1] * self.s2
        qd1, qd2, _ = qd.unbind(-1)
        zero = torch.zeros_like(qd1)
        return joint_vector([zero, -h * qd1 * (qd1 + qd2), zero])

    def bias(self, qd: torch.Tensor) -> torch.Tensor:
        return self.coriolis_qd(qd) + self.gravity()

    def momentum_rate(self, qd: torch.Tensor, mo=None) -> torch.Tensor:
        """dM/dt qd - C qd - G by component, with a = M's and c = C's cos q2 coefficients (p2,
        scaled): dM/dt qd = -a s2 qd2 (2 qd1 + qd2, qd1, 0), C qd = c s2 (-qd2 (2 qd1 + qd2), qd1^2, 0)."""
        a, c = self.m_co[1], self.c_co[1]
        qd1, qd2, _ = qd.unbind(-1)
        r1 = torch.add(qd2, qd1, alpha=2.0) * qd2 * (self.s2 * (c - a))
        inner = qd2 * -a - c * qd1 if isinstance(c, torch.Tensor) else torch.add(qd2 * -a, qd1, alpha=-c)
        r2 = (self.s2 * qd1) * inner
        r3 = -self.g3 * torch.ones_like(r1) if isinstance(self.g3, torch.Tensor) else torch.full_like(r1, -self.g3)
        return joint_vector([r1, r2, r3])

    def accel(self, qd: torch.Tensor, r: torch.Tensor, friction, gravity: bool = True) -> torch.Tensor:
        """M^-1 (friction(r) - C qd - G) (B, 3) component by component (the fewest tensor
        operations: a step is overhead-bound at small B); friction(r, qd) = r - F(qd)."""
        qd1, qd2, _ = qd.unbind(-1)
        r1, r2, r3 = friction(r, qd).unbind(-1)
        r1, r2 = minus_c_qd(self.s2, self.c_co, qd1, qd2, r1, r2)
        if gravity:
            r3 = r3 + self.m3g  # the prismatic joint carries m3 g
        return m_solve_parts(self.c2, self.m_co, r1, r2, r3)
