"""The paper's 3-DOF SCARA ("ACO based Adaptive RBFN Control for Robot Manipulators").

* `scara.urdf`: the robot itself (link lengths l1 = 1.0 m, l2 = 0.8 m; uniform rods m1 = 1.0 kg,
  m2 = 0.8 kg; the quill a point mass m3 = 0.5 kg), as every robot: kinematics and dynamics come
  from it through `rbfn.robots.kinematics` and `rbfn.robots.dynamics`.
* `closed_form`: the same robot in closed form (`fk`, `ik`, M, C, G and the elementwise terms of
  the simulator's hot path), with constants `ScaraParams` equal to the URDF's (tests/robots check
  them against it).
* `ScaraClosedForm`: what the rest of the package may ask of those closed forms (kinematics, the
  dynamics backend `ScaraTerms` that the closed loop's plant and nominal model use, the online
  part's default path). `rbfn.robots.registry`
  hands it out for exactly this URDF, with end link `END_LINK` and no joint locked; nothing else
  chooses it.
* Preset values (end link, IK branch box, gravity, home, rated payload): conf/robot/scara.yaml.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path

import torch

from .closed_form import (
    ScaraParams,
    ScaraTerms,
    c_times,
    coriolis,
    fk,
    gravity,
    ik,
    inertia_params,
    joint_vector,
    kinetic_energy,
    m_solve,
    m_solve_parts,
    m_times,
    mass_entries,
    mass_matrix,
    mass_matrix_dot,
    minus_c_qd,
    with_link_errors,
)

__all__ = [
    "ScaraParams",
    "ScaraTerms",
    "ScaraClosedForm",
    "closed_form",
    "URDF_PATH",
    "END_LINK",
    "fk",
    "ik",
    "with_link_errors",
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
]

URDF_PATH: Path = Path(str(files(__name__) / "scara.urdf"))
END_LINK = "quill"  # the link whose origin `fk` gives: the closed forms hold for this chain only


@dataclass(frozen=True)
class ScaraClosedForm:
    """The SCARA's closed forms with constants `params`, behind the interface every closed form
    offers (`rbfn.robots.registry.ClosedForm`).

    fk(q, link_error=None): positions (B, 3) in m of joints q (B, 3) (rad, rad, m); ik(x,
    link_error=None): joints (B, 3) of the elbow-up branch for positions x (B, 3) in m. link_error:
    relative errors of l1 and l2 (floats, or (B,) tensors: one robot per row); None: nominal.
    """

    params: ScaraParams = ScaraParams()
    joint_names: list[str] = field(default_factory=lambda: ["joint1", "joint2", "joint3"])
    prismatic: list[bool] = field(default_factory=lambda: [False, False, True])
    links: int = 2  # link lengths a kinematic perturbation scales: l1, l2
    path: str = "paper"  # the online part's default desired path: the paper's
    trajectory: str = "paper"  # the closed loop's default desired joints: the paper's
    label: str = "the SCARA (links l1, l2)"  # in messages

    def _params(self, link_error: Sequence | None) -> ScaraParams:
        return self.params if link_error is None else with_link_errors(self.params, link_error)

    def fk(self, q: torch.Tensor, link_error: Sequence | None = None) -> torch.Tensor:
        return fk(q, self._params(link_error))

    def ik(self, x: torch.Tensor, link_error: Sequence | None = None) -> torch.Tensor:
        return ik(x, self._params(link_error))

    def dynamics(self) -> ScaraTerms:
        """The equations of motion in closed form (`rbfn.robots.backend.Dynamics`)."""
        return ScaraTerms(self.params)


def closed_form(gravity: float | None = None, params: ScaraParams | None = None) -> ScaraClosedForm:
    """The closed forms with constants `params`, else the URDF's under `gravity` (m/s^2; None: the
    preset's, 9.8); what `rbfn.robots.registry.closed_form` hands out for scara.urdf."""
    if params is None:
        params = ScaraParams() if gravity is None else ScaraParams(g=gravity)
    return ScaraClosedForm(params)
