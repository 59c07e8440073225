"""The terms of `rbfn.robots.arm_terms`, written one scalar at a time for torch.compile.

The same algorithms and interface (`ArmScalarTerms(arm).at(q, payload)` -> M, C qd + G, G,
C(q, qd) y, C^T qd, M y), but every quantity is a Python float (a URDF constant) or a (B,)
tensor, so that a traced step is a graph of elementwise operations only: torch.compile fuses it
into a few loops over the environments that keep every intermediate in registers, instead of
streaming (n, 3, 3, B) tensors through memory. Constants are folded while tracing (a zero in a
rotation costs nothing). Eagerly it is slow (thousands of small operations): the simulator uses
it only while compiling (`torch.compiler.is_compiling()`), `arm_terms` otherwise.

Why it is a form of its own: the eager simulator needs few, large tensor operations
(`arm_terms`), a traced step needs scalars (this module), and code written either way is slow
the other way. It is written by hand (not generated), reads the constants that `arm_terms`
turns from `rbfn.robots.dynamics.Arm` (the payload's placement included), takes the spatial
products from `rbfn.robots.spatial`, and is tested, eagerly, against `Arm`
(tests/robots/test_dynamics_backends.py) and, compiled, against the eager step in the closed
loop's tests.

A 3-vector is a tuple of 3 scalars, a symmetric 3x3 matrix 6 (xx, yy, zz, xy, xz, yz), a
rotation 9 (row-major), a spatial vector a pair of 3-vectors (angular or moment; linear or force).
"""

from __future__ import annotations

from typing import Any

import torch

from .backend import Friction, christoffel_momentum_rate, forward_dynamics
from .dynamics import Payload
from .spatial import Spatial

__all__ = ["ArmScalarTerms", "ScalarConfig"]


# ----------------------------------------------------------------------------- scalars
def _mul(a, b):
    if isinstance(a, float):
        if a == 0.0:
            return 0.0
        if isinstance(b, float):
            return a * b
        return b if a == 1.0 else (-b if a == -1.0 else b * a)
    if isinstance(b, float):
        return _mul(b, a)
    return a * b


def _add(a, b):
    if isinstance(a, float) and a == 0.0:
        return b
    if isinstance(b, float) and b == 0.0:
        return a
    return a + b


def _sub(a, b):
    if isinstance(b, float) and b == 0.0:
        return a
    if isinstance(a, float) and a == 0.0:
        return -b
    return a - b


def _sum(*xs):
    out = 0.0
    for x in xs:
        out = _add(out, x)
    return out


# ----------------------------------------------------------------------------- vectors
def _v_add(a, b):
    return tuple(_add(x, y) for x, y in zip(a, b))


def _v_sub(a, b):
    return tuple(_sub(x, y) for x, y in zip(a, b))


def _v_scale(a, s):
    return tuple(_mul(x, s) for x in a)


def _dot(a, b):
    return _sum(*(_mul(x, y) for x, y in zip(a, b)))


def _cross(a, b):
    return (
        _sub(_mul(a[1], b[2]), _mul(a[2], b[1])),
        _sub(_mul(a[2], b[0]), _mul(a[0], b[2])),
        _sub(_mul(a[0], b[1]), _mul(a[1], b[0])),
    )


def _rot_vec(r, x):
    """R x for a rotation r (9, row-major) and a vector x."""
    return tuple(_dot(r[3 * i : 3 * i + 3], x) for i in range(3))


def _sym_vec(j, w):
    """J w for a symmetric matrix j (xx, yy, zz, xy, xz, yz)."""
    xx, yy, zz, xy, xz, yz = j
    return (
        _sum(_mul(xx, w[0]), _mul(xy, w[1]), _mul(xz, w[2])),
        _sum(_mul(xy, w[0]), _mul(yy, w[1]), _mul(yz, w[2])),
        _sum(_mul(xz, w[0]), _mul(yz, w[1]), _mul(zz, w[2])),
    )


def _s_add(a, b):
    return _v_add(a[0], b[0]), _v_add(a[1], b[1])


def _s_scale(a, s):
    return _v_scale(a[0], s), _v_scale(a[1], s)


