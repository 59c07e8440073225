"""The packaged robots' presets, and the one place that chooses closed forms.

Every robot, packaged or a user's, is its URDF: kinematics (`rbfn.robots.kinematics`) and
dynamics (`rbfn.robots.dynamics`) are computed from it. A robot may also have closed forms, a
faster second form of the same equations tested equal to the first: `closed_form` hands them out
for exactly the URDF they were written for (its text, end link, no joint locked), and nothing
else in the package asks which robot it is.

A packaged robot is a folder rbfn/robots/NAME/ (NAME.urdf, a docstring citing its numbers,
optional closed forms), NAME one of `rbfn.config.ROBOT_PRESETS`. Its preset values (end link,
IK box, gravity, home, rated payload) live in conf/robot/NAME.yaml only: `preset` reads that file
(from the repository's conf/, beside the package, as the Hydra applications do).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import torch
import yaml  # type: ignore[import-untyped]

from ..config import ROBOT_PRESETS, RobotConfig, from_mapping
from . import scara
from .backend import Dynamics
from .kinematics import read_urdf

__all__ = ["CONF_ROBOT", "WITH_CLOSED_FORMS", "ClosedForm", "closed_form", "preset"]

CONF_ROBOT = Path(__file__).resolve().parents[2] / "conf" / "robot"
"""The presets' folder, conf/robot/ of the repository the package is installed from."""


def preset(name: str) -> RobotConfig:
    """The packaged robot `name`'s preset, conf/robot/NAME.yaml, as a RobotConfig (no Hydra).
    ValueError for a name that is no packaged robot, FileNotFoundError where conf/ is not there
    (a package installed without its repository: give the values instead)."""
    if name not in ROBOT_PRESETS:
        raise ValueError(f"name={name!r} is not a packaged robot; allowed: {list(ROBOT_PRESETS)}")
    path = CONF_ROBOT / f"{name}.yaml"
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: no such file; the presets of the packaged robots are the repository's "
            "conf/robot/*.yaml (install from a checkout, or give the robot's values)"
        )
    raw = yaml.safe_load(path.read_text())
    assert isinstance(raw, dict), f"{path}: a mapping of RobotConfig's keys"
    raw.pop("defaults", None)
    return from_mapping(RobotConfig, raw)


class ClosedForm(Protocol):
    """What the package may ask of a robot's closed forms (a robot folder's, e.g.
    `rbfn.robots.scara.ScaraClosedForm`).

    fk(q, link_error=None): end-link positions (B, 3) in m of joints q (B, n); ik(x, link_error=None):
    joints (B, n) of the IK branch for positions x (B, 3) in m. link_error: relative errors of the
    first `links` link lengths (floats, or (B,) tensors: one robot per row), the online part's
    kinematic perturbation; None: the nominal robot. dynamics(): the equations of motion in closed
    form (`rbfn.robots.backend.Dynamics`), which the closed loop's plant and nominal model use.
    path: the online part's default desired path (online.path null); trajectory: the closed loop's
    default desired joints (control.trajectory null); label: the robot in messages.
    """

    @property
    def params(self) -> Any: ...

    @property
    def joint_names(self) -> list[str]: ...

    @property
    def prismatic(self) -> list[bool]: ...

    @property
    def links(self) -> int: ...

    @property
    def path(self) -> str: ...

    @property
    def trajectory(self) -> str: ...

    @property
    def label(self) -> str: ...

    def fk(self, q: torch.Tensor, link_error: Sequence | None = None) -> torch.Tensor: ...

    def ik(self, x: torch.Tensor, link_error: Sequence | None = None) -> torch.Tensor: ...

    def dynamics(self) -> Dynamics: ...


# The robot folders that ship closed forms. Each gives URDF_PATH, END_LINK (the chain its forms
# hold for, with no joint locked) and closed_form(gravity, params) -> its ClosedForm.
WITH_CLOSED_FORMS = (scara,)


@functools.cache
def _packaged_text(path: Path) -> str:
    return read_urdf(path)


def closed_form(
    urdf_text: str,
    end_link: str,
    locked: Mapping[str, float] | None = None,
    gravity: float | None = None,
    params: Any = None,
) -> ClosedForm | None:
    """The closed forms valid for the robot given by its URDF text, end link and locked joints: a
    robot folder's of `WITH_CLOSED_FORMS` for its packaged URDF (text equal), its END_LINK and
    nothing locked (the SCARA's); None for every other robot (its URDF forms serve it). Their
    constants: `params`, else their own (the URDF's) under `gravity` (m/s^2; None: the preset's)."""
    for robot in WITH_CLOSED_FORMS:
        if end_link == robot.END_LINK and not locked and urdf_text == _packaged_text(robot.URDF_PATH):
            return robot.closed_form(gravity, params)
    return None
