"""The closed loop's robots as MuJoCo models: any URDF arm compiled by MuJoCo from the same URDF
(the SCARA's closed-form constants written as MJCF: `rbfn.robots.scara.mjcf`).

`arm_model` (needs `mujoco`): the URDF is read and parsed as the dynamics reads it
(`rbfn.robots.dynamics.urdf_source`: a file only from a `pathlib.Path`; `kinematics.urdf_tree`:
its joints and its links' inertials, no geometry, so that MuJoCo opens no mesh file and finds no
contact), then MuJoCo compiles it with `fusestatic` off, so that bodies joined by fixed joints
stay bodies (their inertia lumped exactly as `rbfn.robots.dynamics` lumps it, and the payload
link still there to carry the payload as a point mass at its origin). The root link is welded
to the world, as in `rbfn.robots.dynamics`; gravity along -z.

Friction: viscous as joint damping, Coulomb as MuJoCo's `frictionloss` (a dry-friction
constraint, not sign(qd) itself); torques through one motor of gear 1 per joint.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import cast

from lxml import etree

from .dynamics import urdf_source
from .kinematics import urdf_tree

__all__ = ["arm_model"]


def _per_joint(value: float | Sequence[float], n: int, key: str) -> list[float]:
    values = [float(value)] * n if isinstance(value, (int, float)) else [float(v) for v in value]
    if len(values) != n:
        raise ValueError(
            f"{key}={list(cast(Sequence[float], value))} needs one value per joint ({n}) or a single number"
        )
    return values


def arm_model(
    urdf: str | bytes | os.PathLike,
    *,
    payload: float = 0.0,
    payload_link: str | None = None,
    viscous: float | Sequence[float] = 0.0,
    coulomb: float | Sequence[float] = 0.0,
    dt: float = 1e-3,
    integrator: str = "RK4",
    gravity: float | None = None,
):
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
    for j, b, f in zip(
        joints, _per_joint(viscous, len(joints), "viscous"), _per_joint(coulomb, len(joints), "coulomb")
    ):
        j.damping = [b, 0.0, 0.0]
        j.frictionloss = f
        motor = spec.add_actuator()
        motor.target, motor.trntype = j.name, mujoco.mjtTrn.mjTRN_JOINT
    if payload_link is not None and payload:
        body = spec.body(payload_link)
        if body is None:
            raise ValueError(f"payload link {payload_link!r} is not a body of the MuJoCo model")
        point = body.add_body(name="payload", pos=[0.0, 0.0, 0.0])  # welded to the link: a point mass
        point.mass, point.ipos, point.iquat = float(payload), [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        point.inertia = [0.0, 0.0, 0.0]
        point.explicitinertial = True
    return spec.compile()
