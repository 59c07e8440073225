"""Batched rigid-body dynamics of any serial chain read from a URDF: M(q), C(q, qd), G(q) in torch.

    M(q) qdd + C(q, qd) qd + G(q) = tau

The chain runs from the URDF's root link to `end_link`; its revolute, continuous and prismatic
joints are the n degrees of freedom, in order from the root. Every other link is lumped, as a
rigid load, into the moving body it hangs from: links joined by fixed joints, and subtrees behind
joints that are not on the chain (fingers, ...), which are held at zero. Links rigidly fixed to
the root carry no dynamics. A payload is a point mass (kg) at the origin of `end_link` (or of
another link, `payload_link`).

`Arm` is the specification of the dynamics: plain, batch-first (B, n), the reference that every
other form is tested against (tests/robots/test_dynamics_backends.py: the simulator's forms, the
SCARA's closed form, Pinocchio, MuJoCo). The simulator's fast form, `rbfn.robots.arm_terms`
(batch-last, eager or compiled), reads the same lumped constants (`Arm.model`) and uses the same
products of spatial vectors (`rbfn.robots.spatial`).

The payload is placed once, by `_build` (`_Model.payload_body`, `payload_pos`: the point in that
body's frame), and every form reads it from there. Its inertia, (m, m r, m (r.r 1 - r r^T)) for
the point r, is added where each form builds its body inertias: here in body axes, before the
rotation to the root frame (`Arm._bodies`); in the simulator's form in root axes, after it
(`arm_terms.Config`). The two orders round differently and the simulator's numbers are those of
the latter, so another payload model (a rigid body instead of a point) is written in those two
places; the backend test fails until they agree.

Algorithms, all in root-frame axes with spatial vectors (angular; linear) referred to one point
fixed in space, so that the inertias of bodies add without transforms and every recursion of the
composite rigid body algorithm (CRBA) and of recursive Newton-Euler (RNEA) becomes a cumulative
sum over the chain (vectorised over the batch; the only Python loop is the n-step forward
kinematics). The point is the last body's origin at the current q: inertias about a distant point
(the root) lose float32 digits to cancellation on the wrist entries of M (6e-5 relative on the
Panda's M_77 about the root, 1.6e-6 about the wrist).

* S_i (6,): joint i's motion axis; v_i = sum_{k<=i} S_k qd_k; dS_i/dt = v_i x S_i.
* I_i: body i's spatial inertia, kept as (mass m, first moment h = m c (3,), rotational inertia
  J about the origin (3, 3)); I^c_i = sum_{k>=i} I_k, the composite inertia.
* CRBA: M_ij = S_i . I^c_max(i,j) S_j.
* RNEA: a_i = a_g + sum_{k<=i} (dS_k/dt qd_k + S_k qdd_k), a_g = -gravity;
  f_i = I_i a_i + v_i x* I_i v_i; tau_i = S_i . sum_{k>=i} f_k.
* C: the Christoffel-symbol matrix C_ij = sum_k Gamma_ijk qd_k,
  Gamma_ijk = (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i) / 2, in the closed form
  C = sum_k J_k^T (I_k dJ_k/dt + B_k J_k), B_k = (v_k x* I_k - I_k v_k x + (I_k v_k) xbar*) / 2
  (Echeandia and Wensing, "Numerical methods to compute the Coriolis matrix and Christoffel
  symbols for rigid-body systems", 2021), where J_k is body k's Jacobian and f xbar* v = v x* f.
  Summed over bodies this needs only composites of I, dI/dt and I v, so C costs O(n^2) after the
  kinematics instead of the O(n^3) (B, n, n, n) tensor dM/dq_k: for i <= j
  C_ij = S_i . (I^c_j dS_j/dt + dI^c_j/dt S_j / 2 + S_j x* (I v)^c_j / 2), and for i > j
  C_ij = S_j . (dI^c_i/dt S_i / 2 - S_i x* (I v)^c_i / 2) + dS_j/dt . I^c_i S_i.
  It satisfies C qd = RNEA bias, dM/dt = C + C^T and Gamma_ijk = Gamma_ikj, which single out the
  Christoffel matrix (checked against autograd Christoffel symbols in the tests).

URDF origins and inertials are parsed from the XML's floats in float64, lumped once at load and
cached per dtype and device; every method follows the dtype and device of its inputs. The URDF
is read and parsed as the kinematics reads it (`rbfn.robots.kinematics.urdf_text`, `parse_urdf`):
a file only from a `pathlib.Path`, a str is a preset's name or URDF text, never a file name.

Why one module of over 500 lines: `Arm`, the reference every other form is tested against,
and the lumping of a URDF into its bodies (`_build`) agree term by term; the payload model is
written here once for both.
"""

from __future__ import annotations

import logging
import math
import os
import reprlib
from dataclasses import dataclass
from typing import Any

