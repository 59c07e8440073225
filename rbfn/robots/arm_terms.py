"""The terms of a URDF arm's equations of motion for the simulator's hot path, batch-last.

    M(q) qdd + C(q, qd) qd + G(q) = tau

The simulator's fast form of the specification `rbfn.robots.dynamics.Arm`, tested against it
(tests/robots/test_dynamics_backends.py): the same quantities (its lumped constants and payload
placement; world axes, spatial vectors about the last body's origin, their products from
`rbfn.robots.spatial`; CRBA for M, RNEA for C qd + G), laid out with the
environments last, (..., B): every tensor operation then works on long contiguous rows, and
3x3 products are unrolled into a few multiply-adds of (n, 3, B) rows instead of batches of
tiny matrix products. Each body frame is turned (a constant rotation folded into the URDF
constants) so that its joint axis is its z axis, which makes a joint rotation two
multiply-adds. `ArmTerms(arm).at(q, payload)` does the kinematics and body inertias once; the
returned `Config` then gives M, C qd + G, G, C(q, qd) y for any y (the Christoffel C, without
forming it) and C(q, qd)^T qd, batch-first at the edges: (B, n) and (B, n, n).

C(q, qd) y = sum_k J_k^T (I_k dJ_k/dt y + B_k J_k y), B_k u = (v_k x* I_k u - I_k (v_k x u)
+ u x* I_k v_k) / 2 (the body-wise factorisation of Echeandia and Wensing, 2021, that
`Arm.coriolis` forms as a matrix); C^T qd = dT/dq: (C^T qd)_i = dS_i/dt . sum_{k>=i} I_k v_k.
Motion and force vectors are pairs (angular or moment (n, 3, B), linear or force (n, 3, B)).
"""

from __future__ import annotations

import operator
from typing import Any, NamedTuple

import torch

from .backend import Friction, Scaled, christoffel_momentum_rate, forward_dynamics, spd_solve
from .dynamics import Arm, Payload
from .kinematics import axis_frame
from .spatial import Spatial

__all__ = ["ArmTerms", "Config", "Motion"]

Pair = tuple[torch.Tensor, torch.Tensor]


# Below WIDE environments a tensor operation costs its dispatch, not its data: use the fewest
# operations (one fused cross product, one cumsum); above it, the variants that stream best.
WIDE = 512


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """a x b of 3-vectors stored along dim -2: (..., 3, B)."""
    if a.shape[-1] < WIDE and b.shape[-1] < WIDE:
        return torch.linalg.cross(a, b, dim=-2)
    a0, a1, a2 = a.unbind(-2)
    b0, b1, b2 = b.unbind(-2)
    return torch.stack(
        [
            torch.addcmul(a1 * b2, a2, b1, value=-1),
            torch.addcmul(a2 * b0, a0, b2, value=-1),
            torch.addcmul(a0 * b1, a1, b0, value=-1),
        ],
        -2,
    )


