"""The robot's schema (group `robot`): its chain, where its IK answers, its physical facts."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from .base import Choice, _check_sensing, _need, finite


class Target(Choice):  # IK input
    position = "position"  # (B, 3) m
    pose = "pose"  # (B, 7) m + quaternion


class Workspace(Choice):  # where the IK answers
    box = "box"  # one branch, joints inside robot.joint_low..joint_high (one network, rbfn.layer)
    full = "full"  # every pose within the URDF limits, every branch (charts of joint space, rbfn.charts)


# The packaged robots: folders rbfn/robots/NAME/ (NAME.urdf, optional closed forms), presets
# conf/robot/NAME.yaml (tests/robots/test_registry.py checks that the three lists agree).
ROBOT_PRESETS = ("scara", "ur5", "panda")


@dataclass
class RobotConfig:
    """The robot (group `robot`: scara, ur5, panda; or `urdf`, any serial URDF with `urdf` and `end_link`):
    its chain, the box of joints its IK answers in and the kind of target, and its physical facts.
    The defaults are the SCARA's preset, conf/robot/scara.yaml, but for gravity (null: the
    preset's) and home (empty: the box centre; the SCARA's paper trajectory has none).
    With `derive` (robot=urdf, conf/robot/urdf.yaml) the keys left at its markers (name "",
    target null, joint_low/joint_high/home/encoder_counts empty, gravity/control_rate null,
    rated_payload < 0) are derived from the URDF by `rbfn.robots.derive.derive_robot`, which
    train.py and evaluate.py call first; given keys win.

    Joint values are in the URDF's units (rad, or m for prismatic joints), in the URDF's joint
    order along the chain root -> end link, `locked` joints excluded from the box and the IK output.
    """

    name: str = "scara"  # the preset's label; with `urdf` empty, its packaged URDF
    urdf: str = ""  # a URDF file; empty: the packaged URDF of `name`
    end_link: str = "quill"
    target: Optional[Target] = Target.position  # position (B, 3) | pose (B, 7); null: derived (robot=urdf)
    joint_low: list[float] = field(default_factory=lambda: [0.0, 0.3, 0.5])  # the IK branch's box
    joint_high: list[float] = field(default_factory=lambda: [2.0, 2.0, 1.5])
    locked: dict[str, float] = field(default_factory=dict)  # joint name -> held value (redundant arms)
    # a redundant arm's joint whose value is an input of the network beside the pose (pose targets
    # only); "": none. robot=urdf picks one for a 7-joint arm (rbfn.robots.derive)
    redundancy: str = ""
    rotation_scale: float = 0.3  # m per unit of the rotation features (pose targets)
    gravity: Optional[float] = None  # m/s^2 along -z of the root; null: the preset's (name), else 9.81
    home: list[float] = field(default_factory=list)  # a nominal pose per free joint; empty: the box centre
    rated_payload: float = 20.0  # kg: control payload cases default to 0, half and all of it; < 0: derived
    control_rate: Optional[float] = None  # Hz: the maker's controller cycle (the realistic loop's rate)
    # per chain joint: counts per revolution (per metre, prismatic) of the joint-side position
    # measurement (the realistic loop's encoders); empty: exact
    encoder_counts: list[float] = field(default_factory=list)
    derive: bool = False  # robot=urdf: fill the keys left at their markers from the URDF (see above)
    box_halfwidth: float = 0.5  # rad (m, prismatic): the derived box, home +- this, clipped to the limits
    # where the IK answers: box (one branch inside joint_low..joint_high) or full (every pose within the
    # URDF limits, every branch: `charts` networks, one a chart of joint space, rbfn.charts)
    workspace: Workspace = Workspace.box
    charts: int = 64  # workspace=full: how many charts (and networks)
    chart_centers: int = 300  # workspace=full: centres of each chart's network (rbfn.num_centers: the box's)
    chart_samples: int = 3000  # workspace=full: training samples drawn a chart, on average (a sixth validate)
    # workspace=full: refine each chart's centres as `centers.refine` says (false: the charts skip the
    # refinement, which costs a UR5 chart over ten times its selection and fit)
    chart_refine: bool = False

    def check(self, key: str = "robot") -> None:
        """The URDF itself is checked when it is loaded."""
        derived = "(robot=urdf derives it from the URDF, rbfn.robots.derive, before this check)"
        _need(self.target is not None, f"{key}.target", self.target, f"position or pose {derived}")
        _need(
            finite(self.box_halfwidth) and self.box_halfwidth > 0,
            f"{key}.box_halfwidth",
            self.box_halfwidth,
            "must be > 0 (rad, or m for a prismatic joint)",
        )
        lo, hi = self.joint_low, self.joint_high
        _need(
            len(lo) == len(hi) and len(lo) > 0,
            f"{key}.joint_low",
            list(lo),
            f"{key}.joint_low and {key}.joint_high ({list(hi)}) need one value per joint each",
        )
        for i, (l, h) in enumerate(zip(lo, hi)):
            if not (finite(l) and finite(h) and l < h):
                raise ValueError(
                    f"{key}.joint_low/joint_high: empty or invalid range for joint {i + 1}: "
                    f"[{l}, {h}] ({key}.joint_low < {key}.joint_high required)"
                )
        _need(
            self.urdf != "" or self.name in ROBOT_PRESETS,
            f"{key}.name",
            self.name,
            f"with {key}.urdf empty, choose a packaged robot: {list(ROBOT_PRESETS)} (or give {key}.urdf=PATH)",
        )
        for j, v in self.locked.items():
            _need(finite(v), f"{key}.locked.{j}", v, "must be a finite joint value")
        _need(
            not self.redundancy or self.target == Target.pose,
            f"{key}.redundancy",
            self.redundancy,
            f'"" with {key}.target={self.target} (a redundant position arm: hold joints with {key}.locked); '
            "a joint name with pose targets",
        )
        _need(
            self.redundancy not in self.locked,
            f"{key}.redundancy",
            self.redundancy,
            f"a free joint, not one of {key}.locked {list(self.locked)}",
        )
        _need(
            finite(self.rotation_scale) and self.rotation_scale > 0,
            f"{key}.rotation_scale",
            self.rotation_scale,
            "must be > 0 m",
        )
        self._check_physics(key, derived)
        self._check_charts(key)

    def _check_physics(self, key: str, derived: str) -> None:
        """The robot's physical facts: gravity, home, rated payload, controller rate and encoders."""
        n = len(self.joint_low)
        _need(
            self.gravity is None or (finite(self.gravity) and self.gravity >= 0),
            f"{key}.gravity",
            self.gravity,
            "must be >= 0 m/s^2 or null",
        )
        _need(
            len(self.home) in (0, n) and all(finite(v) for v in self.home),
            f"{key}.home",
            list(self.home),
            f"empty (the box centre) or one finite value per joint ({n})",
        )
        _need(
            finite(self.rated_payload) and self.rated_payload >= 0,
            f"{key}.rated_payload",
            self.rated_payload,
            f"must be >= 0 kg; < 0: derived {derived}",
        )
        _check_sensing(self.control_rate, self.encoder_counts, key)

    def _check_charts(self, key: str) -> None:
        """The whole-range IK's charts (workspace=full): their count, centres and samples."""
        _need(
            not isinstance(self.charts, bool) and isinstance(self.charts, int) and self.charts >= 1,
            f"{key}.charts",
            self.charts,
            "must be an integer >= 1 (charts of joint space with workspace=full)",
        )
        for name, least in (("chart_centers", 1), ("chart_samples", 12)):
            v = getattr(self, name)
            _need(
                not isinstance(v, bool) and isinstance(v, int) and v >= least,
                f"{key}.{name}",
                v,
                f"must be an integer >= {least}",
            )