import torch
from pytorch_kinematics.urdf_parser_py.urdf import URDF

from ..config import ROBOT_PRESETS
from .kinematics import _matrix, _path_to, is_urdf_text, parse_urdf, urdf_path, urdf_text
from .registry import preset
from .spatial import SIX, cross, dot, matvec, outer

__all__ = ["Arm", "MAX_MASS", "load_arm", "urdf_source"]

_MOVING = ("revolute", "continuous", "prismatic")
MAX_MASS = 1e6
"""Heaviest link a moving body may carry, kg (1000 t: far beyond any arm's link; 1e30 kg is a typo)."""
INERTIA_TOL = 1e-6
"""Relative tolerance of the inertia checks (a URDF's rounded digits): a principal moment may fall
below 0, or exceed the sum of the other two, by this share of the largest."""
SINGULAR = 1e-12
"""M(q)'s smallest eigenvalue at or below this share of its largest: singular (no inverse)."""

Payload = float | torch.Tensor
_WARNED: set[str] = set()  # the notes `Arm.warn_notes` logged


# ----------------------------------------------------------------------------- URDF parsing
def _pose(origin) -> torch.Tensor:
    """Homogeneous transform (4, 4) float64 (m) of a URDF <origin> (None is the identity)."""
    return torch.tensor(_matrix(origin), dtype=torch.float64)


def _link_inertia(link, to_body: torch.Tensor) -> tuple[float, torch.Tensor, torch.Tensor]:
    """(mass kg, first moment (3,) kg m, inertia (3, 3) kg m^2 about the body origin) of a link
    whose frame is `to_body` (4, 4) in the body frame."""
    zero = (0.0, torch.zeros(3, dtype=torch.float64), torch.zeros(3, 3, dtype=torch.float64))
    inertial = link.inertial
    if inertial is None or not inertial.mass:
        return zero
    m = float(inertial.mass)
    i = inertial.inertia
    ic = (
        torch.zeros(3, 3, dtype=torch.float64)
        if i is None
        else torch.tensor([[i.ixx, i.ixy, i.ixz], [i.ixy, i.iyy, i.iyz], [i.ixz, i.iyz, i.izz]], dtype=torch.float64)
    )
    com = to_body @ _pose(inertial.origin)  # COM frame in the body frame
    rot, c = com[:3, :3], com[:3, 3]
    j = rot @ ic @ rot.T + m * (c.dot(c) * torch.eye(3, dtype=torch.float64) - torch.outer(c, c))
    return m, m * c, j


def urdf_source(name_or_urdf: str | bytes | os.PathLike, arg: str = "name_or_urdf") -> tuple[str, str]:
    """(URDF text, its name in messages) of a packaged robot's name (`rbfn.config.ROBOT_PRESETS`: its URDF), a URDF
    file (a `pathlib.Path`), the URDF's text (a str: never taken for a file name) or its bytes;
    `arg` names the argument in messages."""
    if isinstance(name_or_urdf, str) and name_or_urdf in ROBOT_PRESETS:
        return urdf_text(urdf_path(name_or_urdf))
    if isinstance(name_or_urdf, str) and not is_urdf_text(name_or_urdf):
        raise ValueError(
            f"{arg}={reprlib.repr(name_or_urdf)} is neither a preset nor URDF text; allowed: "
            f"{', '.join(ROBOT_PRESETS)}, the URDF's text or bytes, or a pathlib.Path of a URDF file"
        )
    return urdf_text(name_or_urdf)


@dataclass(frozen=True)
class _Model:
    """Constants of the lumped chain in float64 (n moving joints, bodies 0..n-1)."""

    joint_names: list[str]
    prismatic: torch.Tensor  # (n,) bool
    placement: torch.Tensor  # (n, 4, 4): joint i's frame at q_i = 0 in body i-1's frame
    axis: torch.Tensor  # (n, 3) unit joint axes in the joint frames
    mass: torch.Tensor  # (n,) kg
    first_moment: torch.Tensor  # (n, 3) kg m, about body i's origin, body axes
    inertia: torch.Tensor  # (n, 3, 3) kg m^2, about body i's origin, body axes
    payload_body: int  # body carrying the payload (-1: fixed to the root)
    payload_pos: torch.Tensor  # (3,) m, payload point in that body's frame
    lower: torch.Tensor  # (n,) joint limits, rad or m (+-inf where unlimited)
    upper: torch.Tensor
    effort: torch.Tensor  # (n,) the URDF's effort limits, N m or N (inf where not given)
    end_pose: torch.Tensor  # (4, 4): the end link's frame in body n-1's frame
    body_links: tuple[tuple[str, ...], ...] = ()  # (n,): the links lumped into each body
    problems: tuple[str, ...] = ()  # why these dynamics cannot be simulated, one line each (`Arm.problems`)
    notes: tuple[str, ...] = ()  # inertials that are not physical but do not matter here (`Arm.notes`)


