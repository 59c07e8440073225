"""The SCARA's closed-form constants (`ScaraParams`) as MuJoCo MJCF text (needs no MuJoCo to
build; `mujoco.MjModel.from_xml_string(scara_mjcf())` compiles it), a reference for the closed
forms in the benchmarks.

Links 1 and 2 are uniform rods along their local x axis (mass at mid-length, m l^2 / 12 about the
axes normal to the rod), m3 plus the payload a point mass on the quill, the prismatic joint
positive downward (axis -z), so MuJoCo's M(q), C(q, qd) qd and G(q) are those of
`rbfn.robots.scara.closed_form`. Friction: viscous as joint damping, Coulomb as MuJoCo's
`frictionloss` (a dry-friction constraint, not sign(qd) itself); torques through one motor of
gear 1 per joint.
"""

from __future__ import annotations

from .closed_form import ScaraParams

__all__ = ["scara_mjcf"]

_EPS_INERTIA = 1e-9  # kg m^2: MuJoCo needs positive principal inertias; the model's are zero


def _rod(mass: float, length: float) -> str:
    i = mass * length**2 / 12
    return f'<inertial pos="{length / 2!r} 0 0" mass="{mass!r}" diaginertia="{_EPS_INERTIA!r} {i!r} {i!r}"/>'


def scara_mjcf(
    p: ScaraParams = ScaraParams(),
    payload: float = 0.0,
    viscous: float = 12.0,
    coulomb: float = 0.2,
    dt: float = 1e-3,
    integrator: str = "RK4",
) -> str:
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