def _s_dot(a, b):
    return _add(_dot(a[0], b[0]), _dot(a[1], b[1]))


# v x m, v x* f and I v (`rbfn.robots.spatial`) on pairs of 3-tuples; an inertia J is symmetric (6).
_SPATIAL = Spatial(_cross, _v_add, _sym_vec, lambda m, v, c: _v_sub(_v_scale(v, m), c))
_cross_motion, _cross_force = _SPATIAL.cross_motion, _SPATIAL.cross_force


def _apply(body, v):
    """Spatial inertia body = (m, h, J) times a motion vector v."""
    return _SPATIAL.inertia_times(*body, v)


def _body_add(a, b):
    return _add(a[0], b[0]), _v_add(a[1], b[1]), tuple(_add(x, y) for x, y in zip(a[2], b[2]))


_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


class ArmScalarTerms:
    """Scalar-form terms of an arm of n joints from `ArmTerms`'s float64 constants `c` (turned
    body frames); `ArmTerms.at` serves them while torch.compile traces."""

    def __init__(self, c: dict, n: int) -> None:
        self.n = n

        def snap(x: torch.Tensor) -> list:
            return torch.where(x.abs() < 1e-14, 0.0, x).tolist()  # cos(pi/2) = 6e-17 is a zero

        self.cols = snap(c["cols"])  # (n, 3, 4)
        self.mass = c["mass"].tolist()
        self.first = snap(c["first"])
        self.inertia = snap(c["inertia"])
        self.payload_pos = snap(c["payload_pos"])
        self.payload_body = c["payload_body"]
        self.g0 = tuple(float(v) for v in c["g0"])
        self.prismatic = c["prismatic"]

    def at(self, q: torch.Tensor, payload: Payload = 0.0) -> ScalarConfig:
        if q.dim() != 2 or q.shape[1] != self.n:
            raise ValueError(f"expected joint values (B, {self.n}), got {tuple(q.shape)}")
        return ScalarConfig(self, q, payload)