def _matvec(a: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """a x for matrices (..., 3, 3, B) and vectors (..., 3, B), unrolled over the inner index."""
    out = a[..., 0, :] * x[..., 0:1, :]
    out = torch.addcmul(out, a[..., 1, :], x[..., 1:2, :])
    return torch.addcmul(out, a[..., 2, :], x[..., 2:3, :])


# v x m, v x* f and I v (`rbfn.robots.spatial`) on pairs of (n, 3, B): masses m (n, 1 or B), first
# moments h (n, 3, B), rotational inertias J (n, 3, 3, B); m v0 - c is one fused addcmul.
_SPATIAL = Spatial(_cross, operator.add, _matvec, lambda m, v, c: torch.addcmul(-c, m.unsqueeze(1), v))
_cross_motion, _cross_force, _apply = _SPATIAL.cross_motion, _SPATIAL.cross_force, _SPATIAL.inertia_times


def _rotate_const(rot: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """R_k x_k (n, 3, B) for rotations (n, 3, 3, B) and constant vectors x (n, 3)."""
    out = rot[:, :, 0] * x[:, 0, None, None]
    out = torch.addcmul(out, rot[:, :, 1], x[:, 1, None, None])
    return torch.addcmul(out, rot[:, :, 2], x[:, 2, None, None])


def _suffix_sum(x: torch.Tensor) -> torch.Tensor:
    """sum_{k >= i} x_k along the body dimension 0."""
    if torch.compiler.is_compiling():
        return _unrolled_sum(x, reverse=True)
    if x.shape[-1] < WIDE:
        return x.flip(0).cumsum(0).flip(0)
    out = x.clone()
    for i in range(x.shape[0] - 2, -1, -1):
        out[i] += out[i + 1]
    return out


def _prefix_sum(x: torch.Tensor) -> torch.Tensor:
    """sum_{k <= i} x_k along the body dimension 0."""
    if torch.compiler.is_compiling():
        return _unrolled_sum(x, reverse=False)
    if x.shape[-1] < WIDE:
        return x.cumsum(0)
    out = x.clone()
    for i in range(1, x.shape[0]):
        out[i] += out[i - 1]
    return out


def _unrolled_sum(x: torch.Tensor, reverse: bool) -> torch.Tensor:
    """The running sum along dim 0 as one addition per body: traced, it fuses with its neighbours,
    where a compiled cumsum is a call out of the generated code (89 a period on the UR5)."""
    parts = list(x.unbind(0))
    order = range(len(parts) - 2, -1, -1) if reverse else range(1, len(parts))
    step = 1 if reverse else -1
    for i in order:
        parts[i] = parts[i] + parts[i + step]
    return torch.stack(parts)


class PointMass(NamedTuple):
    """A payload as a URDF arm's terms take it (`ArmTerms.load`): a point mass, kg (float or any
    shape), at the payload link (`rbfn.robots.dynamics`)."""

    mass: Payload


class ArmTerms:
    """The URDF backend of `rbfn.robots.backend.Dynamics` for an `Arm` (its constants, float64 at
    load, cast per dtype and device): the batch-last terms, eager or compiled."""

    compile_chunk = 1  # control periods per compiled call: one period is ~400 fused kernels, a minute to build

    def __init__(self, arm: Arm) -> None:
        arm.check_physics("the closed loop")  # M qdd = ... needs M(q) positive definite
        self.arm, self.n = arm, arm.n
        self._cache: dict = {}

    def _consts(self, dtype: torch.dtype, device: torch.device) -> dict:
        key = (dtype, device)
        if key not in self._cache:
            md, n = self.arm.model, self.n
            # Body frame i turned by Q_i (z column = joint axis): R'_i = R'_{i-1} R0'_i Rz(q_i) with
            # R0'_i = Q_{i-1}^T R0_i Q_i, t0'_i = Q_{i-1}^T t0_i; body constants seen from the turned frame.
            qs = [axis_frame(a) for a in md.axis]
            prev = [torch.eye(3, dtype=torch.float64), *qs[:-1]]
            rot0 = torch.stack([p.T @ md.placement[i, :3, :3] @ qs[i] for i, p in enumerate(prev)])
            t0 = torch.stack([p.T @ md.placement[i, :3, 3] for i, p in enumerate(prev)])
            qt = torch.stack(qs)
            first = (qt.transpose(1, 2) @ md.first_moment.unsqueeze(-1)).squeeze(-1)
            inertia = qt.transpose(1, 2) @ md.inertia @ qt
            pbody = md.payload_body
            pp = qs[pbody].T @ md.payload_pos if pbody >= 0 else md.payload_pos
            c: dict[str, Any] = {
                "cols": torch.cat([rot0, t0.unsqueeze(-1)], -1),  # (n, 3, 4): [R0' | t0']
                "mass": md.mass,
                "first": first,
                "inertia": inertia,
                "payload_pos": pp,
                "g0": -self.arm.gravity_vector,
            }
            c = {k: v.to(dtype=dtype, device=device) for k, v in c.items()}
            prismatic = md.prismatic.tolist()
            c["prismatic"] = prismatic
            c["any_prismatic"] = any(prismatic)
            c["revolute_mask"] = (~md.prismatic).to(dtype=dtype, device=device)[:, None, None]
            c["prismatic_mask"] = md.prismatic.to(device=device)[:, None, None]
            c["upper"] = torch.ones(n, n, dtype=torch.bool, device=device).triu().unsqueeze(-1)
            c["payload_body"] = pbody
            onehot = torch.zeros(n, 1, dtype=dtype, device=device)
            if pbody >= 0:
                onehot[pbody] = 1.0
            c["onehot"] = onehot
            c["eye"] = torch.eye(3, dtype=dtype, device=device)[:, :, None]
            self._cache[key] = c
        return self._cache[key]

    def load(self, payload: Payload) -> PointMass:
        """What the terms need of a payload (kg, float or any shape): its mass."""
        return PointMass(payload)

    def at(self, q: torch.Tensor, payload: Payload = 0.0, load: PointMass | None = None) -> Any:
        """The arm at joints q (B, n) rad or m carrying `payload` kg (float or (B,)) at its payload
        link (or its `load`): a `Config`."""
        if load is not None:
            payload = load.mass
        if q.dim() != 2 or q.shape[1] != self.n:
            raise ValueError(f"expected joint values (B, {self.n}), got {tuple(q.shape)}")
        return Config(self.n, self._consts(q.dtype, q.device), q, payload)

    def scaled(self, m: float, c: float, g: float) -> Scaled:
        """M, C and G scaled by m, c and g (a nominal model)."""
        return Scaled(self, m, c, g)

    def energy(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload, gravity: bool = True) -> torch.Tensor:
        """Kinetic plus (with `gravity`) potential energy (B,) in J, zero height at the root."""
        e = self.arm.kinetic_energy(q, qd, payload)
        return e + self.arm.potential_energy(q, payload) if gravity else e


class Config:
    """Kinematics and body inertias of B environments at one configuration; see `ArmTerms.at`."""

    def __init__(self, n: int, c: dict, q: torch.Tensor, payload: Payload) -> None:
        self.n, self.c = n, c
        qt = q.T.contiguous()  # (n, B)
        b = qt.shape[1]
        cos, sin = torch.cos(qt), torch.sin(qt)
        cols = c["cols"]
        rots, poss, axes = [], [], []
        r_prev = p_prev = None
        for i, prismatic in enumerate(c["prismatic"]):
            if r_prev is None:
                y = cols[i].unsqueeze(-1)  # (3, 4, 1)
            else:  # R_{i-1} [R0' | t0'] (3, 4, B)
                y = r_prev[:, 0, None] * cols[i, 0, :, None]
                y = torch.addcmul(y, r_prev[:, 1, None], cols[i, 1, :, None])
                y = torch.addcmul(y, r_prev[:, 2, None], cols[i, 2, :, None])
            x0, x1, x2, t = y.unbind(1)
            p = t.expand(3, b) if p_prev is None else p_prev + t
            z = x2.expand(3, b)
            if prismatic:
                rot = torch.stack([x0.expand(3, b), x1.expand(3, b), z], 1)
                p = torch.addcmul(p, z, qt[i])
            else:
                ci, si = cos[i], sin[i]
                rot = torch.stack([torch.addcmul(x0 * ci, x1, si), torch.addcmul(x1 * ci, x0, si, value=-1), z], 1)
            rots.append(rot)
            poss.append(p)
            axes.append(z)
            r_prev, p_prev = rot, p
        rot, z = torch.stack(rots), torch.stack(axes)  # (n, 3, 3, B), (n, 3, B)
        pos = torch.stack(poss)
        pos = pos - pos[-1]  # about the last body's origin
        if c["any_prismatic"]:
            self.s = (z * c["revolute_mask"], torch.where(c["prismatic_mask"], z, _cross(pos, z)))
        else:
            self.s = (z, _cross(pos, z))  # S_i (n, 3, B) x 2
        # Body inertias about the reference point; the payload is a point mass on its body, added
        # in world axes (see `rbfn.robots.dynamics` on where the payload model is written).
        mass = c["mass"].unsqueeze(-1)  # (n, 1)
        hb = _rotate_const(rot, c["first"])  # R h_b (n, 3, B)
        body = c["payload_body"]
        rir = _sandwich(rot, c["inertia"])  # R Ibar R^T (n, 3, 3, B)
        if body >= 0 and not (isinstance(payload, (int, float)) and payload == 0):
            mp = torch.as_tensor(payload, dtype=q.dtype, device=q.device).reshape(-1)  # (1 or B,)
            mass = mass + c["onehot"] * mp  # (n, 1 or B)
            r = _rotate_const(rot[body : body + 1], c["payload_pos"][None])[0]  # R pp (3, B)
            hb, rir = hb.clone(), rir.clone()
            hb[body] = torch.addcmul(hb[body], r, mp)
            rir[body] += mp * (c["eye"] * (r * r).sum(0) - r.unsqueeze(1) * r.unsqueeze(0))
        self.m = mass
        self.h = torch.addcmul(hb, mass.unsqueeze(1), pos)  # m p + R h_b (n, 3, B)
        j = torch.addcmul(rir, pos.unsqueeze(2), self.h.unsqueeze(1), value=-1)
        j = torch.addcmul(j, hb.unsqueeze(2), pos.unsqueeze(1), value=-1)
        pdot = (pos * (self.h + hb)).sum(1)  # (n, B)
        j.diagonal(dim1=1, dim2=2).add_(pdot.unsqueeze(-1))
        self.j = j  # (n, 3, 3, B)
        self._composite: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        self._m: torch.Tensor | None = None

    # ------------------------------------------------------------------ pieces
    def apply(self, v: Pair) -> Pair:
        """I_k v_k for motion vectors v of every body."""
        return _apply(self.m, self.h, self.j, v)

    def composite(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(m^c, h^c, J^c): the inertias of the bodies k >= i, about the reference point."""
        if self._composite is None:
            self._composite = (_suffix_sum(self.m), _suffix_sum(self.h), _suffix_sum(self.j))
        return self._composite

    def motion(self, qd: torch.Tensor) -> Motion:
        """Body velocities and axis rates for joint rates qd (B, n); pass it to the methods below
        to share them between calls at the same (q, qd)."""
        return Motion(self, qd)

    def _project(self, f: Pair) -> torch.Tensor:
        """tau_i = S_i . sum_{k>=i} f_k as (B, n) for body forces f."""
        return ((self.s[0] * _suffix_sum(f[0])).sum(1) + (self.s[1] * _suffix_sum(f[1])).sum(1)).T

    def _mass(self) -> torch.Tensor:
        """M (n, n, B) by CRBA: M_ij = S_i . I^c_j S_j for i <= j."""
        if self._m is None:
            f = _apply(*self.composite(), self.s)
            up = (self.s[0].unsqueeze(1) * f[0].unsqueeze(0)).sum(2) + (self.s[1].unsqueeze(1) * f[1].unsqueeze(0)).sum(
                2
            )
            self._m = torch.where(self.c["upper"], up, up.transpose(0, 1))
        return self._m

    # ------------------------------------------------------------------ public quantities
    def mass_matrix(self) -> torch.Tensor:
        """M(q) (B, n, n) (a view of the batch-last matrix)."""
        return self._mass().permute(2, 0, 1)

    def mass_times(self, v: torch.Tensor) -> torch.Tensor:
        """M(q) v (B, n) for v (B, n)."""
        return (self._mass() * v.T.unsqueeze(0)).sum(1).T

    def gravity(self) -> torch.Tensor:
        """G(q) (B, n)."""
        mc, hc, _ = self.composite()
        g0 = self.c["g0"][:, None]
        return ((self.s[0] * _cross(hc, g0.expand_as(hc))).sum(1) + (self.s[1] * g0).sum(1) * mc).T

    def coriolis_qd(self, qd: torch.Tensor, mo: Motion | None = None) -> torch.Tensor:
        """C(q, qd) qd (B, n) by RNEA with gravity off."""
        mo = mo or self.motion(qd)
        acc = (_prefix_sum(mo.sd[0] * mo.qdt), _prefix_sum(mo.sd[1] * mo.qdt))
        ia, iv = self.apply(acc), mo.iv
        cf = _cross_force(mo.v, iv)
        return self._project((ia[0] + cf[0], ia[1] + cf[1]))

    def bias(self, qd: torch.Tensor) -> torch.Tensor:
        """C(q, qd) qd + G(q) (B, n)."""
        return self.coriolis_qd(qd) + self.gravity()

    def coriolis_times(self, qd: torch.Tensor, y: torch.Tensor, mo: Motion | None = None) -> torch.Tensor:
        """C(q, qd) y (B, n) of the Christoffel C, for joint rates qd and any y (B, n)."""
        mo = mo or self.motion(qd)
        v, sd = mo.v, mo.sd
        yt = y.T.unsqueeze(1)
        u = (_prefix_sum(self.s[0] * yt), _prefix_sum(self.s[1] * yt))  # J_k y
        w = (_prefix_sum(sd[0] * yt), _prefix_sum(sd[1] * yt))  # dJ_k/dt y
        iw, iu, ivu = self.apply(w), self.apply(u), self.apply(_cross_motion(v, u))
        a, b = _cross_force(v, iu), _cross_force(u, mo.iv)
        return self._project((iw[0] + 0.5 * (a[0] - ivu[0] + b[0]), iw[1] + 0.5 * (a[1] - ivu[1] + b[1])))

    def coriolis_transpose_qd(self, qd: torch.Tensor, mo: Motion | None = None) -> torch.Tensor:
        """C(q, qd)^T qd = dT/dq (B, n): dS_i/dt . sum_{k>=i} I_k v_k."""
        mo = mo or self.motion(qd)
        iv = mo.iv
        return ((mo.sd[0] * _suffix_sum(iv[0])).sum(1) + (mo.sd[1] * _suffix_sum(iv[1])).sum(1)).T

    def momentum_rate(self, qd: torch.Tensor, mo: Motion | None = None) -> torch.Tensor:
        """dM/dt qd - C qd - G = C^T qd - G (B, n) (dM/dt = C + C^T for the Christoffel C)."""
        return christoffel_momentum_rate(self, qd, mo)

    def solve(self, r: torch.Tensor) -> torch.Tensor:
        """M(q)^-1 r (B, n) by a batched Cholesky factorisation. A matrix that is not positive
        definite (never, for a physical arm) gives non-finite values, which the simulator reports,
        without a per-call error check (cholesky_ex). Compiled, the factorisation written out
        (`spd_solve`), which fuses into the step: an ahead-of-time package calls torch's own
        through a fallback (UR5, one control period at B = 1: 454 against 330 us a call)."""
        if torch.compiler.is_compiling():
            return spd_solve(self.mass_matrix(), r)
        chol = torch.linalg.cholesky_ex(self.mass_matrix())[0]
        return torch.cholesky_solve(r.unsqueeze(-1), chol).squeeze(-1)

    def accel(self, qd: torch.Tensor, r: torch.Tensor, friction: Friction, gravity: bool = True) -> torch.Tensor:
        """Joint accelerations M^-1 (friction(r - C qd) - G) (B, n), friction(r, qd) = r - F(qd)."""
        return forward_dynamics(self, qd, r, friction, gravity)


class Motion:
    """Body velocities v, axis rates dS/dt (pairs of (n, 3, B)) and momenta I v at joint rates qd."""

    def __init__(self, cfg: Config, qd: torch.Tensor) -> None:
        self.cfg, self.qdt = cfg, qd.T.unsqueeze(1)  # (n, 1, B)
        s = cfg.s
        self.v = (_prefix_sum(s[0] * self.qdt), _prefix_sum(s[1] * self.qdt))
        self.sd = _cross_motion(self.v, s)
        self._iv: Pair | None = None

    @property
    def iv(self) -> Pair:
        if self._iv is None:
            self._iv = self.cfg.apply(self.v)
        return self._iv


def _sandwich(rot: torch.Tensor, inertia: torch.Tensor) -> torch.Tensor:
    """R_k Ibar_k R_k^T (n, 3, 3, B) for rotations (n, 3, 3, B) and constant inertias (n, 3, 3)."""
    ri = rot[:, :, 0].unsqueeze(2) * inertia[:, 0, None, :, None]
    ri = torch.addcmul(ri, rot[:, :, 1].unsqueeze(2), inertia[:, 1, None, :, None])
    ri = torch.addcmul(ri, rot[:, :, 2].unsqueeze(2), inertia[:, 2, None, :, None])  # R Ibar
    out = ri[:, :, 0].unsqueeze(2) * rot[:, :, 0].unsqueeze(1)
    out = torch.addcmul(out, ri[:, :, 1].unsqueeze(2), rot[:, :, 1].unsqueeze(1))
    return torch.addcmul(out, ri[:, :, 2].unsqueeze(2), rot[:, :, 2].unsqueeze(1))
