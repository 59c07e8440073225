"""Learned IK, then exact: the network picks the branch and gets close, a few batched
damped-least-squares (Levenberg-Marquardt) steps on the robot's own FK and Jacobian make it exact.

    solver = rbfn.load_solver("outputs/train/.../checkpoint.pt")
    q, converged = solver.solve(targets, iterations=3)   # targets (B, 3) m, or (B, 7) m + quaternion

    q, converged = solver.solve(targets, near=q_now)     # the converged answer nearest the current joints

Each step solves (J J^T + lambda I) y = e, dq = J^T y for the task error e (position in m, and for
pose targets the rotation error as an axis-angle vector in rad, root frame; lambda may grow with
the error, Levenberg-Marquardt's way: `error_damping`), shortens it to `max_step`, moves the
joints it would carry past a limit to the limit (the others take the error left), and
line-searches it where it makes little progress (a charted network's polish instead takes back a
step that makes the error worse and tries it shorter: `REJECTED_SCALE`); the joints stay within
the trained box widened by `margin` of its width (inside the URDF limits), so the answer stays on
the branch the network was trained on. For arms whose first joint turns about the base's vertical
axis, targets the network misses are turned into its trained range (`rbfn.yaw`) and that joint
ranges over its URDF limits. `converged` is True where the final error is within `tol_mm` and
`tol_deg`. With `restarts`, the targets that did not converge are tried again from random joints
in the box, as a sampling IK would, so only the hard few pay for it. Runs where torch and the
robot model are available; deployed exports hold the network alone.

Why one module of over 500 lines: the damped-least-squares step, its line search, the box
clamp, the restarts, a charted network's charts in turn and the nearest-solution choice are one
algorithm over one state (the solver's tolerances, joint range and robot), each part calling the
step and the same ranking of answers (`_rank`).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import torch
from pytorch_kinematics import transforms as tf

from .charts import ChartedIK, charts_from_checkpoint, embed
from .checkpoint import CHARTS_KIND, model_from_checkpoint, read_checkpoint
from .config import Target, finite, validate_device
from .layer import RBFNetwork, row_blocks
from .memory import FLOAT64, check_fits
from .robots.backend import spd_solve
from .robots.kinematics import joint_limits
from .robots.robot import Robot, robot_from_record, rotation_error_deg, rotation_vector
from .yaw import answer as yaw_answer, base_yaw as yaw_of, nearest_turn

__all__ = [
    "IKSolver",
    "load_solver",
    "DEFAULT_ITERATIONS",
    "MAX_ITERATIONS",
    "SOLVE_ALL_ITERATIONS",
    "CHARTED_ITERATIONS",
]

DEFAULT_ITERATIONS = 3
MAX_ITERATIONS = 1000  # per call and per restart: a guard against typos (the polish converges in a few)
STEP_SCALES = (2.0, 1.4, 1.0, 0.6, 0.3)  # the line search's multiples of a step (measured on the UR5)
# `solve_all`'s line search tries two besides the full step: the longer where the full step reduced the
# error too little, the shorter where it made it worse. Against trying all four: half the forward
# kinematics, 8-15 % more solves/s on the UR5, Panda and iiwa (3 % on the KR10), as many solved within one
# pose in 10 000 (test stream of seed 3 and evaluation stream), when the charted solve searched too.
# A box network's 3 steps are all it has: it tries all four (two: UR5 box 99.27 -> 99.18 %), as does the
# exported graph (no branches).
LONGER, SHORTER = STEP_SCALES[:2], STEP_SCALES[3:]
# The charted solve's polish (`IKSolver._trial`) searches no line: a step that makes the error worse is
# taken back and tried at REJECTED_SCALE of its length at the next step (and after a kept step the
# scale rises again by as much, up to the full step). Each step is then one Jacobian a row, where the line
# search added two forward kinematics for the rows searched and a Jacobian for those it moved, for one
# step more an answer (CHARTED_ITERATIONS 6, was 5). Measured on 10 000 whole-range poses of the test
# stream of seed 3 (not the evaluation stream), Jacobians and forward kinematics a pose: UR5 10.2 and 7.6
# -> 8.3 and 0.5, Panda 15.4 and 13.3 -> 11.8 and 1.1 (with GIVE_UP_STEP 4 and `_direction`'s joints moved
# to a limit); solved: UR5 100.00 % either way, Panda 99.93 % against 99.90 % (99.83 % without those two);
# the solve 1.17-1.30x faster on the UR5, Panda, KR10 and iiwa. Taken back to 0.5 of the step, the fewest
# Jacobians of 0.2, 0.3 and 0.5 (UR5 8.44, 8.34, 8.20 a pose; Panda 12.07, 11.96, 11.66), as many solved;
# a scale that also grew past the full step where progress was slow converged far less often (first
# chart, Panda: 45.6 % against 67.9 % in 5 steps).
REJECTED_SCALE = 0.5
# lambda's error-dependent part, lambda = damping + c |e|^2 (e: position in m, rotation in rad), off by
# default. Measured on UR5 poses over the whole joint range (5 % of them with sigma_min of J below 0.004,
# mostly at the wrist singularity), from the exact joints moved uniformly by up to 0.05 / 0.2 rad a joint:
# 5 steps converged 99.72 % / 96.62 % with c = 0 and 100.00 % / 99.50 % with c = 0.01 (0.1: 99.98 /
# 99.60; 3 steps 97.75 / 80.38 against 99.92 / 92.42). From the network's answers in the trained box it
# changes nothing measurable (UR5 at M = 300, 3 steps: 98.94 against 98.98 %), so the default keeps
# today's results; a whole-workspace seed will want it.
ERROR_DAMPING = 0.0
CHARTED_ERROR_DAMPING = 0.01  # load_solver's for a charted network: its seeds come from anywhere
# The charted network's raw answer (`IKSolver.network`): of the PRESELECT charts whose centres lie
# nearest a target, the best by forward kinematics.
PRESELECT = 16
# The charted solve's charts in turn (`IKSolver._charted_first`): the targets not yet reached try their
# next IN_TURN[i] charts (nearest first) at once in round i, while more than FEW of them remain after
# the first round; the rest try every chart not yet tried at once (a few targets, many charts: one
# batched polish instead of one small one a chart; a single target solved alone, 1.15x the time in
# turn through every round, 2.2x with every chart from the start, measured on the UR5). Measured on
# the UR5 and the Panda (64 charts, 10 000 poses of the test stream of seed 1, not the evaluation
# stream), each solving as many: with the rounds in blocks of 4 096 targets, (1, 2, 4, 8, 16) 10 174
# and 5 719 solves/s, (1, 2, 4, 8) 9 991 and 5 504, (1, 1, 2, 4, 8) 9 516 and 5 617, (1, 2, 4) 9 225
# and 4 202, one chart a round up to 8 about 7 550 on the UR5, FEW = 32 within 1 % of 8; with the
# rounds over the whole batch (as now), (1, 1, 2, 4, 8, 16) 3-9 % above (1, 2, 4, 8, 16) on the UR5,
# the Panda and the KR10 (12 018 / 11 040, 5 998 / 5 620, 11 377 / 11 091; median of 9), one chart a
# round up to 12 below both.
IN_TURN = (1, 1, 2, 4, 8, 16)
FEW = 8
# A charted solve polishes in float32 (its seeds are float32), then checks every answer in float64 and
# polishes there the few float32 left short: float32 halves the kinematics' memory traffic (UR5, 4 096 rows,
# one thread: pose and Jacobian 0.80 against 1.32 ms); its rounding (about 1e-6 m and rad) is a hundredth of
# the tolerances. The whole solve 1.1-1.2x faster on the UR5, Panda, KR10 and iiwa, success unchanged.
POLISH_DTYPE = torch.float32
# A settling polish (`IKSolver._polish`) of more than GIVE_UP_STEP steps gives up, after that many, on the
# answers still more than GIVE_UP tolerances off: they are on a branch that does not reach the target
# (the next chart's answer tries). Chosen on 4 000 whole-range poses of the test stream of seed 3 (not the
# evaluation stream), the first chart's answers polished 5 steps: of those still above 1 000 tolerances
# after 3 steps, none converged on the UR5 (189 of its 993 misses) and one of 670 on the Panda; after 2
# steps, 80 of the UR5's 3 007 that converge were still that far. On the evaluation stream the Panda solves
# 7-10 % faster, the UR5 and the KR10 2-5 %, each solving as many. With the steps taken back
# (`REJECTED_SCALE`) a far answer moves more slowly: after 4 steps, not 3 (10 000 poses of that stream, 6
# steps an answer): the Panda missed 7 poses, not 12, for 6 % more Jacobians; the UR5, KR10 and iiwa as
# many (0, 8, 0), for -1 to +2 %.
GIVE_UP_STEP = 4
GIVE_UP = 1000.0
# `_least_norm` solves J J^T y = e by Cholesky written out (`spd_solve`) with the batch last from this many
# rows, by `torch.linalg.solve` (batch first) below: one thread, float32, m = 6: 0.6 against 2.1 ms at 4 096
# rows, 0.8 against 0.3 ms at 512 (a fixed ~110 elementwise operations against LAPACK's per-matrix cost)
CHOLESKY_ROWS = 1024
# `IKSolver._posture`'s pull, a share of a joint's half range a step at its limit: the polish from `near`
# of an arm with more joints than its target needs (a 7-joint arm's pose) adds it in J's null space, so a
# path followed point by point drifts less along the arm's self-motion into a limit. Measured (the first
# value tried) on straight joint-space paths of 1 000 points between uniform joints, 26 an arm: jumps of
# more than 0.1 rad, Panda 2 (in 2 paths, the largest 4.6 rad) -> 1 (0.14 rad), iiwa 28 (in 5 paths) -> 16
# (in 4; most where joint 6 nears 0 and the wrist's self-motion turns fast); `bench.ik_path` on the
# Panda into the corners of its range (reach 0.45) 3 -> 0
POSTURE = 0.01
FLOAT32_DAMPING = 1e-6  # the least lambda (m^2) of a float32 step: J J^T's rounding is about 1e-7 of its trace
UNCONVERGED = 1e9  # `IKSolver._rank`'s offset of an unconverged answer (a converged one ranks below it)
SOLVE_ALL_ITERATIONS = 5
CHARTED_ITERATIONS = 6  # solve's default steps for a charted network (see REJECTED_SCALE)
# solve_all: answers this close in (cos q, sin q) are one solution. Measured on 300 UR5 poses: 1e-3 counted
# 7.76 a pose (at most 22: near the wrist singularity a continuum reaches the pose), 1e-2 7.06 (eaik: 7.02)
DISTINCT = 1e-2
PROGRESS = 0.25  # a full step that leaves more than this share of the error is searched along
FAR = 100.0  # a network answer this many tolerances off (10 mm at the default 0.1 mm) tries the base turns
BLOCK_ROWS = 4096  # targets a block of `IKSolver.solve`: its Jacobians, chains, base turns and line-search
# trials take up to 6 KB a target on the SCARA and 28 KB on the UR5 (measured), so a block holds at most ~120 MB
WHOLE_BATCH_VALUES = 8  # float64 joint vectors a target `solve` holds for the whole batch at most
# (answers, `near`, restarts' starts and answers, indices and masks), besides the targets


def goals(x: torch.Tensor, pose: bool) -> torch.Tensor:
    """Targets x (B, 3, 7 or 8) as the polish compares with them, once a polish: positions (B, 3)
    m, and for pose targets (`pose`) the rotation matrix's rows after them (B, 12)."""
    if not pose:
        return x[:, :3]
    return torch.cat([x[:, :3], tf.quaternion_to_matrix(x[:, 3:7]).reshape(-1, 9)], -1)


