"""The closed loop's robots as MuJoCo models: the paper's SCARA as MJCF text, and any URDF arm
compiled by MuJoCo from the same URDF.

SCARA (`scara_mjcf`, needs no MuJoCo to build): links 1 and 2 are uniform rods along their local
x axis (mass at mid-length, m l^2 / 12 about the axes normal to the rod), m3 plus the payload a
point mass on the quill, the prismatic joint positive downward (axis -z), so MuJoCo's M(q),
C(q, qd) qd and G(q) are those of `rbfn.robots.scara`; `mujoco.MjModel.from_xml_string(scara_mjcf())`
compiles it.

URDF arms (`arm_model`, needs `mujoco`): the URDF is read and parsed as the dynamics reads it
(`rbfn.robots.dynamics.urdf_source`: a file only from a `pathlib.Path`; `kinematics.urdf_tree`:
its joints and its links' inertials, no geometry, so that MuJoCo opens no mesh file and finds no
contact), then MuJoCo compiles it with `fusestatic` off, so that bodies joined by fixed joints
stay bodies (their inertia lumped exactly as `rbfn.robots.dynamics` lumps it, and the payload
link still there to carry the payload as a point mass at its origin). The root link is welded
to the world, as in `rbfn.robots.dynamics`; gravity along -z.

Both: friction viscous as joint damping, Coulomb as MuJoCo's `frictionloss` (a dry-friction
constraint, not sign(qd) itself); torques through one motor of gear 1 per joint.
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from typing import cast

from lxml import etree

from .dynamics import urdf_source
from .kinematics import urdf_tree
from .scara import ScaraParams

__all__ = ["scara_mjcf", "arm_model"]

_EPS_INERTIA = 1e-9   # kg m^2: MuJoCo needs positive principal inertias; the model's are zero


def _rod(mass: float, length: float) -> str:
    i = mass * length**2 / 12
    return (f'<inertial pos="{length / 2!r} 0 0" mass="{mass!r}" '
            f'diaginertia="{_EPS_INERTIA!r} {i!r} {i!r}"/>')


def scara_mjcf(p: ScaraParams = ScaraParams(), payload: float = 0.0, viscous: float = 12.0,
               coulomb: float = 0.2, dt: float = 1e-3, integrator: str = "RK4") -> str:
    """MJCF text of the SCARA with a payload (kg) on the quill; dt in s, friction in SI units."""
    joint = f'damping="{viscous!r}" frictionloss="{coulomb!r}"'
    e = repr(_EPS_INERTIA)
    return f"""<mujoco model="scara">
  <option timestep="{dt!r}" integrator="{integrator}" gravity="0 0 {-p.g!r}"/>
  <worldbody>
    <body name="link1">
      <joint name="joint1" type="hinge" axis="0 0 1" {joint}/>
      {_rod(p.m1, p.l1)}
      <body name="link2" pos="{p.l1!r} 0 0">
        <joint name="joint2" type="hinge" axis="0 0 1" {joint}/>
        {_rod(p.m2, p.l2)}
        <body name="quill" pos="{p.l2!r} 0 0">
          <joint name="joint3" type="slide" axis="0 0 -1" {joint}/>
          <inertial pos="0 0 0" mass="{p.m3 + payload!r}" diaginertia="{e} {e} {e}"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="joint1" gear="1"/>
    <motor joint="joint2" gear="1"/>
    <motor joint="joint3" gear="1"/>
  </actuator>
</mujoco>
"""


def _per_joint(value: float | Sequence[float], n: int, key: str) -> list[float]:
    values = [float(value)] * n if isinstance(value, (int, float)) else [float(v) for v in value]
    if len(values) != n:
        raise ValueError(f"{key}={list(cast(Sequence[float], value))} needs one value per joint ({n}) "
                         "or a single number")
    return values


def arm_model(urdf: str | bytes | os.PathLike, payload: float = 0.0, payload_link: str | None = None,
              viscous: float | Sequence[float] = 0.0, coulomb: float | Sequence[float] = 0.0,
              dt: float = 1e-3, integrator: str = "RK4", gravity: float | None = None):
    """`mujoco.MjModel` of a URDF arm (a preset's name, a `pathlib.Path`, the URDF's text or bytes:
    a str is never taken for a file name) with `payload` kg at the origin of `payload_link` (a
    body of the URDF; None: no payload), per-joint viscous damping (N m s/rad) and Coulomb
    friction loss (N m), a motor per joint, timestep dt s, `integrator` (RK4, Euler,
    implicitfast, ...), gravity m/s^2 along -z (None: the model's 9.81)."""
    root = urdf_tree(*urdf_source(urdf, "urdf"), inertials=True)
    import mujoco

    etree.SubElement(etree.SubElement(root, "mujoco"), "compiler", fusestatic="false")
    spec = mujoco.MjSpec.from_string(etree.tostring(root, encoding="unicode"))
    spec.option.timestep = dt
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
    if gravity is not None:
        spec.option.gravity = [0.0, 0.0, -float(gravity)]
    joints = [j for j in spec.joints if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]
    for j, b, f in zip(joints, _per_joint(viscous, len(joints), "viscous"),
                       _per_joint(coulomb, len(joints), "coulomb")):
        j.damping = [b, 0.0, 0.0]
        j.frictionloss = f
        motor = spec.add_actuator()
        motor.target, motor.trntype = j.name, mujoco.mjtTrn.mjTRN_JOINT
    if payload_link is not None and payload:
        body = spec.body(payload_link)
        if body is None:
            raise ValueError(f"payload link {payload_link!r} is not a body of the MuJoCo model")
        point = body.add_body(name="payload", pos=[0.0, 0.0, 0.0])      # welded to the link: a point mass
        point.mass, point.ipos, point.iquat = float(payload), [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        point.inertia = [0.0, 0.0, 0.0]
        point.explicitinertial = True
    return spec.compile()
