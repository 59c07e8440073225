"""The robot an IK network is trained for: its URDF chain, the joints held fixed, the sampled joint
box and the kind of target (position, or position and orientation).

Targets are positions (B, 3) in m, or poses (B, 7): position in m, then a unit quaternion
(w, x, y, z) of the end link's orientation in the root frame, with w >= 0 (q and -q are the
same rotation). Joint vectors given to and returned by the IK are the free joints (B, n) in the
URDF's order along the chain; `locked` joints are held at their values.
"""

from __future__ import annotations

import math
import reprlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import pytorch_kinematics as pk
import torch
from pytorch_kinematics import transforms as tf

from ..config import RobotConfig, Target, finite
from .kinematics import (
    _steps,
    compose,
    forward_kinematics_pose,
    jacobian_and_pose,
    joint_limits,
    load_serial_chain,
    read_urdf,
    urdf_path,
)

__all__ = [
    "Frame",
    "check_ik_is_function",
    "Robot",
    "check_joint_values",
    "load_robot",
    "robot_from_record",
    "pose_targets",
    "unit_quaternions",
    "rotation_error_deg",
    "rotation_vector",
]


def unit_quaternions(rot: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (..., 4) (w, x, y, z), w >= 0, of rotation matrices (..., 3, 3)."""
    quat = tf.matrix_to_quaternion(rot)
    return torch.where(quat[..., :1] < 0, -quat, quat)


def pose_targets(pose: torch.Tensor) -> torch.Tensor:
    """Targets (B, 7) = position (m) and unit quaternion (w, x, y, z), w >= 0, of poses (B, 4, 4)."""
    return torch.cat([pose[..., :3, 3], unit_quaternions(pose[..., :3, :3])], -1)


def rotation_error_deg(r_hat: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """Angle (B,) in degrees of the rotation between rotation matrices r_hat and r (B, 3, 3), from
    their chordal distance |r_hat - r|_F = 2 sqrt(2) sin(angle / 2): elementwise, no product of
    the matrices (as exact as the angle from that product's trace and skew part, to rounding)."""
    chord = (r_hat - r).square().sum((-1, -2)).sqrt() / (2.0 * math.sqrt(2.0))
    return torch.rad2deg(2.0 * torch.asin(chord.clamp(max=1.0)))


def rotation_vector(r: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (B, 3), the axis times the angle (rad, in [0, pi]), of rotation matrices r
    (B, 3, 3): the matrix logarithm. Below a quarter turn from the skew part r - r^T = 2 sin(angle)
    [axis]x; beyond it from the symmetric part (r + r^T) / 2 - cos(angle) I = (1 - cos(angle)) axis
    axis^T (its column of the largest diagonal, signed like the skew part), which keeps the axis at
    half a turn. No data-dependent branches (the exporters take it). Elementwise on the nine entries,
    each a row of B (one thread, float32, 4 096 rows: 0.47 against 0.82 ms on (B, 3, 3) slices)."""
    m = r.permute(1, 2, 0).contiguous()  # (3, 3, B)
    v0, v1, v2 = m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]  # 2 sin(angle) axis
    cos = 0.5 * (m[0, 0] + m[1, 1] + m[2, 2] - 1.0)
    sin2 = (v0 * v0 + v1 * v1 + v2 * v2).sqrt()  # 2 sin(angle)
    angle = torch.atan2(sin2, 2.0 * cos)
    near = torch.where(sin2 > 1e-12, angle / sin2.clamp(min=1e-12), torch.full_like(sin2, 0.5))
    d0, d1, d2 = m[0, 0] - cos, m[1, 1] - cos, m[2, 2] - cos  # the symmetric part's diagonal
    s01, s02, s12 = 0.5 * (m[0, 1] + m[1, 0]), 0.5 * (m[0, 2] + m[2, 0]), 0.5 * (m[1, 2] + m[2, 1])
    first, second = (d0 >= d1) & (d0 >= d2), d1 >= d2  # the column of the largest diagonal
    c0 = torch.where(first, d0, torch.where(second, s01, s02))
    c1 = torch.where(first, s01, torch.where(second, d1, s12))
    c2 = torch.where(first, s02, torch.where(second, s12, d2))
    norm = (c0 * c0 + c1 * c1 + c2 * c2).sqrt().clamp(min=torch.finfo(r.dtype).tiny)
    far = torch.where(c0 * v0 + c1 * v1 + c2 * v2 < 0.0, -angle, angle) / norm
    half = cos < 0.0
    return torch.stack([torch.where(half, c * far, v * near) for c, v in ((c0, v0), (c1, v1), (c2, v2))], -1)


class Frame(NamedTuple):
    """The end link at a batch of joints (`Robot.frame`): rotations (B, 3, 3), positions (B, 3) m,
    and where asked the task Jacobian (B, 3 or 6, n) over the free joints (else None)."""

    rot: torch.Tensor
    pos: torch.Tensor
    jac: torch.Tensor | None


@dataclass
class Robot:
    """A serial chain (float64) root -> end link, the free joints' box (n,) sampled for training,
    the held joints and the target kind."""

    chain: pk.SerialChain
    urdf_text: str
    end_link: str
    low: torch.Tensor
    high: torch.Tensor
    target: str = "position"
    locked: dict[str, float] = field(default_factory=dict)
    name: str = ""
    redundancy: str = ""  # the free joint whose value the network takes beside the pose; "": none

    def __post_init__(self) -> None:
        names = self.chain.get_joint_parameter_names()
        unknown = [j for j in self.locked if j not in names]
        if unknown:
            raise ValueError(
                f"robot.locked names {unknown}, which are not joints of the chain to {self.end_link!r}: {names}"
            )
        self.free = [i for i, j in enumerate(names) if j not in self.locked]
        if self.redundancy and (self.redundancy not in names or self.redundancy in self.locked):
            free = [names[i] for i in self.free]
            raise ValueError(
                f"robot.redundancy={self.redundancy!r} is not allowed: allowed are the free joints of the chain to "
                f"{self.end_link!r}: {free}"
            )
        if self.redundancy and self.target != Target.pose:
            raise ValueError(
                f"robot.redundancy={self.redundancy!r} is not allowed with robot.target={self.target}: "
                "it needs pose targets"
            )
        full = torch.zeros(len(names), dtype=torch.float64)
        for j, v in self.locked.items():
            full[names.index(j)] = v
        self._full = full

    @property
    def joint_names(self) -> list[str]:
        """The free joints (the IK's outputs), in chain order."""
        names = self.chain.get_joint_parameter_names()
        return [names[i] for i in self.free]

    @property
    def redundant(self) -> int | None:
        """The index of `redundancy` among the free joints, or None."""
        return self.joint_names.index(self.redundancy) if self.redundancy else None

    def inputs(self, q: torch.Tensor) -> torch.Tensor:
        """The network's inputs for the free joints q (B, n): their targets (B, 3 or 7), and with a
        `redundancy` joint its value after the pose (B, 8)."""
        x = self.targets(q)
        r = self.redundant
        return x if r is None else torch.cat([x, q[:, r : r + 1].to(x.dtype)], -1)

    def split_inputs(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """`inputs`' inverse: (the targets (B, 3 or 7), the redundant joint's values (B,) or None)
        of network inputs x (B, 3, 7 or 8), as `IKSolver.solve` takes them (`redundancy=`)."""
        return (x, None) if self.redundant is None else (x[:, :7], x[:, 7])

    def full_joints(self, q: torch.Tensor) -> torch.Tensor:
        """Every chain joint (B, n_chain) from the free joints q (B, n), locked ones filled in."""
        out = self._full.to(dtype=q.dtype, device=q.device).expand(q.shape[0], -1).clone()
        out[:, self.free] = q
        return out

    def pose(self, q: torch.Tensor) -> torch.Tensor:
        """End-link poses (B, 4, 4) in m of the free joints q (B, n)."""
        return forward_kinematics_pose(self.chain, self.full_joints(q))

    def targets(self, q: torch.Tensor) -> torch.Tensor:
        """IK targets (B, 3) or (B, 7) reached by the free joints q (B, n)."""
        pose = self.pose(q)
        return pose_targets(pose) if self.target == Target.pose else pose[:, :3, 3]

    def jacobian(self, q: torch.Tensor) -> torch.Tensor:
        """Task Jacobian (B, 3 or 6, n) at the free joints q (B, n), root frame: the end link's
        linear velocity (m per rad or m of joint) and, for pose targets, its angular velocity below."""
        return self._task(jacobian_and_pose(self.chain, self.full_joints(q))[0]).contiguous()

    def _task(self, jac: torch.Tensor) -> torch.Tensor:
        """The task's rows (3 or 6) and the free joints' columns of a chain's geometric Jacobian (B, 6, n_chain)."""
        jac = jac[:, : 6 if self.target == Target.pose else 3]
        return jac[:, :, self.free] if self.locked else jac

    def frame(self, q: torch.Tensor, jacobian: bool = False) -> Frame:
        """`Frame` at the free joints q (B, n), in q's dtype (float32 or float64): `pose` and
        `jacobian` without the 4 x 4 poses or blocks (the polish's form, a block of rows at a time)."""
        th = self.full_joints(q) if self.locked else q
        rot, pos, jac = compose(_steps(self.chain, q.dtype), th, jacobian)
        # contiguous: reductions over a batch-last view are slow
        return Frame(rot.contiguous(), pos.contiguous(), None if jac is None else self._task(jac))

    def errors(self, q_hat: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(position error (B,) in mm, rotation error (B,) in degrees or None for position targets)
        of joints q_hat (B, n) against targets x."""
        pose = self.pose(q_hat.to(torch.float64))
        x = x.to(torch.float64)
        pos = (pose[:, :3, 3] - x[:, :3]).norm(dim=-1) * 1000.0
        if self.target != Target.pose:
            return pos, None
        return pos, rotation_error_deg(pose[:, :3, :3], tf.quaternion_to_matrix(x[:, 3:7]))

    def base_yaw_sign(self, tol: float = 1e-9) -> int:
        """+1 or -1 where the first free joint turns the whole arm about the root's vertical (z)
        axis, so that turning a target about z by d is turning that joint by +d or -d (the sign
        of its axis); 0 otherwise. Read from the chain: the first free joint is revolute, its axis
        is the root's +-z and its origin, after every fixed offset and held joint before it, lies
        on that axis (within `tol`, m and unit axis). The SCARA, the UR5 and the Panda have it."""
        t = torch.eye(4, dtype=torch.float64)
        names = self.chain.get_joint_parameter_names()
        for frame in self.chain._serial_frames:
            joint = frame.joint
            if joint.offset is not None:
                t = t @ joint.offset.get_matrix()[0].to(device="cpu", dtype=torch.float64)
            if joint.joint_type == "fixed":
                continue
            axis = joint.axis.to(device="cpu", dtype=torch.float64)
            axis = axis / axis.norm()
            if joint.name in self.locked:  # held: part of the fixed transform before the first free joint
                held = torch.eye(4, dtype=torch.float64)
                value = self.locked[joint.name]
                if joint.joint_type == "revolute":
                    held[:3, :3] = tf.axis_angle_to_matrix(axis * value)
                else:
                    held[:3, 3] = axis * value
                t = t @ held
                continue
            assert joint.name in names
            z = t[:3, :3] @ axis  # the joint's axis in the root frame
            on_axis = float(t[:2, 3].abs().max()) <= tol and float(z[:2].abs().max()) <= tol
            return int(torch.sign(z[2])) if joint.joint_type == "revolute" and on_axis else 0
        return 0

    def record(self) -> dict:
        """Plain data for a checkpoint's `robot` entry."""
        return {
            "name": self.name,
            "urdf": self.urdf_text,
            "end_link": self.end_link,
            "target": str(self.target),
            "locked": dict(self.locked),
            "joint_names": self.joint_names,
            "joint_low": self.low.tolist(),
            "joint_high": self.high.tolist(),
            "redundancy": self.redundancy,
        }


def _check_box(robot: Robot, where: str) -> None:
    names = robot.joint_names
    low, high = robot.low, robot.high
    if len(names) != low.shape[0]:
        raise ValueError(
            f"{where}: robot.joint_low/joint_high give {low.shape[0]} joints "
            f"({reprlib.repr(low.tolist())}); allowed: one per free joint of the chain to "
            f"{robot.end_link!r}, which has {len(names)}: {names}"
        )
    u_low, u_high = (t[robot.free] for t in joint_limits(robot.chain))
    outside = (low < u_low - 1e-12) | (high > u_high + 1e-12)
    if bool(outside.any()):
        j = int(outside.nonzero()[0])
        raise ValueError(
            f"{where}: joint range of {names[j]} [{low[j]:.4g}, {high[j]:.4g}] leaves the URDF "
            f"limits [{u_low[j]:.4g}, {u_high[j]:.4g}]"
        )


def _outside(
    key: str, values: list[float], joints: list[str], lower: list[float], upper: list[float], shown: object
) -> None:
    """ValueError naming `key`=`shown`, the first of `joints` whose value lies outside its URDF limits
    [lower, upper] (rad or m; +-inf where none), the value and the limits."""
    for v, j, lo, hi in zip(values, joints, lower, upper):
        if not lo - 1e-12 <= v <= hi + 1e-12:
            raise ValueError(
                f"{key}={shown!r} is not allowed: joint {j} at {v:.6g} lies outside its URDF limits "
                f"[{lo:.6g}, {hi:.6g}]; allowed: a value within them"
            )


def check_joint_values(
    locked: dict[str, float],
    names: list[str],
    lower: torch.Tensor,
    upper: torch.Tensor,
    free: dict[str, list[float]] | None = None,
) -> None:
    """ValueError where a joint-valued key puts a joint outside its URDF limits, naming the key, the
    joint, the value and the limits: robot.locked.JOINT (`locked`, the held values) and each key of
    `free` (key -> one value per free joint, e.g. robot.home: the closed loop's nominal pose, the
    sinusoid about it; an empty list: not given). `names`: the chain's joints in order, `lower`,
    `upper` (n,) their limits, rad or m, +-inf where none."""
    lo, hi = lower.tolist(), upper.tolist()
    for j, v in locked.items():
        if j in names:
            i = names.index(j)
            _outside(f"robot.locked.{j}", [float(v)], [j], [lo[i]], [hi[i]], v)
    idx = [i for i, j in enumerate(names) if j not in locked]
    for key, values in (free or {}).items():
        if values and len(values) == len(idx):
            listed = [float(v) for v in values]
            _outside(key, listed, [names[i] for i in idx], [lo[i] for i in idx], [hi[i] for i in idx], listed)


def load_robot(cfg: RobotConfig, device: str = "cpu") -> Robot:
    """The robot of `cfg` (the packaged URDF of `cfg.name` when `cfg.urdf` is empty), its box, home
    and locked values checked against the URDF's joint limits. A robot.urdf that is missing (FileNotFoundError) or
    no regular file (ValueError: a directory, FIFO or device, named as such) is refused unread."""
    path = Path(cfg.urdf) if cfg.urdf else urdf_path(cfg.name)
    try:
        text = read_urdf(path)
    except (FileNotFoundError, ValueError) as e:
        raise type(e)(f"robot.urdf={cfg.urdf!r}: {e}") from None
    chain = load_serial_chain(text, cfg.end_link, torch.float64, device, source=str(path))
    robot = Robot(
        chain,
        text,
        cfg.end_link,
        torch.tensor(cfg.joint_low, dtype=torch.float64),
        torch.tensor(cfg.joint_high, dtype=torch.float64),
        str(cfg.target),
        dict(cfg.locked),
        cfg.name,
        cfg.redundancy,
    )
    _check_box(robot, str(path))
    names = robot.chain.get_joint_parameter_names()
    check_joint_values(cfg.locked, names, *joint_limits(robot.chain), {"robot.home": list(cfg.home)})
    return robot


def _check_fields(record: dict) -> None:
    """ValueError naming the first field of a checkpoint's robot entry of the wrong type or range."""

    def need(ok: bool, key: str, allowed: str) -> None:
        if not ok:
            raise ValueError(f"robot.{key}={reprlib.repr(record.get(key))} is not allowed; allowed: {allowed}")

    need(isinstance(record.get("urdf"), str), "urdf", "the URDF's text (a str of XML whose root element is <robot>)")
    need(isinstance(record.get("end_link"), str), "end_link", "the name of a link of the URDF (a str)")
    for key in ("joint_low", "joint_high"):
        value = record.get(key)
        need(
            isinstance(value, (list, tuple)) and all(finite(v) for v in value),
            key,
            "a list of finite numbers (rad or m), one per free joint",
        )
    low, high = record["joint_low"], record["joint_high"]
    need(len(low) == len(high), "joint_high", f"as many entries as robot.joint_low ({len(low)})")
    need(
        all(a < b for a, b in zip(low, high)), "joint_high", f"each entry above robot.joint_low's ({reprlib.repr(low)})"
    )
    names = record.get("joint_names", [])
    need(
        isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names),
        "joint_names",
        "a list of joint names (str)",
    )
    need(record.get("target", "position") in list(Target), "target", f"one of {[str(t) for t in Target]}")
    locked = record.get("locked", {})
    need(
        isinstance(locked, dict) and all(isinstance(k, str) and finite(v) for k, v in locked.items()),
        "locked",
        "a dict from joint name (str) to a finite held value (rad or m)",
    )
    need(isinstance(record.get("name", ""), str), "name", "a label (str)")
    need(isinstance(record.get("redundancy", ""), str), "redundancy", 'a free joint\'s name (str), or "" for none')


def robot_from_record(record: dict, device: str = "cpu") -> Robot:
    """The Robot of a checkpoint's `robot` entry, checked first: ValueError naming the field, its
    value and what is allowed when a field has the wrong type or range (urdf: URDF text, never a
    file name; end_link: a link of it; joint_low < joint_high: finite, one per free joint of the
    chain, within the URDF's limits; joint_names: the chain's free joints; target: position or
    pose; locked: joints of the chain -> finite values; name: str)."""
    if not isinstance(record, dict):
        raise TypeError(
            f"robot={reprlib.repr(record)} is a {type(record).__name__}; allowed: a dict (the "
            "checkpoint's robot entry, as Robot.record() writes it)"
        )
    _check_fields(record)
    chain = load_serial_chain(record["urdf"], record["end_link"], torch.float64, device, source="robot.urdf")
    robot = Robot(
        chain,
        record["urdf"],
        record["end_link"],
        torch.tensor(record["joint_low"], dtype=torch.float64),
        torch.tensor(record["joint_high"], dtype=torch.float64),
        str(record.get("target", "position")),
        {k: float(v) for k, v in record.get("locked", {}).items()},
        record.get("name", ""),
        record.get("redundancy", ""),
    )
    _check_box(robot, "robot entry")
    check_joint_values(robot.locked, robot.chain.get_joint_parameter_names(), *joint_limits(robot.chain))
    names = record.get("joint_names")
    if names is not None and list(names) != robot.joint_names:
        raise ValueError(
            f"robot.joint_names={reprlib.repr(names)} is not allowed; allowed: the free joints of the "
            f"chain to {robot.end_link!r}, in chain order: {robot.joint_names}"
        )
    return robot


def check_ik_is_function(
    target: Target | str, joints: Sequence[str], locked: Mapping[str, float], redundancy: str = ""
) -> None:
    """Refuse an arm whose free joints `joints` (the IK's outputs, by name, `locked` ones excluded)
    outnumber the degrees of freedom of its targets: 3 for `position`, 6 for `pose`, one more with a
    `redundancy` joint (its value is an input of the network).

    Many joint vectors then reach each target: the training data is no function of the target,
    and a network fitted to it learns their average (a task Jacobian, 3 or 6 rows, has fewer rows
    than joints: the same condition). ValueError naming robot.target, the free joints and
    robot.locked, whatever the refinement mode; `rbfn.pipeline.train_ik`, train.py and the
    derivation of a URDF's values (`rbfn.robots.derive`) check it before any work."""
    dof, n = (6 if target == Target.pose else 3) + bool(redundancy), len(joints)
    if n <= dof:
        return
    ways = (
        f"lock {n - dof} of them with robot.locked (on the command line +robot.locked.NAME=VALUE, one per "
        "joint) and drop their entries from robot.joint_low/joint_high"
    )
    if target != Target.pose and n <= 6:  # pose targets fix 6: an arm with at most 6 free joints
        ways += ", or use robot.target=pose (position and orientation, 6 degrees of freedom)"
    if target == Target.pose and n == 7 and not redundancy:
        ways += ", or give one of them as an input beside the pose: robot.redundancy=NAME"
    what = f"robot.target={target}" + (f" with robot.redundancy={redundancy}" if redundancy else "")
    raise ValueError(
        f"{what} has {dof} degrees of freedom but the arm has {n} free joints {list(joints)} "
        f"(robot.locked={dict(locked)}): many joint vectors reach each target, so the IK map is not a "
        f"function and the network would learn their average; {ways}"
    )
