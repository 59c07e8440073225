"""The whole base rotation: one network for every turn of a first joint about the base's vertical axis.

Where the first free joint turns the whole arm about the root's z axis (`Robot.base_yaw_sign`:
the SCARA, the UR5, the Panda), turning a target about z by d is turning that joint by s d (s =
+-1, the axis' sign) and nothing else. So a target anywhere around the base is turned by -d into
the trained range of that joint, solved there, and d is added back to the joint:

    1. candidates: d_k = azimuth(target) - azimuth(box centre's target) + 2 pi k / K, k < K, K turns
       spaced at most 0.8 times the joint's trained width apart, so one of them brings the target's
       first joint inside the box whatever the other joints;
    2. the network answers each turned target; the pick is the candidate flagged in the workspace
       whose first joint lies nearest the box's centre (the exports: they hold no robot model), or,
       given a `score`, the one that reaches the target best (the solver: forward kinematics);
    3. q1 += s d, wrapped by whole turns into the joint's URDF limits (the turn nearest the box's
       centre; the solver's `near` picks the turn nearest the current joints); an answer that no
       turn brings inside the limits is flagged.

Turned targets do not depend on the target's own yaw (only on the other joints), so a target
anywhere around the base is answered as one inside the box. A second pass re-centring the turn on
the network's first answer was tried and left out: 1 % off the UR5's median error for one more
network pass.

The solver (`rbfn.solver`, for the targets the network as trained misses by more than
`rbfn.solver.FAR` tolerances) and
the exports (`rbfn.export`, in their graph, for every target) both call `answer`, the one place of
this mapping. Arms without the symmetry are solved as before, their targets not turned.
Plain torch, traceable (torch.export, ONNX): no data-dependent branches.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from .robots.kinematics import joint_limits
from .robots.robot import Robot

__all__ = ["BaseYaw", "base_yaw", "turn", "answer", "nearest_turn"]

SPACING = 0.8  # candidates' spacing at most this share of the first joint's trained width


@dataclass(frozen=True)
class BaseYaw:
    """What the base rotation needs of a robot: the first joint's axis sign (+-1), trained box
    [low, high] and URDF limits [limit_low, limit_high] (rad; +-inf for a continuous joint), the
    azimuth (rad) of the box centre's target and the number of candidate turns."""

    sign: int
    low: float
    high: float
    limit_low: float
    limit_high: float
    azimuth: float
    candidates: int

    @property
    def centre(self) -> float:
        """The middle of the first joint's trained range (rad)."""
        return 0.5 * (self.low + self.high)


def base_yaw(robot: Robot) -> BaseYaw | None:
    """The robot's `BaseYaw`, or None where its first free joint does not turn the whole arm about
    the root's z axis (`Robot.base_yaw_sign`)."""
    sign = robot.base_yaw_sign()
    if sign == 0:
        return None
    low, high = float(robot.low[0]), float(robot.high[0])
    limit_low, limit_high = (float(t[robot.free[0]]) for t in joint_limits(robot.chain))
    centre = robot.targets((0.5 * (robot.low + robot.high))[None].to(robot.chain.device))
    azimuth = math.atan2(float(centre[0, 1]), float(centre[0, 0]))
    k = max(2, math.ceil(2 * math.pi / (SPACING * (high - low))))
    return BaseYaw(sign, low, high, limit_low, limit_high, azimuth, k)


def turn(x: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Targets x (B, 3) (m) or (B, 7) (m, then a unit quaternion (w, x, y, z)) turned about the
    root's z axis by `angle` (B,) rad: positions rotated, orientations pre-multiplied; w >= 0. A
    redundant joint's value after the pose (B, 8) is kept as it is."""
    c, s = torch.cos(angle), torch.sin(angle)
    p = torch.stack([c * x[:, 0] - s * x[:, 1], s * x[:, 0] + c * x[:, 1], x[:, 2]], -1)
    if x.shape[1] == 3:
        return p
    ch, sh = torch.cos(0.5 * angle), torch.sin(0.5 * angle)  # (ch, 0, 0, sh) * (w, x, y, z)
    w, qx, qy, qz = x[:, 3], x[:, 4], x[:, 5], x[:, 6]
    quat = torch.stack([ch * w - sh * qz, ch * qx - sh * qy, ch * qy + sh * qx, ch * qz + sh * w], -1)
    return torch.cat([p, torch.where(quat[:, :1] < 0, -quat, quat), x[:, 7:]], -1)


def nearest_turn(yaw: BaseYaw, q1: torch.Tensor, toward: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(q1 + 2 pi k (B,), within (B,)): the whole turn of the first joint q1 (B,) rad nearest
    `toward` (B,) among those inside its URDF limits, and whether any is (else the nearest)."""
    k = torch.round((toward - q1) / (2 * math.pi))
    options = q1[:, None] + 2 * math.pi * (
        k[:, None] + torch.tensor([0.0, -1.0, 1.0], dtype=q1.dtype, device=q1.device)
    )
    inside = (options >= yaw.limit_low) & (options <= yaw.limit_high)
    score = (options - toward[:, None]).abs() + torch.where(inside, 0.0, 100.0)
    best = score.argmin(-1, keepdim=True)
    return options.gather(1, best)[:, 0], inside.gather(1, best)[:, 0]


def answer(
    yaw: BaseYaw,
    solve: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]],
    x: torch.Tensor,
    score: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(joints (B, n), in_workspace (B,), turn d (B,) rad) for targets x (B, 3 or 7) anywhere around
    the base: the steps of the module docstring. `solve` maps targets to (joints, in-workspace
    mask), the network's; `score`, where given, maps the candidates' joints (K B, n) (turned back,
    rows candidate-major) to a cost (K B,) (lower is better: the solver's forward-kinematics error),
    else the pick is by the network's own flag and centring."""
    b, k, dtype = x.shape[0], yaw.candidates, x.dtype
    az = torch.atan2(x[:, 1], x[:, 0]).to(torch.float64)  # in x's dtype (onnxruntime has no float64 Atan)
    x = x.to(torch.float64)  # the turns in float64, so that every deployment rounds the same turned targets
    steps = torch.arange(k, dtype=x.dtype, device=x.device) * (2 * math.pi / k)
    d = (az[None, :] - yaw.azimuth + steps[:, None]).reshape(k * b)  # (K B,), candidate-major
    q, inside = solve(turn(x.repeat(k, 1), -d).to(dtype))
    q1 = q[:, 0].to(torch.float64)
    if score is None:
        cost = (q1 - yaw.centre).abs() + torch.where(inside, 0.0, 100.0)
    else:
        shifted = torch.cat([(q1 + yaw.sign * d)[:, None], q[:, 1:].to(torch.float64)], -1)
        cost = score(shifted)
    best = cost.reshape(k, b).argmin(0)  # (B,)
    pick = best * b + torch.arange(b, device=x.device)
    d, q, inside = d[pick], q[pick], inside[pick]
    first, within = nearest_turn(yaw, q1[pick] + yaw.sign * d, torch.full_like(d, yaw.centre))
    return torch.cat([first[:, None].to(q.dtype), q[:, 1:]], -1), inside & within, d