def _moments(inertia: torch.Tensor) -> list[float]:
    """Principal moments (3,) kg m^2, ascending, of a symmetric inertia (3, 3)."""
    return torch.linalg.eigvalsh(inertia).tolist()


def _unphysical(moments: list[float]) -> str:
    """What is wrong with principal moments (ascending, kg m^2) of an inertia about a centre of mass
    ("" where nothing is): one below 0 (not positive semi-definite), or the largest above the sum
    of the other two (the triangle inequality, which every real mass distribution meets), each
    beyond INERTIA_TOL of the largest (and 1e-12 kg m^2)."""
    a, b, c = moments
    tol = INERTIA_TOL * max(abs(c), abs(a)) + 1e-12  # (and an absolute 1e-12 kg m^2: zero, rounded)
    if a < -tol:
        return (
            f"principal moments {[float(f'{v:.4g}') for v in moments]} kg m^2, one below 0 (not positive semi-definite)"
        )
    if c > a + b + tol:
        return (
            f"principal moments {[float(f'{v:.4g}') for v in moments]} kg m^2, the largest above the sum of the "
            "other two (the triangle inequality)"
        )
    return ""


def _com_inertia(mass: float, first: torch.Tensor, inertia: torch.Tensor) -> torch.Tensor:
    """Rotational inertia (3, 3) about the centre of mass of a body of `mass` kg, first moment
    (3,) kg m and rotational inertia (3, 3) kg m^2 about its origin."""
    if mass <= 0:
        return inertia
    c = first / mass
    return inertia - mass * (c.dot(c) * torch.eye(3, dtype=torch.float64) - torch.outer(c, c))


def _inertial_problems(
    robot: URDF, located: dict, names: list[str], mass: torch.Tensor, first: torch.Tensor, inertia: torch.Tensor
) -> tuple[tuple[tuple[str, ...], ...], tuple[str, ...], tuple[str, ...]]:
    """(the links lumped into each body, problems, notes) of the URDF's inertials: a moving body's
    link with a negative mass or one above MAX_MASS, and a body whose lumped inertia about its centre
    of mass is unphysical (`_unphysical`), are problems naming the link(s); a link whose own
    inertia is unphysical while its body's lumped one is not, or that is fixed to the root (which
    carries no dynamics), is a note. `located`: link -> (body, pose)."""
    n = len(names)
    links: list[list[str]] = [[] for _ in range(n)]
    problems: list[str] = []
    notes: list[str] = []
    own: dict[str, str] = {}
    allowed = "allowed: principal moments >= 0, each at most the sum of the other two (a physical body)"
    for name, link in robot.link_map.items():
        body, inertial = located[name][0], link.inertial
        if body >= 0:
            links[body].append(name)
        if inertial is None:
            continue
        m = float(inertial.mass or 0.0)
        if body >= 0 and not 0 <= m <= MAX_MASS:
            problems.append(
                f"link {name!r} (moved by joint {names[body]!r}) has mass {m:g} kg; allowed: a mass in "
                f"[0, {MAX_MASS:g}] kg"
            )
        i = inertial.inertia
        if i is not None:
            t = torch.tensor([[i.ixx, i.ixy, i.ixz], [i.ixy, i.iyy, i.iyz], [i.ixz, i.iyz, i.izz]], dtype=torch.float64)
            wrong = _unphysical(_moments(t))
            if wrong and body < 0:
                notes.append(f"link {name!r} has an <inertia> with {wrong} (fixed to the root: no dynamics use it)")
            elif wrong:
                own[name] = f"link {name!r} has an <inertia> with {wrong}"
    for b in range(n):
        wrong = _unphysical(_moments(_com_inertia(float(mass[b]), first[b], inertia[b])))
        bad = [own[k] for k in links[b] if k in own]
        if wrong:
            what = "; ".join(bad) if bad else f"the links {links[b]} lumped together have {wrong}"
            problems.append(f"{what} (the body that joint {names[b]!r} moves); {allowed}")
        else:
            notes += [
                f"{k} (lumped into the body that joint {names[b]!r} moves, which as a whole is physical)" for k in bad
            ]
    return tuple(tuple(k) for k in links), tuple(problems), tuple(notes)


