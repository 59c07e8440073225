"""Learned IK, then exact: the network picks the branch and gets close, a few batched
damped-least-squares (Levenberg-Marquardt) steps on the robot's own FK and Jacobian make it exact.

    solver = rbfn.load_solver("outputs/train/.../checkpoint.pt")
    q, converged = solver.solve(targets, iterations=3)   # targets (B, 3) m, or (B, 7) m + quaternion

Each step solves (J J^T + lambda I) y = e, dq = J^T y for the task error e (position in m, and for
pose targets the rotation error as an axis-angle vector in rad, root frame), and clamps the
joints to the trained box, so the answer never leaves the branch the network was trained on.
`converged` is True where the final error is within `tol_mm` and `tol_deg`. With `restarts`, the
targets that did not converge are tried again from random joints in the box, as a sampling IK
would, so only the hard few pay for it. Runs where torch and the robot model are available;
deployed exports hold the network alone.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from pytorch_kinematics import transforms as tf

from .checkpoint import model_from_checkpoint, read_checkpoint
from .config import Target, finite, validate_device
from .layer import RBFNetwork
from .robots.robot import Robot, robot_from_record

__all__ = ["IKSolver", "load_solver", "DEFAULT_ITERATIONS", "MAX_ITERATIONS"]

DEFAULT_ITERATIONS = 3
MAX_ITERATIONS = 1000  # per call and per restart: a guard against typos (the polish converges in a few)


def _count(name: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_ITERATIONS:
        raise ValueError(f"{name}={v!r} is not allowed: use an integer in [0, {MAX_ITERATIONS}]")
    return v


def _positive(name: str, v, zero: bool = False) -> float:
    if not (finite(v) and (v >= 0 if zero else v > 0)):
        raise ValueError(f"{name}={v!r} is not allowed: use a finite number {'>= 0' if zero else '> 0'}")
    return float(v)


class IKSolver:
    """The IK network of a checkpoint plus damped-least-squares polish on the robot's kinematics."""

    def __init__(
        self, model: RBFNetwork, robot: Robot, tol_mm: float = 0.1, tol_deg: float = 0.1, damping: float = 1e-8
    ) -> None:
        if not isinstance(model, RBFNetwork):
            raise TypeError(f"model must be an RBFNetwork, got {type(model).__name__}")
        if not isinstance(robot, Robot):
            raise TypeError(f"robot must be a rbfn.robots.robot.Robot, got {type(robot).__name__}")
        if model.out_features != len(robot.joint_names):
            raise ValueError(
                f"the model returns {model.out_features} joints, the robot has {len(robot.joint_names)} "
                f"free joints ({robot.joint_names})"
            )
        self.model, self.robot = model, robot
        self.tol_mm, self.tol_deg = _positive("tol_mm", tol_mm), _positive("tol_deg", tol_deg)
        self.damping = _positive("damping", damping, zero=True)
        self.pose_target = robot.target == Target.pose

    def _errors(self, q: torch.Tensor, x: torch.Tensor):
        """Task error e (B, 3 or 6), Jacobian J (B, 3 or 6, n), position error (B,) m, rotation (B,) rad."""
        jac, pose = self.robot.jacobian(q, with_pose=True)
        e_pos = x[:, :3] - pose[:, :3, 3]
        if not self.pose_target:
            return e_pos, jac, e_pos.norm(dim=-1), None
        r_err = tf.quaternion_to_matrix(x[:, 3:]) @ pose[:, :3, :3].transpose(-1, -2)
        e_rot = tf.matrix_to_axis_angle(r_err)  # (B, 3), world frame
        return torch.cat([e_pos, e_rot], -1), jac, e_pos.norm(dim=-1), e_rot.norm(dim=-1)

    def _polish(self, q: torch.Tensor, x: torch.Tensor, iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        """`iterations` damped-least-squares steps from joints q (B, n) toward targets x; (joints,
        converged (B,))."""
        low, high = self.robot.low.to(q.device), self.robot.high.to(q.device)
        eye = torch.eye(3 if not self.pose_target else 6, dtype=torch.float64, device=q.device)
        for _ in range(iterations):
            e, jac, _, _ = self._errors(q, x)
            y = torch.linalg.solve(jac @ jac.transpose(-1, -2) + self.damping * eye, e.unsqueeze(-1))
            q = (q + (jac.transpose(-1, -2) @ y).squeeze(-1)).clamp(low, high)
        _, _, pos, rot = self._errors(q, x)
        ok = pos * 1000.0 <= self.tol_mm
        if rot is not None:
            ok &= torch.rad2deg(rot) <= self.tol_deg
        return q, ok

    @torch.no_grad()
    def solve(
        self,
        targets,
        iterations: int = DEFAULT_ITERATIONS,
        restarts: int = 0,
        restart_iterations: int = 20,
        seed: int = 0,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Joints (B, n) float64 and converged (B,) bool for targets (B, 3) or (B, 7) (float64 math).

        restarts: for the targets not converged after `iterations` steps from the network's answer,
        up to this many rounds of `restart_iterations` steps from joints drawn uniformly in the
        trained box (generator seeded by `seed`); a target keeps the first start that converges.
        """
        for name, v in (("iterations", iterations), ("restarts", restarts), ("restart_iterations", restart_iterations)):
            _count(name, v)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
            raise ValueError(f"seed={seed!r} is not allowed: use an integer in [0, 2**63)")
        dev = self.robot.chain.device
        x = self.model.check_inputs(targets).to(dtype=torch.float64, device=dev)
        low, high = self.robot.low.to(dev), self.robot.high.to(dev)
        model = self.model if self.model.centers.dtype == torch.float64 else copy.deepcopy(self.model).double()
        q, ok = self._polish(model(x).clamp(low, high), x, iterations)
        g = torch.Generator(device=dev).manual_seed(seed)
        for _ in range(restarts):
            todo = (~ok).nonzero().squeeze(-1)
            if todo.numel() == 0:
                break
            start = low + (high - low) * torch.rand(
                todo.numel(), low.shape[0], generator=g, dtype=torch.float64, device=dev
            )
            q_r, ok_r = self._polish(start, x[todo], restart_iterations)
            q[todo[ok_r]], ok[todo[ok_r]] = q_r[ok_r], True
        return q, ok


def load_solver(path: str | Path, device: str = "cpu", tol_mm: float = 0.1, tol_deg: float = 0.1) -> IKSolver:
    """The IKSolver of the checkpoint at `path`: its network (float64) and its robot's kinematics."""
    validate_device(device, 0, prefix="")
    ckpt = read_checkpoint(path)
    return IKSolver(model_from_checkpoint(ckpt).to(device), robot_from_record(ckpt["robot"], device), tol_mm, tol_deg)