class ScalarConfig:
    """Kinematics and body inertias at q (B, n): the interface of `arm_terms.Config`."""

    def __init__(self, t: ArmScalarTerms, q: torch.Tensor, payload: Payload) -> None:
        self.t, self.n, self.like = t, t.n, q
        qs = q.T.contiguous().unbind(0)  # rows (B,): contiguous loads
        rots, pos, axes = [], [], []
        r = p = None
        for i in range(self.n):
            c = t.cols[i]
            if r is None:
                x = [[c[a][k] for k in range(4)] for a in range(3)]
            else:
                x = [[_sum(*(_mul(r[3 * a + j], c[j][k]) for j in range(3))) for k in range(4)] for a in range(3)]
            tr = (x[0][3], x[1][3], x[2][3])
            p = tr if p is None else _v_add(p, tr)
            z = (x[0][2], x[1][2], x[2][2])
            if t.prismatic[i]:
                r = tuple(x[a][k] for a in range(3) for k in range(3))
                p = _v_add(p, _v_scale(z, qs[i]))
            else:
                ci, si = torch.cos(qs[i]), torch.sin(qs[i])
                r = tuple(
                    e
                    for a in range(3)
                    for e in (
                        _add(_mul(x[a][0], ci), _mul(x[a][1], si)),
                        _sub(_mul(x[a][1], ci), _mul(x[a][0], si)),
                        x[a][2],
                    )
                )
            rots.append(r)
            pos.append(p)
            axes.append(z)
        last = pos[-1]
        pos = [_v_sub(pi, last) for pi in pos]  # about the last body's origin
        self.s = [((0.0, 0.0, 0.0), z) if t.prismatic[i] else (z, _cross(pos[i], z)) for i, z in enumerate(axes)]
        self.bodies = [self._body(i, rots[i], pos[i], payload) for i in range(self.n)]
        self._composite = self._m = None

    def _body(self, i: int, rot, p, payload):
        """(m, h, J sym) of body i about the reference point; the payload a point mass on its body."""
        t = self.t
        m = t.mass[i]
        hb = _rot_vec(rot, tuple(t.first[i]))
        ib = t.inertia[i]
        u = [[_sum(*(_mul(rot[3 * a + k], ib[k][b]) for k in range(3))) for b in range(3)] for a in range(3)]
        rir = [_sum(*(_mul(u[a][k], rot[3 * b + k]) for k in range(3))) for a, b in _SYM]
        if i == t.payload_body and not (isinstance(payload, (int, float)) and payload == 0):
            mp = payload if isinstance(payload, torch.Tensor) else float(payload)
            rp = _rot_vec(rot, tuple(t.payload_pos))
            m = _add(m, mp)
            hb = _v_add(hb, _v_scale(rp, mp))
            rr = _dot(rp, rp)
            rir = [_add(e, _mul(mp, _sub(rr if a == b else 0.0, _mul(rp[a], rp[b])))) for e, (a, b) in zip(rir, _SYM)]
        h = _v_add(_v_scale(p, m), hb)
        pd = _dot(p, _v_add(h, hb))
        j = tuple(
            _sub(_add(e, pd if a == b else 0.0), _add(_mul(p[a], h[b]), _mul(hb[a], p[b])))
            for e, (a, b) in zip(rir, _SYM)
        )
        return m, h, j

    # ------------------------------------------------------------------ pieces
    def composite(self):
        if self._composite is None:
            out, acc = [None] * self.n, None
            for i in range(self.n - 1, -1, -1):
                acc = self.bodies[i] if acc is None else _body_add(acc, self.bodies[i])
                out[i] = acc
            self._composite = out
        return self._composite

    def motion(self, qd: torch.Tensor) -> ScalarMotion:
        return ScalarMotion(self, qd)

    def _rows(self, xs) -> torch.Tensor:
        """(len(xs), B) from scalars (floats broadcast): contiguous stores."""
        return torch.stack([x if isinstance(x, torch.Tensor) else torch.full_like(self.like[:, 0], x) for x in xs], 0)

    def _stack(self, xs) -> torch.Tensor:
        """(B, len(xs)) (a transposed view) from scalars."""
        return self._rows(xs).T

    def _project(self, f) -> list:
        """tau_i = S_i . sum_{k>=i} f_k (list of n scalars)."""
        out, acc = [None] * self.n, None
        for i in range(self.n - 1, -1, -1):
            acc = f[i] if acc is None else _s_add(acc, f[i])
            out[i] = _s_dot(self.s[i], acc)
        return out

    def _mass(self):
        if self._m is None:
            comp = self.composite()
            f = [_apply(comp[j], self.s[j]) for j in range(self.n)]
            m = [[None] * self.n for _ in range(self.n)]
            for i in range(self.n):
                for j in range(i, self.n):
                    m[i][j] = m[j][i] = _s_dot(self.s[i], f[j])
            self._m = m
        return self._m

    def _gravity(self) -> list:
        g0 = self.t.g0
        return [_s_dot(self.s[i], (_cross(c[1], g0), _v_scale(g0, c[0]))) for i, c in enumerate(self.composite())]

    def _coriolis_qd(self, mo: ScalarMotion) -> list:
        acc, f = None, []
        for k in range(self.n):
            term = _s_scale(mo.sd[k], mo.qd[k])
            acc = term if acc is None else _s_add(acc, term)
            f.append(_s_add(_apply(self.bodies[k], acc), _cross_force(mo.v[k], mo.iv[k])))
        return self._project(f)

    # ------------------------------------------------------------------ public quantities
    def mass_matrix(self) -> torch.Tensor:
        m = self._mass()
        return torch.stack([self._rows(row) for row in m], 0).permute(2, 0, 1)

    def mass_times(self, v: torch.Tensor) -> torch.Tensor:
        m, vs = self._mass(), v.T.contiguous().unbind(0)
        return self._stack([_sum(*(_mul(m[i][j], vs[j]) for j in range(self.n))) for i in range(self.n)])

    def gravity(self) -> torch.Tensor:
        return self._stack(self._gravity())

    def solve(self, r: torch.Tensor) -> torch.Tensor:
        """M(q)^-1 r (B, n) for r (B, n): the Cholesky factorisation M = L L^T and two triangular
        solves, written out in scalars so that they fuse with the rest of the step."""
        m, n = self._mass(), self.n
        low = [[None] * n for _ in range(n)]
        inv: list[Any] = [None] * n  # 1 / L_jj
        for j in range(n):
            d = _sub(m[j][j], _sum(*(_mul(low[j][k], low[j][k]) for k in range(j))))
            inv[j] = torch.rsqrt(d) if isinstance(d, torch.Tensor) else d**-0.5
            low[j][j] = _mul(d, inv[j])  # sqrt(d)
            for i in range(j + 1, n):
                low[i][j] = _mul(_sub(m[i][j], _sum(*(_mul(low[i][k], low[j][k]) for k in range(j)))), inv[j])
        rs = r.T.contiguous().unbind(0)
        y = [None] * n
        for i in range(n):
            y[i] = _mul(_sub(rs[i], _sum(*(_mul(low[i][k], y[k]) for k in range(i)))), inv[i])
        x = [None] * n
        for i in range(n - 1, -1, -1):
            x[i] = _mul(_sub(y[i], _sum(*(_mul(low[k][i], x[k]) for k in range(i + 1, n)))), inv[i])
        return self._stack(x)

    def coriolis_qd(self, qd: torch.Tensor, mo: ScalarMotion | None = None) -> torch.Tensor:
        return self._stack(self._coriolis_qd(mo or self.motion(qd)))

    def bias(self, qd: torch.Tensor) -> torch.Tensor:
        return self._stack([_add(a, b) for a, b in zip(self._coriolis_qd(self.motion(qd)), self._gravity())])

    def coriolis_times(self, qd: torch.Tensor, y: torch.Tensor, mo: ScalarMotion | None = None) -> torch.Tensor:
        mo = mo or self.motion(qd)
        ys = y.T.contiguous().unbind(0)
        u = w = None
        f = []
        for k in range(self.n):
            du, dw = _s_scale(self.s[k], ys[k]), _s_scale(mo.sd[k], ys[k])
            u = du if u is None else _s_add(u, du)  # J_k y
            w = dw if w is None else _s_add(w, dw)  # dJ_k/dt y
            body, v = self.bodies[k], mo.v[k]
            a = _cross_force(v, _apply(body, u))
            b = _cross_force(u, mo.iv[k])
            ivu = _apply(body, _cross_motion(v, u))
            half = _s_scale(_s_add(_s_add(a, b), _s_scale(ivu, -1.0)), 0.5)
            f.append(_s_add(_apply(body, w), half))
        return self._stack(self._project(f))

    def coriolis_transpose_qd(self, qd: torch.Tensor, mo: ScalarMotion | None = None) -> torch.Tensor:
        mo = mo or self.motion(qd)
        out, acc = [None] * self.n, None
        for i in range(self.n - 1, -1, -1):
            acc = mo.iv[i] if acc is None else _s_add(acc, mo.iv[i])
            out[i] = _s_dot(mo.sd[i], acc)
        return self._stack(out)

    def momentum_rate(self, qd: torch.Tensor, mo: ScalarMotion | None = None) -> torch.Tensor:
        return christoffel_momentum_rate(self, qd, mo)

    def accel(self, qd: torch.Tensor, r: torch.Tensor, friction: Friction, gravity: bool = True) -> torch.Tensor:
        """M^-1 (friction(r - C qd) - G) by the scalar Cholesky solve (`solve`), fused with the
        rest of the step (torch.linalg's batched LAPACK calls would run apart and cost as much as
        the whole fused step)."""
        return forward_dynamics(self, qd, r, friction, gravity)


class ScalarMotion:
    """Body velocities v_k, axis rates dS_k/dt and momenta I_k v_k at joint rates qd (B, n)."""

    def __init__(self, cfg: ScalarConfig, qd: torch.Tensor) -> None:
        self.qd = qd.T.contiguous().unbind(0)
        self.v, self.sd, v = [], [], None
        for k in range(cfg.n):
            term = _s_scale(cfg.s[k], self.qd[k])
            v = term if v is None else _s_add(v, term)
            self.v.append(v)
            self.sd.append(_cross_motion(v, cfg.s[k]))
        self.iv = [_apply(b, v) for b, v in zip(cfg.bodies, self.v)]