def _build(robot: URDF, source: str, end_link: str, payload_link: str | None) -> _Model:
    path = _path_to(robot, source, end_link)  # joints root -> end_link, the URDF one tree
    payload_link = end_link if payload_link is None else payload_link
    if payload_link not in robot.link_map:
        raise ValueError(f"payload link {payload_link!r} is not a link of the URDF; links: {sorted(robot.link_map)}")
    root = path[0].parent if path else end_link

    # Walk the chain: body index and pose in its body frame of every chain link.
    eye = torch.eye(4, dtype=torch.float64)
    where = {root: (-1, eye)}  # link -> (body, pose in body frame)
    names, prismatic, placement, axis, lower, upper, effort = [], [], [], [], [], [], []
    for joint in path:
        jname, child = joint.name, joint.child
        body, pose = where[joint.parent]
        if joint.type == "fixed":
            where[child] = (body, pose @ _pose(joint.origin))
            continue
        if joint.type not in _MOVING:
            raise ValueError(
                f"joint {jname!r} on the chain to {end_link!r} is {joint.type!r}; "
                f"supported: fixed, {', '.join(_MOVING)}"
            )
        if joint.mimic is not None:
            raise ValueError(
                f"joint {jname!r} on the chain mimics {joint.mimic.joint!r}; "
                "mimic joints are not supported on the chain"
            )
        a = torch.tensor([float(v) for v in (joint.axis or (1.0, 0.0, 0.0))], dtype=torch.float64)
        if a.norm() == 0:
            raise ValueError(f"joint {jname!r} has a zero axis")
        names.append(jname)
        prismatic.append(joint.type == "prismatic")
        placement.append(pose @ _pose(joint.origin))
        axis.append(a / a.norm())
        limit = joint.limit if joint.type != "continuous" else None
        low = None if limit is None else limit.lower
        high = None if limit is None else limit.upper
        lower.append(-math.inf if low is None else float(low))
        upper.append(math.inf if high is None else float(high))
        given = None if joint.limit is None else joint.limit.effort
        effort.append(math.inf if given is None or float(given) <= 0 else float(given))
        where[child] = (len(names) - 1, eye)

    # Every other link hangs, through joints held at zero, from its nearest chain ancestor.
    def locate(link: str):
        if link not in where:
            jname, parent = robot.parent_map[link]
            body, pose = locate(parent)
            where[link] = (body, pose @ _pose(robot.joint_map[jname].origin))
        return where[link]

    n = len(names)
    if n == 0:
        raise ValueError(f"the chain from {root!r} to {end_link!r} has no moving joint")
    mass = torch.zeros(n, dtype=torch.float64)
    first = torch.zeros(n, 3, dtype=torch.float64)
    inertia = torch.zeros(n, 3, 3, dtype=torch.float64)
    for name, link in robot.link_map.items():
        body, pose = locate(name)
        if body < 0:
            continue
        m, h, j = _link_inertia(link, pose)
        mass[body] += m
        first[body] += h
        inertia[body] += j
    pbody, ppose = locate(payload_link)
    body_links, problems, notes = _inertial_problems(robot, where, names, mass, first, inertia)
    return _Model(
        names,
        torch.tensor(prismatic),
        torch.stack(placement),
        torch.stack(axis),
        mass,
        first,
        inertia,
        pbody,
        ppose[:3, 3].clone(),
        torch.tensor(lower, dtype=torch.float64),
        torch.tensor(upper, dtype=torch.float64),
        torch.tensor(effort, dtype=torch.float64),
        where[end_link][1].clone(),
        body_links,
        problems,
        notes,
    )


# ----------------------------------------------------------------------------- chain sums
def _rev_cumsum(x: torch.Tensor) -> torch.Tensor:
    """sum_{k >= i} x_k along the body dimension 1."""
    return x.flip(1).cumsum(1).flip(1)


class _Bodies:
    """World-frame spatial inertias of the n bodies of a batch, about the reference point.

    Kept as mass m (B, n), first moment h (B, n, 3) and the pieces of J = R Ibar R^T
    + (p.(h + h'))1 - p h^T - h' p^T (p body origin, h' = R (first moment about p)), so that
    applying an inertia to a vector needs no (B, n, 3, 3) matrix; `j()` forms J when needed.
    """

    def __init__(self, rot, pos, mass, first, inertia, eye):
        self.rot, self.pos, self.ibar, self.eye = rot, pos, inertia, eye
        self.hb = matvec(rot, first)  # h' (B, n, 3)
        self.m = mass.expand(rot.shape[:2])
        self.h = self.m.unsqueeze(-1) * pos + self.hb
        self._j = None

    def apply(self, v: torch.Tensor) -> torch.Tensor:
        """I_k v_k (B, n, 6) for v (B, n, 6): `SIX.inertia_times` without forming J."""
        w, v0 = v[..., :3], v[..., 3:]
        p, h, hb, rot = self.pos, self.h, self.hb, self.rot
        jw = (
            matvec(rot, matvec(self.ibar, matvec(rot.transpose(-1, -2), w)))
            + dot(p, h + hb) * w
            - p * dot(h, w)
            - hb * dot(p, w)
        )
        return torch.cat([jw + cross(h, v0), self.m.unsqueeze(-1) * v0 - cross(h, w)], -1)

    def j(self) -> torch.Tensor:
        """J (B, n, 3, 3) kg m^2 about the reference point."""
        if self._j is None:
            p, h, hb, rot = self.pos, self.h, self.hb, self.rot
            self._j = (
                rot @ self.ibar @ rot.transpose(-1, -2)
                + dot(p, h + hb).unsqueeze(-1) * self.eye
                - outer(p, h)
                - outer(hb, p)
            )
        return self._j