def _count(name: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_ITERATIONS:
        raise ValueError(f"{name}={v!r} is not allowed: use an integer in [0, {MAX_ITERATIONS}]")
    return v


def _positive(name: str, v, zero: bool = False) -> float:
    if not (finite(v) and (v >= 0 if zero else v > 0)):
        raise ValueError(f"{name}={v!r} is not allowed: use a finite number {'>= 0' if zero else '> 0'}")
    return float(v)


def _untried(tried: torch.Tensor, k: int) -> torch.Tensor:
    """(T, k - t) the chart indices of 0 .. k - 1 not in each row of tried (T, t) (distinct), in
    increasing order."""
    left = torch.ones(tried.shape[0], k, dtype=torch.bool, device=tried.device).scatter_(1, tried, False)
    return left.to(torch.int8).argsort(dim=1, descending=True, stable=True)[:, : k - tried.shape[1]]


def shortened(max_step: float, dq: torch.Tensor) -> torch.Tensor:
    """Steps dq (B, n) scaled down, each as a whole, to at most max_step on every joint (rad, or m)
    (the solver's and the exported graph's; a zero step stays zero)."""
    tiny = torch.finfo(dq.dtype).tiny
    return dq * (max_step / dq.abs().amax(-1, keepdim=True).clamp(min=tiny)).clamp(max=1.0)


def _least_norm(jl: torch.Tensor, lam: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """dq (B, n) = J^T (J J^T + lambda I)^-1 e for Jacobians jl (m, n, B), the batch last, lambda (B,)
    and errors e (B, m): J J^T and J^T y elementwise with the batch last (UR5, 4 096 rows, float32:
    J J^T 0.2 ms, against 4.0 ms as a batched product of the batch-first view). From `CHOLESKY_ROWS`
    rows, J J^T a sum of n outer products added in place (one thread, 4 096 rows: 0.16 against 0.44
    ms for n = 6) and the solve the written-out Cholesky `rbfn.robots.backend.spd_solve` on its
    batch-last entries; below them `torch.linalg.solve`."""
    m, n, b = jl.shape
    if b < CHOLESKY_ROWS:
        eye = torch.eye(m, dtype=jl.dtype, device=jl.device)
        jjt = (jl[:, None] * jl[None]).sum(2).permute(2, 0, 1)  # (B, m, m)
        y = torch.linalg.solve(jjt + lam[:, None, None] * eye, e.unsqueeze(-1)).squeeze(-1)  # (B, m)
        return (jl * y.T[:, None]).sum(0).T
    jl = jl.contiguous()
    a = jl[:, None, 0] * jl[None, :, 0]  # (m, m, B): J J^T, a sum of n outer products, in place
    for k in range(1, n):
        a.addcmul_(jl[:, None, k], jl[None, :, k])
    a.diagonal(dim1=0, dim2=1).add_(lam[:, None])  # + lambda I
    # the batch-last views: each entry `spd_solve` reads is a contiguous row of B
    y = spd_solve(a.permute(2, 0, 1), e.T.contiguous().T).T.contiguous()  # (m, B)
    dq = jl[0] * y[0]  # (n, B)
    for i in range(1, m):
        dq.addcmul_(jl[i], y[i])
    return dq.T


class IKSolver:
    """The IK network of a checkpoint plus damped-least-squares polish on the robot's kinematics.

    tol_mm, tol_deg: what counts as converged. damping: lambda of the step (m^2; 0 is Gauss-Newton).
    error_damping: c of the error-dependent part of lambda, lambda = damping + c |e|^2 per target
    (Levenberg-Marquardt damping that fades as the error does: near a singular configuration a
    far target's Gauss-Newton step is huge and wrong, the damped one short and right; 0: constant).
    max_step: the largest joint change of one step before its line search (rad, or m for a
    prismatic joint). margin: how far past the trained box the polish may move each joint, as a
    share of the box's width (kept inside the URDF limits). base_yaw: turn targets around the base
    into the trained range where the arm allows it (`rbfn.yaw`; False: as trained, targets unturned).
    """

    # Targets per block of `solve` and `network` (memory: see BLOCK_ROWS).
    block_rows: int = BLOCK_ROWS

    def __init__(
        self,
        model: RBFNetwork | ChartedIK,
        robot: Robot,
        *,
        tol_mm: float = 0.1,
        tol_deg: float = 0.1,
        damping: float = 1e-8,
        error_damping: float = ERROR_DAMPING,
        max_step: float = 0.5,
        margin: float = 0.1,
        base_yaw: bool = True,
    ) -> None:
        if not isinstance(model, (RBFNetwork, ChartedIK)):
            raise TypeError(f"model must be an RBFNetwork or a ChartedIK, got {type(model).__name__}")
        if not isinstance(robot, Robot):
            raise TypeError(f"robot must be a rbfn.robots.robot.Robot, got {type(robot).__name__}")
        if model.out_features != len(robot.joint_names):
            raise ValueError(
                f"the model returns {model.out_features} joints, the robot has {len(robot.joint_names)} "
                f"free joints ({robot.joint_names})"
            )
        if not isinstance(base_yaw, bool):
            raise ValueError(f"base_yaw={base_yaw!r} is not allowed: use True or False")
        self.model, self.robot = model, robot
        self.tol_mm, self.tol_deg = _positive("tol_mm", tol_mm), _positive("tol_deg", tol_deg)
        self.damping = _positive("damping", damping, zero=True)
        self.error_damping = _positive("error_damping", error_damping, zero=True)
        self.max_step = _positive("max_step", max_step)
        self.margin = _positive("margin", margin, zero=True)
        self.pose_target = robot.target == Target.pose
        self.charted = isinstance(model, ChartedIK)
        self._charts32: ChartedIK | None = None  # `_answering`'s float32 copy of a charted network
        self.yaw = yaw_of(robot) if base_yaw and not self.charted else None
        # The joints' range the network answers in (restarts draw from it, `near`'s distance divides by it).
        self.box_low: torch.Tensor = model.low if isinstance(model, ChartedIK) else robot.low
        self.box_high: torch.Tensor = model.high if isinstance(model, ChartedIK) else robot.high
        if isinstance(model, ChartedIK):  # the whole URDF range
            self.low, self.high = model.low.clone().double(), model.high.clone().double()
            return
        # The polish's joint range: the trained box widened by `margin` of its width, inside the URDF
        # limits; the first joint over its whole URDF range where targets are turned around the base.
        u_low, u_high = (t[robot.free] for t in joint_limits(robot.chain))
        wide = self.margin * (robot.high - robot.low)
        self.low = torch.maximum(robot.low - wide, u_low)
        self.high = torch.minimum(robot.high + wide, u_high)
        if self.yaw is not None:
            self.low[0], self.high[0] = self.yaw.limit_low, self.yaw.limit_high

    @property
    def default_iterations(self) -> int:
        """`solve`'s polish steps when not given: `CHARTED_ITERATIONS` for a charted network, else
        `DEFAULT_ITERATIONS`."""
        return CHARTED_ITERATIONS if self.charted else DEFAULT_ITERATIONS

    def _goals(self, x: torch.Tensor) -> torch.Tensor:
        """`goals` of targets x for this solver's robot."""
        return goals(x, self.pose_target)

    def _errors(self, q: torch.Tensor, goal: torch.Tensor):
        """Task error e (B, 3 or 6), Jacobian J (B, 3 or 6, n), position error (B,) m, rotation (B,)
        rad of joints q (B, n) against `goals` rows (B, 3 or 12)."""
        rot, pos, jac = self.robot.frame(q, jacobian=True)
        e_pos = goal[:, :3] - pos
        if not self.pose_target:
            return e_pos, jac, e_pos.norm(dim=-1), None
        e_rot = rotation_vector(goal[:, 3:].reshape(-1, 3, 3) @ rot.transpose(-1, -2))  # world frame
        return torch.cat([e_pos, e_rot], -1), jac, e_pos.norm(dim=-1), e_rot.norm(dim=-1)

    def _pose_errors(self, q: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(position error (B,) mm, rotation error (B,) deg or None) of joints q (B, n) against
        `goals` rows (B, 3 or 12), by forward kinematics only."""
        rot, pos, _ = self.robot.frame(q)
        mm = (pos - goal[:, :3]).norm(dim=-1) * 1000.0
        return mm, rotation_error_deg(rot, goal[:, 3:].reshape(-1, 3, 3)) if self.pose_target else None

    def _cost(self, q: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Error (B,) of joints q (B, n) against `goals` rows (B, 3 or 12) in tolerances: mm / tol_mm +
        deg / tol_deg (forward kinematics only)."""
        mm, deg = self._pose_errors(q, goal)
        return mm / self.tol_mm + (deg / self.tol_deg if deg is not None else 0.0)

    def _polish(
        self,
        q: torch.Tensor,
        x: torch.Tensor,
        iterations: int,
        first: tuple | None = None,
        hold: int | None = None,
        settle: bool = False,
        posture: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`iterations` damped-least-squares steps from joints q (B, n) toward targets x (`hold`: a
        joint index the steps leave where it is; `posture`, with `settle`: each step also pulls the
        joints away from their limits in J's null space, `_posture`); (joints, converged (B,)). `first`:
        `_errors(q, goals(x))` where already computed. Without `settle`, every step is `_step` (its
        line search). With `settle` (the charted solve's polish), every step is `_trial` (a step that
        makes the error worse is taken back, and tried shorter next), a target stops once converged
        (the steps left go to the others; its answer is then within the tolerances, not as near as
        the steps would bring it), or after `GIVE_UP_STEP` steps if still more than `GIVE_UP`
        tolerances off, so a batch costs the steps its targets need, not `iterations` each."""
        goal = self._goals(x)
        state = first if first is not None else self._errors(q, goal)
        if not settle:
            for _ in range(iterations):
                q, state = self._step(q, goal, state, hold)
            return q, self._converged(state)
        q, ok = q.clone(), torch.zeros(q.shape[0], dtype=torch.bool, device=q.device)
        active = torch.arange(q.shape[0], device=q.device)
        cost, scale = self._tolerances(state), torch.ones(q.shape[0], dtype=q.dtype, device=q.device)
        for i in range(iterations + 1):
            done = self._converged(state)
            ok[active[done]] = True
            if i == GIVE_UP_STEP < iterations:
                done = done | (cost > GIVE_UP)
            if i == iterations or bool(done.all()):
                break
            if bool(done.any()):
                keep = (~done).nonzero().squeeze(-1)
                active, state = active[keep], tuple(None if t is None else t.index_select(0, keep) for t in state)
                cost, scale = cost[keep], scale[keep]
            q_a, state, cost, scale = self._trial(
                q.index_select(0, active), goal.index_select(0, active), state, cost, scale, hold, posture
            )
            q.index_copy_(0, active, q_a)
        return q, ok

    def _reached(self, q: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """(B,) bool: joints q (B, n) within `tol_mm` and `tol_deg` of `goals` rows (forward kinematics only)."""
        mm, deg = self._pose_errors(q, goal)
        return mm <= self.tol_mm if deg is None else (mm <= self.tol_mm) & (deg <= self.tol_deg)

    def _converged(self, errors: tuple) -> torch.Tensor:
        """(B,) bool: `_errors`' position and rotation errors within `tol_mm` and `tol_deg`."""
        _, _, pos, rot = errors
        ok = pos * 1000.0 <= self.tol_mm
        if rot is not None:
            ok &= torch.rad2deg(rot) <= self.tol_deg
        return ok

    def _direction(self, q: torch.Tensor, state: tuple, hold: int | None, posture: bool = False) -> torch.Tensor:
        """The damped-least-squares step dq (B, n) from joints q (B, n), `state` being their `_errors`:
        dq = J^T (J J^T + lambda I)^-1 e, lambda = damping + error_damping |e|^2 (with `posture`, plus
        `_posture`'s pull in J's null space), shortened to at most `max_step` per joint; where it would
        carry joints past a limit, those joints go to the limit and the others take the error left (a
        clamping loop's one pass)."""
        low, high = self.low.to(q.device, q.dtype), self.high.to(q.device, q.dtype)
        e, jac = state[0], state[1]
        if hold is not None:
            jac = jac.clone()
            jac[:, :, hold] = 0.0
        # (float32: lambda at least FLOAT32_DAMPING, as float64's 1e-8 is below its rounding of J J^T)
        floor = FLOAT32_DAMPING if q.dtype == torch.float32 else 0.0
        lam = max(self.damping, floor) + self.error_damping * e.square().sum(-1)  # (B,)
        jl = jac.permute(1, 2, 0)  # (m, n, B): the batch last, as `compose` gives J
        dq = _least_norm(jl, lam, e)
        if posture:  # z less its part J^T (J J^T + lambda I)^-1 J z that would move the end link
            z = self._posture(q)
            if hold is not None:
                z[:, hold] = 0.0
            dq = dq + z - _least_norm(jl, lam, (jl * z.T).sum(1).T)
        dq = shortened(self.max_step, dq)
        # Joints the step carries past a limit: moved to it, and the error left solved again without
        # them (their columns of J zeroed), so the others take up what they cannot give.
        below, above = q + dq < low, q + dq > high
        held = below | above
        rows = held.any(-1).nonzero().squeeze(-1)
        if rows.numel():
            h = held[rows]
            to_limit = torch.where(below[rows], low - q[rows], high - q[rows]) * h  # (R, n)
            j = jl[:, :, rows]  # (m, n, R)
            e_h = e[rows] - (j * to_limit.T).sum(1).T
            dq[rows] = shortened(self.max_step, _least_norm(j * (~h).T, lam[rows], e_h) + to_limit)
        return dq

    def _posture(self, q: torch.Tensor) -> torch.Tensor:
        """(B, n) the pull of joints q (B, n) away from their limits: -`POSTURE` h u^3 (rad, or m), u the
        joint's place in the polish's range from -1 to 1 (its middle 0), h half that range's width.
        Cubed, it pulls hardly at all in the middle of a range (u = 0.5: an eighth of it at a limit)."""
        low, high = self.low.to(q.device, q.dtype), self.high.to(q.device, q.dtype)
        half = 0.5 * (high - low)
        return -POSTURE * half * ((q - low) / half - 1.0).pow(3)

    def _trial(
        self,
        q: torch.Tensor,
        goal: torch.Tensor,
        state: tuple,
        cost: torch.Tensor,
        scale: torch.Tensor,
        hold: int | None,
        posture: bool = False,
    ) -> tuple[torch.Tensor, tuple, torch.Tensor, torch.Tensor]:
        """One step of a settling polish (`_polish`), without a line search: q + scale dq (`_direction`,
        within the polish's joint range), kept where it lowers the error (`_tolerances`, cost (B,) at q)
        and taken back where it does not, its scale (B,) then cut to `REJECTED_SCALE` of itself (where
        kept, raised again by as much, up to 1). (joints, `_errors` there, their cost, the scales.) A
        step is one Jacobian for every row; a taken-back step costs its row a step."""
        low, high = self.low.to(q.device, q.dtype), self.high.to(q.device, q.dtype)
        tried = (q + scale[:, None] * self._direction(q, state, hold, posture)).clamp(low, high)
        after = self._errors(tried, goal)
        now = self._tolerances(after)
        better = now < cost
        kept = tuple(
            None if a is None else torch.where(better.view(-1, *(1,) * (a.dim() - 1)), a, b)
            for a, b in zip(after, state)
        )
        scale = torch.where(better, (scale / REJECTED_SCALE).clamp(max=1.0), scale * REJECTED_SCALE)
        return torch.where(better[:, None], tried, q), kept, torch.where(better, now, cost), scale

    def _step(self, q: torch.Tensor, goal: torch.Tensor, state: tuple, hold: int | None) -> tuple[torch.Tensor, tuple]:
        """One damped-least-squares step (`_direction`) from joints q (B, n) toward `goals` rows,
        `state` being `_errors(q, goal)`, with a line search: (the joints after it, `_errors` there).

        Where the full step leaves more than PROGRESS of the error (mm / tol_mm + deg / tol_deg), a
        line search: q + a dq for a in SHORTER where the full step made the error worse, in LONGER
        where it reduced it too little (a box network: in both), each within the polish's joint
        range, the one nearest the target kept. Near a singular configuration the full Gauss-Newton
        step overshoots (the first step from a far network answer multiplied the error threefold);
        the search takes the shorter step there and the longer one where the error is curved the
        other way. A step costs one Jacobian (its pose gives the error after the step, and the next
        step's Jacobian), plus two forward kinematics (a box network: four) for the rows searched,
        and a Jacobian for those of them a shorter or longer step moves."""
        low, high = self.low.to(q.device, q.dtype), self.high.to(q.device, q.dtype)
        dq = self._direction(q, state, hold)
        full = (q + dq).clamp(low, high)
        # The error after the step comes with the next step's Jacobian (it costs about what forward
        # kinematics alone does), so a step is one Jacobian, not a Jacobian and a pose.
        after = self._errors(full, goal)
        now, before = self._tolerances(after), self._tolerances(state)
        slow = (now > PROGRESS * before).nonzero().squeeze(-1)
        if slow.numel():  # the full step's error is `after`'s; the other multiples by forward kinematics
            if self.charted:  # (m, s)
                worse = (now[slow] > before[slow])[:, None]
                scales = torch.where(worse, q.new_tensor(SHORTER), q.new_tensor(LONGER))
            else:
                scales = q.new_tensor(LONGER + SHORTER).expand(slow.numel(), -1)
            m, n, s = slow.numel(), q.shape[1], scales.shape[1]
            trials = (q[slow, None] + scales[:, :, None] * dq[slow, None]).clamp(low, high)  # (m, s, n)
            cost = self._cost(trials.reshape(m * s, n), goal[slow].repeat_interleave(s, 0)).reshape(m, s)
            best = torch.cat([cost, now[slow, None]], 1).argmin(-1)
            moved = (best < s).nonzero().squeeze(-1)
            full[slow[moved]] = trials[moved, best[moved]]
            self._refresh(after, slow[moved], full, goal)
        return full, after

    def _refresh(self, errors: tuple, rows: torch.Tensor, q: torch.Tensor, goal: torch.Tensor) -> None:
        """`errors` (`_errors`' tuple for joints q (B, n) and `goals` rows) recomputed in place at `rows`
        (indices), where q changed."""
        for part, new in zip(errors, self._errors(q[rows], goal[rows])):
            if part is not None and new is not None:
                part[rows] = new

    def _tolerances(self, errors: tuple) -> torch.Tensor:
        """`_errors`' position (m) and rotation (rad) errors (B,) in tolerances: mm / tol_mm + deg / tol_deg."""
        _, _, pos, rot = errors
        return pos * 1000.0 / self.tol_mm + (torch.rad2deg(rot) / self.tol_deg if rot is not None else 0.0)

    @torch.no_grad()
    def network(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(the network's joints (B, n) float64, within the polish's range; the base turn d (B,) rad,
        0 without it) for targets x (B, 3 or 7) float64, in blocks of `block_rows` targets."""
        model = self._answering()
        return row_blocks(lambda xb: self._network(xb, model)[:2], self.block_rows, x)

    def _answering(self):
        """The network in float64 (itself, or a float64 copy); a charted one in float32 (its
        answers are seeds the polish makes exact: float32 halves their time), frozen once (`ChartedIK.frozen`)."""
        if isinstance(self.model, ChartedIK):
            if self._charts32 is None:
                self._charts32 = self.model.frozen(torch.float32)
            return self._charts32
        return self.model if self.model.centers.dtype == torch.float64 else copy.deepcopy(self.model).double()

    def _network(self, x: torch.Tensor, model: RBFNetwork):
        """`network`'s (joints, turn) for one block of targets x, from the float64 network `model`,
        and `_errors` at those joints (None without the base turn)."""
        low, high = self.low.to(x.device), self.high.to(x.device)
        d = torch.zeros(x.shape[0], dtype=torch.float64, device=x.device)
        if isinstance(model, ChartedIK):  # the best-ranked chart's answer
            return self._ranked(model, x)[0][:, 0], d, None
        q = model(x).clamp(low, high)
        if self.yaw is None:
            return q, d, None
        # The answer as trained where it is close; the targets it misses by more than FAR tolerances
        # (outside the trained yaw range, or at its edge) try the base turns, picked by forward kinematics.
        # The errors come with the Jacobian, the polish's first.
        goal = self._goals(x)
        e, jac, pos, rot = self._errors(q, goal)
        cost = self._tolerances((e, jac, pos, rot))
        far = (cost > FAR).nonzero().squeeze(-1)
        if far.numel():
            xf, gf, k = x[far], goal[far], self.yaw.candidates
            plain = lambda z: (model(z), torch.ones(z.shape[0], dtype=torch.bool, device=z.device))  # noqa: E731
            q_f, _, d_f = yaw_answer(self.yaw, plain, xf, score=lambda qs: self._cost(qs, gf.repeat(k, 1)))
            q_f = q_f.clamp(low, high)
            better = self._cost(q_f, gf) < cost[far]
            rows = far[better]
            q[rows], d[rows] = q_f[better], d_f[better]
            if rows.numel():
                self._refresh((e, jac, pos, rot), rows, q, goal)
        return q, d, (e, jac, pos, rot)

    def _near(self, near, b: int, device) -> torch.Tensor:
        """`near` as (B, n) float64 joints, or a clear error naming it."""
        names = self.robot.joint_names
        want = f"({b}, {len(names)}): the robot's current joints {names} (rad, or m if prismatic), a row per target"
        if isinstance(near, np.ndarray):
            near = torch.as_tensor(near)
        if not isinstance(near, torch.Tensor):
            raise TypeError(f"near must be a torch.Tensor or numpy.ndarray {want}; got {type(near).__name__}")
        if tuple(near.shape) != (b, len(names)):
            raise ValueError(f"near must be {want}; got shape {tuple(near.shape)}")
        if not near.is_floating_point():
            raise TypeError(f"near must be floating-point joints {want}; got dtype {near.dtype}")
        bad = ~torch.isfinite(near).all(-1)
        if bool(bad.any()):
            i = int(bad.nonzero()[0])
            raise ValueError(f"near must be finite; row {i} is {near[i].tolist()}")
        return near.to(dtype=torch.float64, device=device)

    @torch.no_grad()
    def solve(
        self,
        targets,
        iterations: int | None = None,
        restarts: int = 0,
        restart_iterations: int = 20,
        seed: int = 0,
        near=None,
        redundancy=None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Joints (B, n) float64 and converged (B,) bool for targets (B, 3) or (B, 7) (float64 math;
        a charted network's polish in `POLISH_DTYPE`, every answer then checked in float64).

        iterations: polish steps on each answer's path; None: `DEFAULT_ITERATIONS` (3), or for a
        charted network (`rbfn.charts`) `CHARTED_ITERATIONS` (6: its seeds are farther).

        redundancy: for a network trained with a redundant joint (`robot.redundancy`), that joint's
        value (B,) (rad, or m if prismatic) the network answers with; None: `near`'s value of it,
        or without `near` the middle of its trained range. The polish moves every joint, by the
        least-norm step, so the answer keeps that joint near the value asked.

        near: the robot's current joints (B, n) (rad, or m if prismatic), or None. Given, the polish
        starts from both the network's answer and `near`, and each target gets, among the converged
        answers, the one nearest `near` (the first joint, where targets are turned around the base,
        by the whole turn nearest it); distance: each joint's change divided by the width of its
        trained range, so radians and metres count alike. For a charted network, `near` polished
        is the answer where it converges (where the arm has more joints than its target needs, a
        7-joint arm's pose, each step also pulls the joints from their limits in J's null space,
        `POSTURE`, so a path solved point by point drifts less along the self-motion into a
        limit), else the converged one nearest `near` of every chart's answers, its whole turns
        nearest `near`. Solving a path point by point with the previous
        answer as `near` keeps it on its branch.
        restarts: for the targets not converged after `iterations` steps from the network's answer,
        up to this many rounds of `restart_iterations` steps from joints drawn uniformly in the
        trained box (turned with the target; generator seeded by `seed`); a target keeps the first
        start that converges.

        Any B: the targets are solved in blocks of `block_rows` (a charted network's rounds polish
        in blocks of `block_rows` answers; each target's answer is its own, so the blocks give what
        one whole batch gives); what the call holds for the whole batch is a few float64 numbers a
        target (`WHOLE_BATCH_VALUES`, and a charted network's order of the charts), checked against
        the memory available before any work where B is above one block.
        """
        if iterations is None:
            iterations = self.default_iterations
        for name, v in (("iterations", iterations), ("restarts", restarts), ("restart_iterations", restart_iterations)):
            _count(name, v)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
            raise ValueError(f"seed={seed!r} is not allowed: use an integer in [0, 2**63)")
        dev = self.robot.chain.device
        r = self.robot.redundant
        x = self._inputs(targets, near, redundancy, dev)
        b, rows = x.shape[0], self.block_rows
        if isinstance(rows, bool) or not isinstance(rows, int) or rows < 1:
            raise ValueError(f"IKSolver.block_rows={rows!r} is not allowed: use a positive integer (targets a block)")
        if b > rows:
            n = len(self.robot.joint_names)
            order = sum(IN_TURN) if self.charted else 0  # a charted solve's charts a target, in turn (int64)
            check_fits(
                "targets",
                tuple(x.shape),
                b * (2 * x.shape[1] + WHOLE_BATCH_VALUES * n + order) * FLOAT64,
                str(dev),
                f"the targets in float64 (and a copy), the answers, {WHOLE_BATCH_VALUES} float64 joint vectors a "
                f"target{f', and the order of {order} charts' if order else ''}; the polish itself runs in blocks "
                f"of {rows} targets",
                advice="solve fewer targets a call",
            )
        x = x.to(dtype=torch.float64, device=dev)
        near_q = None if near is None else self._near(near, b, dev)
        model = self._answering()
        if isinstance(model, ChartedIK):  # the whole batch at once: its rounds polish in blocks
            q, ok, d = self._charted_first(model, x, near_q, iterations)
        elif near_q is None:
            q, ok, d = row_blocks(lambda xb: self._first(model, xb, None, iterations), rows, x)
        else:
            q, ok, d = row_blocks(lambda xb, nb: self._first(model, xb, nb, iterations), rows, x, near_q)
        low, high = self.box_low.to(dev, torch.float64), self.box_high.to(dev, torch.float64)
        g = torch.Generator(device=dev).manual_seed(seed)
        for _ in range(restarts):
            todo = (~ok).nonzero().squeeze(-1)
            if todo.numel() == 0:
                break
            start = low + (high - low) * torch.rand(
                todo.numel(), low.shape[0], generator=g, dtype=torch.float64, device=dev
            )
            if self.yaw is not None:
                start[:, 0] += self.yaw.sign * d[todo]
            if r is not None:  # the redundant joint where it was asked to be
                start[:, r] = x[todo, -1]
            q_r, ok_r = row_blocks(lambda sb, xb: self._polish(sb, xb, restart_iterations), rows, start, x[todo])
            q[todo[ok_r]], ok[todo[ok_r]] = q_r[ok_r], True
        return q, ok

    def _inputs(self, targets, near, redundancy, dev) -> torch.Tensor:
        """The network's inputs (B, d) for `solve`'s targets, `near` and `redundancy` (checked)."""
        if self.robot.redundant is not None:
            return self._redundant_inputs(targets, near, redundancy, dev)
        if redundancy is not None:
            raise ValueError(
                "redundancy= is not allowed: this network was trained without a redundant joint "
                f"(robot.redundancy is empty; its joints {self.robot.joint_names} follow from the target alone)"
            )
        return self.model.check_inputs(targets)

    def _redundant_inputs(self, targets, near, redundancy, dev) -> torch.Tensor:
        """The network's inputs (B, 8): poses `targets` (B, 7) and the redundant joint's value from
        `redundancy` (B,), else `near` (B, n), else the middle of its trained range."""
        r, name = self.robot.redundant, self.robot.redundancy
        assert r is not None
        t = torch.as_tensor(targets) if isinstance(targets, np.ndarray) else targets
        if not isinstance(t, torch.Tensor) or t.dim() != 2 or t.shape[1] != 7:
            got = f"shape {tuple(t.shape)}" if isinstance(t, torch.Tensor) else type(t).__name__
            raise ValueError(
                f"IK targets must be poses (B, 7): position in m, then a unit quaternion (w, x, y, z); got {got} "
                f"(the redundant joint {name}'s value comes from near= or redundancy=)"
            )
        b = t.shape[0]
        if redundancy is not None:
            v = torch.as_tensor(redundancy) if isinstance(redundancy, np.ndarray) else redundancy
            if not isinstance(v, torch.Tensor) or tuple(v.shape) != (b,) or not v.is_floating_point():
                got = f"{v.dtype} shape {tuple(v.shape)}" if isinstance(v, torch.Tensor) else type(v).__name__
                raise ValueError(
                    f"redundancy must be a floating-point tensor or array ({b},): joint {name}'s value per target "
                    f"(rad, or m if prismatic); got {got}"
                )
            v = v.to(dtype=torch.float64, device=dev)
        elif near is not None:
            v = self._near(near, b, dev)[:, r]
        else:
            v = torch.full((b,), float(0.5 * (self.box_low[r] + self.box_high[r])), dtype=torch.float64, device=dev)
        return self.model.check_inputs(torch.cat([t.to(device=dev, dtype=torch.float64), v[:, None]], -1))

    def _first(
        self, model: RBFNetwork, x: torch.Tensor, near_q: torch.Tensor | None, iterations: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """`solve` before its restarts for a box network, one block of targets x (B, 3 or 7) float64 (and `near`'s
        joints (B, n)): (joints (B, n), converged (B,), the base turn (B,) rad) from the float64
        network `model`."""
        b, dev = x.shape[0], x.device
        q, d, first = self._network(x, model)
        if near_q is None:
            q, ok = self._polish(q, x, iterations, first)
            return q, ok, d
        both, ok2 = self._polish(
            torch.cat([q, near_q.clamp(self.low.to(dev), self.high.to(dev))]), x.repeat(2, 1), iterations
        )
        both = both.reshape(2, b, q.shape[1])
        if self.yaw is not None:
            both[..., 0] = nearest_turn(self.yaw, both[..., 0].reshape(-1), near_q[:, 0].repeat(2))[0].reshape(2, b)
        q, ok = self._pick(both.transpose(0, 1), ok2.reshape(2, b).T, x, near_q)
        return q, ok, d

    def _pick(
        self, cands: torch.Tensor, ok: torch.Tensor, x: torch.Tensor, near_q: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Of candidate answers cands (B, C, n) with converged ok (B, C) to targets x (B, d), the
        best by `_rank`: the converged one nearest `near_q` (B, n), where none converged the
        nearest the target. (joints (B, n), converged (B,)); ties: the first."""
        b, c, n = cands.shape
        rep = lambda t: t.repeat_interleave(c, 0)  # noqa: E731
        pick = self._rank(cands.reshape(-1, n), ok.reshape(-1), rep(x), rep(near_q)).reshape(b, c).argmin(1)
        rows = torch.arange(b, device=cands.device)
        return cands[rows, pick], ok[rows, pick]

    def _ranked(self, model: ChartedIK, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(the charts' answers (B, T, n) to targets x (B, d) float64, best first: the `PRESELECT`
        charts whose centres lie nearest the target (in cover radii), ranked by forward kinematics;
        every chart's answer (B, K, n))."""
        q, close = model.answers(x)
        q = self._asked(q.to(x.dtype), x)
        b, k, n = q.shape
        t = min(PRESELECT, k)
        idx = close.topk(t, dim=1, largest=False).indices
        seeds = q.gather(1, idx[..., None].expand(-1, -1, n))
        cost = self._cost(seeds.reshape(-1, n), self._goals(x).repeat_interleave(t, 0)).reshape(b, t)
        return seeds.gather(1, cost.argsort(1)[..., None].expand(-1, -1, n)), q

    def _asked(self, q: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The charts' answers q (B, K, n) or (B, n) with a redundant joint set to the value asked (the last
        column of the inputs x (B, 8)); unchanged without one."""
        r = self.robot.redundant
        if r is not None:
            q[..., r] = x[:, -1].to(q.dtype).view(-1, *(1,) * (q.dim() - 2))
        return q

    def _charted_first(
        self, model: ChartedIK, x: torch.Tensor, near_q: torch.Tensor | None, iterations: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """`_first` for a charted network, on the whole batch (each round's polish in blocks of
        `block_rows` answers): the charts in turn, nearest first (`ChartedIK.ranked`). Without
        `near`, every target takes its nearest chart's answer, the targets still unreached their
        next chart's, then the next 2, 4, ... (`IN_TURN`), and the last few (or all after those
        rounds) every chart not yet tried; the first that converges is the answer. With `near`, it
        is polished first and is the answer where it converges; the few targets it does not reach
        try every chart at once, and the converged answer nearest `near` (its whole turns nearest
        it) is theirs. Each answer is polished `iterations` steps, a target stopping once it
        converges (`_polish`'s `settle`); the targets none reached polish their nearest answer
        `iterations` steps more, and keep the answer nearest the target. So a target pays for the
        charts it needs: measured on the UR5 (64 charts, whole-range poses), 73 % converge from the
        first chart, and a pose polishes about 1.5 chart answers (the staged polish this replaced
        polished 14 answer steps a pose, the best 4 of 16 ranked by forward kinematics 2 steps and
        the best 2 of them 3 more). The polish runs in `POLISH_DTYPE`; the answers come back in
        float64, checked there, the few float32 left short of the tolerances polished again."""
        x64, x = x, x.to(POLISH_DTYPE)
        near_q = None if near_q is None else near_q.to(POLISH_DTYPE)
        b, dev, rows = x.shape[0], x.device, self.block_rows
        low, high = self.low.to(dev, x.dtype), self.high.to(dev, x.dtype)
        q = torch.zeros(b, low.shape[0], dtype=x.dtype, device=dev)
        ok = torch.zeros(b, dtype=torch.bool, device=dev)
        # the best answer's rank (`_rank`): below UNCONVERGED where it converged
        miss = torch.full((b,), torch.inf, dtype=torch.float64, device=dev)
        todo = torch.arange(b, device=dev)
        rounds: tuple[int, ...] = IN_TURN
        if near_q is not None:
            start = near_q.clamp(low, high)
            redundant = low.shape[0] > (6 if self.pose_target else 3)  # joints the target leaves free
            q, ok = row_blocks(
                lambda sb, xb: self._polish(sb, xb, iterations, settle=True, posture=redundant), rows, start, x
            )
            todo = (~ok).nonzero().squeeze(-1)
            miss[todo] = UNCONVERGED + row_blocks(self._cost, rows, q[todo], self._goals(x[todo])).double()
            rounds = ()  # the few `near` does not reach: every chart, the converged answer nearest `near`
        # the first round's chart for every target; the next charts' order for the targets it leaves
        order = row_blocks(lambda xb: model.ranked(xb, rounds[0] if rounds else 0), rows, x[todo])
        k, at = model.num_charts, 0
        for width in (*rounds, k):
            if not todo.numel():
                break
            width = min(width, order.shape[1] - at)
            every = width < 1 or (at > 0 and todo.numel() <= FEW)  # every chart not yet tried, at once
            if every and at >= k:
                break
            charts = _untried(order[:, :at], k) if every else order[:, at : at + width]
            per = max(1, rows // charts.shape[1])  # targets a block: at most `block_rows` answers polished at once
            near_rows = () if near_q is None else (near_q[todo],)
            qs, oks, cost = row_blocks(
                lambda xb, cb, *nb: self._attempt(model, xb, cb, nb[0] if nb else None, iterations),
                per,
                x[todo],
                charts,
                *near_rows,
            )
            better = cost < miss[todo]
            q[todo[better]], miss[todo[better]], ok[todo[oks]] = qs[better], cost[better], True
            if every:
                break
            todo, order, at = todo[~oks], order[~oks], at + width
            if order.shape[1] == at and at < sum(rounds) and todo.numel():
                order = row_blocks(lambda xb: model.ranked(xb, sum(rounds)), rows, x[todo])
        # The targets no answer reached: the nearest answer `iterations` steps more (near a singular
        # configuration the last tenth of a millimetre can take them)
        rest = (~ok).nonzero().squeeze(-1)
        if rest.numel():
            q_r, ok_r = row_blocks(lambda sb, xb: self._polish(sb, xb, iterations, settle=True), rows, q[rest], x[rest])
            if near_q is not None:  # its whole turns nearest `near`, as `_attempt`'s answers
                q_r = self._turned(q_r, near_q[rest])
            keep = ok_r | (UNCONVERGED + row_blocks(self._cost, rows, q_r, self._goals(x[rest])).double() < miss[rest])
            q[rest[keep]], ok[rest] = q_r[keep], ok_r
        # float64 from here (float32's limits are rounded outward: back inside them); the answers
        # checked, and the few that float32 left short of the tolerances polished
        q = q.double().clamp(self.low.to(dev), self.high.to(dev))
        short = (ok & ~row_blocks(self._reached, rows, q, self._goals(x64))).nonzero().squeeze(-1)
        if short.numel():
            q[short], ok[short] = self._polish(q[short], x64[short], iterations, settle=True)
        return q, ok, torch.zeros(b, dtype=torch.float64, device=dev)

    def _attempt(
        self, model: ChartedIK, x: torch.Tensor, charts: torch.Tensor, ref: torch.Tensor | None, iterations: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """For targets x (T, d), the answers of charts[i] (T, W) polished `iterations` steps (each
        stopping once converged), their whole turns nearest ref[i] (T, n) where given; of each
        target's W, the best by `_rank`: (joints (T, n), converged (T,), its rank (T,))."""
        t, w = charts.shape
        xs = x.repeat_interleave(w, 0)
        seeds = self._asked(model.chart_answers(xs, charts.reshape(-1)).to(x.dtype), xs)
        q, ok = self._polish(seeds, xs, iterations, settle=True)
        if ref is not None:
            q = self._turned(q, ref.repeat_interleave(w, 0))
        rank = self._rank(q, ok, xs, None if ref is None else ref.repeat_interleave(w, 0))
        pick = torch.arange(t, device=x.device) * w + rank.reshape(t, w).argmin(1)
        return q[pick], ok[pick], rank[pick]

    def _rank(self, q: torch.Tensor, ok: torch.Tensor, x: torch.Tensor, ref: torch.Tensor | None) -> torch.Tensor:
        """(B,) how answers q (B, n) with converged ok (B,) to targets x rank, lowest best: a
        converged answer its distance to ref (B, n) (each joint's change over its range's width, so
        radians and metres count alike), or 0 without ref (so the first converged wins a tie); an
        unconverged one UNCONVERGED plus its `_cost` (the nearest the target)."""
        rank = torch.zeros(q.shape[0], dtype=torch.float64, device=q.device)
        if ref is not None:
            width = (self.box_high - self.box_low).to(q.device, q.dtype)
            rank[ok] = ((q[ok] - ref[ok]) / width).norm(dim=-1).double()
        rank[~ok] = UNCONVERGED + self._cost(q[~ok], self._goals(x[~ok])).double()
        return rank

    def _turned(self, q: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        """Joints q (..., n) with each revolute joint moved by the whole turns that bring it nearest
        `ref` (broadcast to q) within the polish's range (unmoved where no turn fits)."""
        assert isinstance(self.model, ChartedIK)
        rev = self.model.revolute.to(q.device)
        low, high = self.low.to(q.device, q.dtype), self.high.to(q.device, q.dtype)
        turned = q + 2 * torch.pi * torch.round((ref - q) / (2 * torch.pi))
        turned = torch.where(turned > high, turned - 2 * torch.pi, turned)
        turned = torch.where(turned < low, turned + 2 * torch.pi, turned)
        fits = rev & (turned >= low) & (turned <= high)
        return torch.where(fits, turned, q)

    @torch.no_grad()
    def solve_all(
        self, targets, iterations: int = SOLVE_ALL_ITERATIONS, redundancy=None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Every distinct solution the network's charts lead to: (solutions (B, K, n) float64,
        converged (B, K) bool), K the number of charts (1 for a box network), the distinct converged
        answers first in each row and NaN after them. Each chart's answer is polished `iterations`
        steps; answers whose joints (cos q, sin q for a revolute joint, so whole turns count as one)
        lie within `DISTINCT` of an earlier one are the same solution. `redundancy`: as in `solve`."""
        _count("iterations", iterations)
        if not isinstance(self.model, ChartedIK):
            q, ok = self.solve(targets, iterations, redundancy=redundancy)
            return torch.where(ok[:, None], q, torch.nan)[:, None], ok[:, None]
        dev = self.robot.chain.device
        x = self._inputs(targets, None, redundancy, dev).to(dtype=torch.float64, device=dev)
        model = self._answering()
        rows = max(1, self.block_rows // model.num_charts)
        return row_blocks(lambda xb: self._all(model, xb, iterations), rows, x)

    def _all(self, model: ChartedIK, x: torch.Tensor, iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        """`solve_all` for one block of targets x (B, d) float64."""
        seeds = self._asked(model.answers(x)[0].to(x.dtype), x)
        b, k, n = seeds.shape
        # a redundant arm's joint held where it was asked to be: its solutions are then discrete
        q, ok = self._polish(seeds.reshape(-1, n), x.repeat_interleave(k, 0), iterations, hold=self.robot.redundant)
        q, ok = q.reshape(b, k, n), ok.reshape(b, k)
        e = embed(q.reshape(-1, n), model.revolute, model.low, model.high).reshape(b, k, -1)
        same = torch.cdist(e, e) < DISTINCT  # (B, K, K)
        earlier = torch.ones(k, k, dtype=torch.bool, device=x.device).tril(-1)
        dup = (same & earlier & ok[:, None, :]).any(-1)
        keep = ok & ~dup
        order = (~keep).to(torch.int8).argsort(dim=1, stable=True)
        q = torch.where(keep[..., None], q, torch.nan).gather(1, order[..., None].expand(-1, -1, n))
        return q, keep.gather(1, order)


def load_solver(
    path: str | Path, device: str = "cpu", tol_mm: float = 0.1, tol_deg: float = 0.1, base_yaw: bool = True
) -> IKSolver:
    """The IKSolver of the checkpoint at `path`: its network (float64) and its robot's kinematics."""
    validate_device(device, 0, prefix="")
    ckpt = read_checkpoint(path)
    robot = robot_from_record(ckpt["robot"], device)
    if ckpt["kind"] == CHARTS_KIND:  # a charted network (robot.workspace=full)
        charted = charts_from_checkpoint(ckpt).to(device)
        return IKSolver(charted, robot, tol_mm=tol_mm, tol_deg=tol_deg, error_damping=CHARTED_ERROR_DAMPING)
    return IKSolver(model_from_checkpoint(ckpt).to(device), robot, tol_mm=tol_mm, tol_deg=tol_deg, base_yaw=base_yaw)