# ----------------------------------------------------------------------------- the arm
class Arm:
    """Rigid-body dynamics of a serial chain, the specification; build it with `load_arm`.

    Joint values q (B, n) are rad (revolute) or m (prismatic), qd in rad/s or m/s; M in kg m^2
    (kg on prismatic rows and columns), C qd, G and tau in N m or N. `payload` is kg, a float or
    (B,). Any leading batch shape works; outputs keep the dtype and device of q.
    """

    def __init__(
        self,
        model: _Model,
        gravity: float | tuple[float, float, float],
        end_link: str,
        dtype: torch.dtype,
        device: str | torch.device,
    ):
        self._model = model
        self.end_link = end_link
        self.joint_names = list(model.joint_names)
        self.n = len(self.joint_names)
        g = [0.0, 0.0, -float(gravity)] if isinstance(gravity, (int, float)) else [float(v) for v in gravity]
        self.gravity_vector = torch.tensor(g, dtype=torch.float64)  # (3,) m/s^2, root frame
        self._cache: dict = {}
        self.dtype, self.device = dtype, torch.device(device)
        self._consts(dtype, self.device)

    def __repr__(self) -> str:
        return f"Arm(n={self.n}, joints={self.joint_names}, end_link={self.end_link!r})"

    @property
    def model(self) -> _Model:
        """The lumped chain's constants, float64 (shared, read-only: the arm's dynamics use them)."""
        return self._model

    @property
    def prismatic(self) -> list[bool]:
        """Per joint (n): True where the joint is prismatic (m), False where revolute (rad)."""
        return self._model.prismatic.tolist()

    def joint_limits(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(lower, upper) (n,) float64 in rad or m; -inf, inf for continuous joints."""
        return self._model.lower.clone(), self._model.upper.clone()

    @property
    def problems(self) -> list[str]:
        """Why these dynamics cannot be simulated (M qdd = tau - C qd - G has no solution, or a
        meaningless one), one line each naming the link or joint and what is allowed; empty where
        they can: a moving body's link with a mass outside [0, MAX_MASS] kg, a body whose inertia
        about its centre of mass is unphysical (a principal moment below 0, or one above the sum of
        the other two), and a mass matrix M(q) that is not positive definite at seeded joint
        vectors within the limits (a joint that moves no mass or inertia: a massless last link, a
        URDF without inertials). Links fixed to the root, and zero-mass links beyond which some
        mass moves (a tool frame), are fine."""
        if "problems" not in self._cache:
            self._cache["problems"] = list(self._model.problems) or self._mass_matrix_problems()
        return list(self._cache["problems"])

    @property
    def notes(self) -> list[str]:
        """Links whose own inertia is unphysical while the body they are lumped into is not (the
        simulation is fine; the URDF is worth a look), one line each."""
        return list(self._model.notes)

    def warn_notes(self, logger: logging.Logger, where: str) -> None:
        """Log each of `notes` as a warning, prefixed by `where`, once per process (the same URDF is
        loaded by the derivation and by each check of the closed loop)."""
        for note in self.notes:
            if note not in _WARNED:
                _WARNED.add(note)
                logger.warning("%s: %s", where, note)

    def _mass_matrix_problems(self, samples: int = 16, seed: int = 0) -> list[str]:
        """[the first joint that moves no mass or inertia, in words] where M(q) is singular or
        indefinite at one of `samples` seeded joint vectors within the limits ([-pi, pi] rad or
        [-1, 1] m where there are none), else []."""
        md = self._model
        span = torch.where(md.prismatic, 1.0, math.pi).to(torch.float64)
        lo = torch.where(torch.isfinite(md.lower), md.lower, -span)
        hi = torch.where(torch.isfinite(md.upper), md.upper, span)
        g = torch.Generator().manual_seed(seed)
        q = lo + (hi - lo) * torch.rand(samples, self.n, generator=g, dtype=torch.float64)
        values, vectors = torch.linalg.eigh(self.mass_matrix(q))
        ratio = values[:, 0] / values[:, -1].abs().clamp_min(1e-300)
        k = int(ratio.argmin())
        if float(ratio[k]) > SINGULAR:
            return []
        j = int(vectors[k, :, 0].abs().argmax())  # the joint the null motion turns most
        carried = [link for body in md.body_links[j:] for link in body] if md.body_links else []
        return [
            f"joint {self.joint_names[j]!r} moves no mass or inertia: the mass matrix M(q) is "
            f"{'singular' if float(values[k, 0]) >= 0 else 'not positive definite'} (eigenvalues "
            f"{float(values[k, 0]):.3g} to {float(values[k, -1]):.3g}) at q = {[round(v, 3) for v in q[k].tolist()]}, "
            f"and the links it carries ({carried}) have no mass or inertia it can move; allowed: "
            "every moving joint carrying some mass or inertia beyond it (the URDF's <inertial> elements)"
        ]

    def check_physics(self, what: str = "the closed loop") -> None:
        """ValueError with the first of `problems` (what `what` cannot do with this arm)."""
        if self.problems:
            raise ValueError(f"{what} cannot simulate this arm's dynamics: {self.problems[0]}")

    def effort_limits(self) -> torch.Tensor:
        """The URDF's effort limits (n,) float64 in N m (N for a prismatic joint); inf where a
        joint gives none (or 0, which URDFs use for "not given")."""
        return self._model.effort.clone()

    def frames(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The lumped chain's kinematics, float64: joint i's frame at q_i = 0 in body i-1's frame
        (n, 4, 4) (m), unit axes (n, 3) in the joint frames, prismatic (n,) bool, and the end
        link's frame in body n-1's frame (4, 4)."""
        md = self._model
        return md.placement.clone(), md.axis.clone(), md.prismatic.clone(), md.end_pose.clone()

    def _consts(self, dtype: torch.dtype, device: torch.device) -> dict:
        """Per-joint and per-body constants in `dtype` on `device`, computed once."""
        key = (dtype, device)
        if key not in self._cache:
            md = self._model
            a = md.axis
            skew = torch.zeros(self.n, 3, 3, dtype=torch.float64)
            skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
            skew = skew - skew.transpose(1, 2)
            rot0, p0 = md.placement[:, :3, :3], md.placement[:, :3, 3]
            axis0 = matvec(rot0, a)
            pp = md.payload_pos
            c: dict[str, Any] = {
                "rot0": rot0,
                "p0": p0,
                "axis0": axis0,
                "rot0_skew": rot0 @ skew,
                "rot0_aa": outer(axis0, a),
                "mass": md.mass,
                "first": md.first_moment,
                "inertia": md.inertia,
                "payload_pos": pp,
                "payload_inertia": pp.dot(pp) * torch.eye(3, dtype=torch.float64) - outer(pp, pp),
                "eye": torch.eye(3, dtype=torch.float64),
                "revolute": (~md.prismatic).to(torch.float64).unsqueeze(-1),
                "a_g": torch.cat([torch.zeros(3, dtype=torch.float64), -self.gravity_vector]),
            }
            c = {k: v.to(dtype=dtype, device=device) for k, v in c.items()}
            c["prismatic"] = md.prismatic.tolist()
            c["upper"] = torch.ones(self.n, self.n, dtype=torch.bool, device=device).triu()
            onehot = torch.zeros(self.n, dtype=dtype, device=device)
            if md.payload_body >= 0:
                onehot[md.payload_body] = 1.0
            c["onehot"] = onehot
            self._cache[key] = c
        return self._cache[key]

    # ------------------------------------------------------------------ building blocks
    def _flat(self, *xs: torch.Tensor) -> tuple[torch.Size, list[torch.Tensor]]:
        if xs[0].shape[-1] != self.n:
            raise ValueError(f"expected joint values (..., {self.n}), got {tuple(xs[0].shape)}")
        return xs[0].shape[:-1], [x.reshape(-1, self.n) for x in xs]

    def _kinematics(self, q: torch.Tensor, c: dict, centred: bool = True):
        """Body rotations (B, n, 3, 3), origins (B, n, 3) and joint motion axes S (B, n, 6).

        Root axes; with `centred` positions are relative to the last body's origin (a point
        fixed in space at this instant), which keeps float32 free of the cancellation that
        inertias about a distant point suffer.
        """
        batch = q.shape[0]
        rots, origins, axes = [], [], []
        rot_prev: Any = None
        pos_prev: Any = None
        for i, prismatic in enumerate(c["prismatic"]):
            if rot_prev is None:
                rot_j, p_j = c["rot0"][i].expand(batch, 3, 3), c["p0"][i].expand(batch, 3)
                z = c["axis0"][i].expand(batch, 3)
            else:
                rot_j = rot_prev @ c["rot0"][i]
                p_j, z = pos_prev + matvec(rot_prev, c["p0"][i]), matvec(rot_prev, c["axis0"][i])
            qi = q[:, i, None]
            if prismatic:
                rot, p = rot_j, p_j + z * qi
            else:
                cq, sq = torch.cos(qi).unsqueeze(-1), torch.sin(qi).unsqueeze(-1)
                local = cq * c["rot0"][i] + sq * c["rot0_skew"][i] + (1 - cq) * c["rot0_aa"][i]
                rot, p = (local if rot_prev is None else rot_prev @ local), p_j
            rots.append(rot)
            origins.append(p)
            axes.append(z)
            rot_prev, pos_prev = rot, p
        rot, pos, z = torch.stack(rots, 1), torch.stack(origins, 1), torch.stack(axes, 1)
        if centred:
            pos = pos - pos[:, -1:]
        rev = c["revolute"]  # (n, 1): 1 revolute, 0 prismatic
        s = torch.cat([z * rev, torch.where(rev > 0, cross(pos, z), z)], -1)
        return rot, pos, s

    def _bodies(self, q: torch.Tensor, payload: Payload, centred: bool = True):
        """(constants, S (B, n, 6), bodies) for q (B, n), payload in kg (float or (B,))."""
        c = self._consts(q.dtype, q.device)
        rot, pos, s = self._kinematics(q, c, centred)
        mass, first, inertia = c["mass"], c["first"], c["inertia"]
        none = isinstance(payload, (int, float)) and payload == 0
        if self._model.payload_body >= 0 and not none:
            # The payload changes the carrying body's constants: m, m c_b and Ibar about its origin.
            mp = torch.as_tensor(payload, dtype=q.dtype, device=q.device).reshape(-1, 1)
            mp = mp * c["onehot"]  # (1 or B, n)
            mass = mass + mp
            first = first + mp.unsqueeze(-1) * c["payload_pos"]
            inertia = inertia + mp[..., None, None] * c["payload_inertia"]
        return c, s, _Bodies(rot, pos, mass, first, inertia, c["eye"])

    def _mass_matrix(self, c: dict, s: torch.Tensor, b: _Bodies) -> torch.Tensor:
        f = SIX.inertia_times(_rev_cumsum(b.m), _rev_cumsum(b.h), _rev_cumsum(b.j()), s)  # I^c_j S_j
        up = s @ f.transpose(1, 2)  # S_i . F_j
        return torch.where(c["upper"], up, up.transpose(1, 2))

    def _rnea(self, c: dict, s: torch.Tensor, b: _Bodies, qd: torch.Tensor, qdd: torch.Tensor | None) -> torch.Tensor:
        v = (s * qd.unsqueeze(-1)).cumsum(1)
        acc = SIX.cross_motion(v, s) * qd.unsqueeze(-1)
        if qdd is not None:
            acc = acc + s * qdd.unsqueeze(-1)
        f = b.apply(c["a_g"] + acc.cumsum(1)) + SIX.cross_force(v, b.apply(v))
        return (s * _rev_cumsum(f)).sum(-1)

    # ------------------------------------------------------------------ public quantities
    def mass_matrix(self, q: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """Inertia matrix M(q) (B, n, n) for q (B, n), by CRBA."""
        shape, (q,) = self._flat(q)
        return self._mass_matrix(*self._bodies(q, payload)).reshape(*shape, self.n, self.n)

    def inverse_dynamics(
        self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor | None = None, payload: Payload = 0.0
    ) -> torch.Tensor:
        """Joint torques tau = M qdd + C qd + G (B, n) by RNEA for q, qd, qdd (B, n)."""
        shape, xs = self._flat(q, qd) if qdd is None else self._flat(q, qd, qdd)
        c, s, b = self._bodies(xs[0], payload)
        tau = self._rnea(c, s, b, xs[1], xs[2] if qdd is not None else None)
        return tau.reshape(*shape, self.n)

    def bias(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """C(q, qd) qd + G(q) (B, n) by RNEA for q, qd (B, n)."""
        return self.inverse_dynamics(q, qd, None, payload)

    def dynamics(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """(M (B, n, n), C qd + G (B, n)) sharing one kinematics pass; for q, qd (B, n)."""
        shape, (q, qd) = self._flat(q, qd)
        c, s, b = self._bodies(q, payload)
        return (
            self._mass_matrix(c, s, b).reshape(*shape, self.n, self.n),
            self._rnea(c, s, b, qd, None).reshape(*shape, self.n),
        )

    def gravity(self, q: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """Gravity torques G(q) (B, n) for q (B, n)."""
        shape, (q,) = self._flat(q)
        c, s, b = self._bodies(q, payload)
        a = c["a_g"][3:].expand_as(b.h)
        f = torch.cat([cross(_rev_cumsum(b.h), a), _rev_cumsum(b.m).unsqueeze(-1) * a], -1)
        return (s * f).sum(-1).reshape(*shape, self.n)

    def _velocity_terms(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload):
        """Pieces of C and dM/dt, each (B, n, 6): S, dS/dt, F = I^c S, E = I^c dS/dt,
        D = (dI^c/dt) S / 2, X = S x* (I v)^c."""
        c, s, b = self._bodies(q, payload)
        v = (s * qd.unsqueeze(-1)).cumsum(1)
        sd = SIX.cross_motion(v, s)
        w, v0 = v[..., :3], v[..., 3:]
        j, h = b.j(), b.h
        # d/dt of (h, J) of each body moving with spatial velocity v (m is constant):
        # dh/dt = w x h + m v0, dJ/dt = [w] J - J [w] + 2 (h.v0) 1 - v0 h^T - h v0^T.
        wj = torch.linalg.cross(w.unsqueeze(-1).expand_as(j), j, dim=-2)  # [w] J
        jd = wj + wj.transpose(-1, -2) + 2 * dot(h, v0).unsqueeze(-1) * c["eye"] - outer(v0, h) - outer(h, v0)
        hd = cross(w, h) + b.m.unsqueeze(-1) * v0
        mc, hc, jc = _rev_cumsum(b.m), _rev_cumsum(h), _rev_cumsum(j)
        f, e = SIX.inertia_times(mc, hc, jc, s), SIX.inertia_times(mc, hc, jc, sd)
        d = 0.5 * SIX.inertia_times(torch.zeros_like(mc), _rev_cumsum(hd), _rev_cumsum(jd), s)
        x = SIX.cross_force(s, _rev_cumsum(b.apply(v)))
        return c, s, sd, f, e, d, x

    def coriolis(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """Coriolis and centrifugal matrix C(q, qd) (B, n, n) of the Christoffel symbols of M,
        for q, qd (B, n): dM/dt - 2C is skew-symmetric and C qd = bias - G."""
        shape, (q, qd) = self._flat(q, qd)
        c, s, sd, f, e, d, x = self._velocity_terms(q, qd, payload)
        up = s @ (d + e + 0.5 * x).transpose(1, 2)  # i <= j
        lo = (d - 0.5 * x) @ s.transpose(1, 2) + f @ sd.transpose(1, 2)  # i > j
        return torch.where(c["upper"], up, lo).reshape(*shape, self.n, self.n)

    def mass_matrix_dot(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """Time derivative of M along the motion, dM/dt (B, n, n), for q, qd (B, n)."""
        shape, (q, qd) = self._flat(q, qd)
        c, s, sd, f, e, d, _ = self._velocity_terms(q, qd, payload)
        up = sd @ f.transpose(1, 2) + s @ (2 * d + e).transpose(1, 2)
        return torch.where(c["upper"], up, up.transpose(1, 2)).reshape(*shape, self.n, self.n)

    def kinetic_energy(self, q: torch.Tensor, qd: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """Kinetic energy 1/2 qd^T M qd (B,) in J, summed over the bodies."""
        shape, (q, qd) = self._flat(q, qd)
        _, s, b = self._bodies(q, payload)
        v = (s * qd.unsqueeze(-1)).cumsum(1)
        return 0.5 * (v * b.apply(v)).sum((-1, -2)).reshape(shape)

    def potential_energy(self, q: torch.Tensor, payload: Payload = 0.0) -> torch.Tensor:
        """Gravitational potential energy (B,) in J, zero at the root origin: -sum_k m_k g . c_k."""
        shape, (q,) = self._flat(q)
        c, _, b = self._bodies(q, payload, centred=False)
        return (b.h.sum(1) * c["a_g"][3:]).sum(-1).reshape(shape)


# ----------------------------------------------------------------------------- loading
def load_arm(
    name_or_urdf: str | bytes | os.PathLike,
    end_link: str | None = None,
    gravity: float | None = None,
    dtype: torch.dtype = torch.float64,
    device: str | torch.device = "cpu",
    payload_link: str | None = None,
) -> Arm:
    """Dynamics of a preset ("scara", "ur5", "panda") or of a URDF: a file (a `pathlib.Path`), its
    text (a str: never taken for a file name) or its bytes, as `urdf_source` reads them.

    end_link: the chain's last link (required for a URDF; None for a preset: its own).
    gravity: m/s^2 along -z of the root frame (or a (3,) vector); None is the preset's or 9.81.
    A preset's end link and gravity are those of conf/robot/NAME.yaml (`rbfn.robots.registry.preset`,
    read only when one of them is None). payload_link: where the payload sits, default end_link.
    dtype, device: where the constants are first cached (inputs of any other are served too).
    """
    text, source = urdf_source(name_or_urdf)
    robot = parse_urdf(text, source, inertials=True)
    if isinstance(name_or_urdf, str) and name_or_urdf in ROBOT_PRESETS and (end_link is None or gravity is None):
        values = preset(name_or_urdf)
        end_link = values.end_link if end_link is None else end_link
        gravity = values.gravity if gravity is None else gravity
    if end_link is None:
        raise ValueError(f"end_link=None is allowed for a preset only; allowed for {source}: one of its links")
    gravity = 9.81 if gravity is None else gravity
    return Arm(_build(robot, source, end_link, payload_link), gravity, end_link, dtype, device)
