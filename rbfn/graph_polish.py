"""The polish in a graph: a charted network's answers made exact inside the exported model.

A charted network's raw answers are seeds, tens of mm off (`rbfn.charts`); the torch solver
(`rbfn.solver.IKSolver`) polishes its charts' answers in turn, nearest first, each target until one
converges. A static graph cannot stop rows early, so `GraphPolish` polishes a fixed set on every
row instead, in plain tensor operations that torch.export and the ONNX exporter take, so that an
exported charted network answers exact joints and a flag that means what it says (the polish
converged within the tolerances), with onnxruntime alone:

1. the `PRESELECT` charts whose centres lie nearest the target, ranked by forward kinematics;
2. the best `WIDE` polished `FIRST_STEPS` damped-least-squares steps, the best `NARROW` of them the
   remaining steps (`STEPS` in all on each answer's path), the nearest kept.

This was the solver's staged polish before it took the charts in turn (measured there: the same
targets solved, at 2.9x the rate on the UR5). In the graph the rows are never split, so the line
search (the solver's charted polish takes a worse step back instead, over one step more; the graph
keeps its fixed `STEPS`, searched) and the re-solve without the joints a step carries past a limit
run on every row (masked where the solver takes a subset), and there is no fallback to every chart
for the few targets the ranking misses (the solver's last round). The robot's
kinematics are `rbfn.robots.kinematics.compose` on the chain's frames, held as constants; the
linear solve is a Cholesky factorisation written out (the ONNX exporter has no solve).
"""

from __future__ import annotations

import torch
from torch import nn

from .robots.backend import spd_solve
from .robots.kinematics import _Step, _steps, compose
from .robots.robot import Robot, rotation_error_deg, rotation_vector
from .solver import (
    CHARTED_ERROR_DAMPING,
    PRESELECT,
    PROGRESS,
    STEP_SCALES,
    IKSolver,
    goals,
    shortened,
)

__all__ = ["GraphPolish", "graph_polish"]

# The staged polish: of the PRESELECT charts whose centres lie nearest a target, ranked by forward
# kinematics, the WIDE best take FIRST_STEPS steps, the NARROW best after them the rest. Measured on
# the UR5 over the whole joint range (64 charts, 5 steps): polishing the best 1 / 2 / 4 / 8 ranked
# answers all 5 steps solves 80.5 / 92.0 / 98.2 / 99.5 %, the staged (8 x 2 steps, then 2 x 3) 98.6 %
# for 22 steps a target instead of 40 (every chart: 99.9 %).
WIDE = 4
FIRST_STEPS = 2
NARROW = 2
# Steps on each answer's path, each with the line search of the solver's `IKSolver._step` (the solver's
# charted solve takes one step more without it, `CHARTED_ITERATIONS`: a graph steps every row alike).
STEPS = 5

FULL = STEP_SCALES.index(1.0)  # the full step among the line search's multiples
RETRY = 8  # the answers ranked after the first WIDE, polished on every row for the targets those miss


class GraphPolish(nn.Module):
    """The staged polish of a charted network's answers for `robot`, as a graph (module docstring):
    `forward(seeds (B, K, n), closeness (B, K), targets x (B, 3, 7 or 8))` -> (joints (B, n),
    converged (B,)). Tolerances, damping and the step's bound as `solver`'s (an `IKSolver` of the
    charted network: its float64 settings, here in the module's dtype)."""

    held: torch.Tensor
    low: torch.Tensor
    high: torch.Tensor

    def __init__(self, robot: Robot, solver: IKSolver) -> None:
        super().__init__()
        steps = _steps(robot.chain)
        self.frames = [(st.kind, st.joint) for st in steps]
        for i, st in enumerate(steps):  # one buffer a frame: the graph takes them as constants
            self.register_buffer(f"frame{i}_move", st.move.float())
        self.register_buffer("held", robot.full_joints(robot.low[None].double())[0].float())  # locked values
        self.free = [int(i) for i in robot.free]
        self.chain_joints = int(self.held.shape[0])
        self.register_buffer("low", solver.low.float())
        self.register_buffer("high", solver.high.float())
        self.pose = solver.pose_target
        self.redundant = robot.redundant
        self.tol_mm, self.tol_deg = float(solver.tol_mm), float(solver.tol_deg)
        self.damping, self.error_damping = float(solver.damping), float(solver.error_damping)
        self.max_step = float(solver.max_step)

    def _kinematics(self, q: torch.Tensor, jacobian: bool):
        """(rotations (B, 3, 3), positions (B, 3), task Jacobian (B, 3 or 6, n) or None) at the free
        joints q (B, n): the chain's frames composed (`rbfn.robots.kinematics.compose`)."""
        if len(self.free) == self.chain_joints:
            th = q
        else:  # the held joints' values between the free ones
            columns = [q[:, self.free.index(j)] if j in self.free else self.held[j].expand(q.shape[0]) for j in
                       range(self.chain_joints)]  # fmt: skip
            th = torch.stack(columns, -1)
        steps = [_Step(getattr(self, f"frame{i}_move"), kind, joint) for i, (kind, joint) in enumerate(self.frames)]
        rot, pos, jac = compose(steps, th, jacobian)
        if jac is not None:
            jac = jac[:, : 6 if self.pose else 3][:, :, self.free]
        return rot, pos, jac

    def _errors(self, q: torch.Tensor, goal: torch.Tensor):
        """(task error e (B, 3 or 6), Jacobian (B, 3 or 6, n), cost (B,)) at joints q (B, n)."""
        rot, pos, jac = self._kinematics(q, True)
        e, mm, deg = self._error(rot, pos, goal)
        return e, self._tolerances(mm, deg), jac

    def _error(self, rot: torch.Tensor, pos: torch.Tensor, goal: torch.Tensor):
        """(task error e (B, 3 or 6), position error (B,) mm, rotation error (B,) deg or None) of end
        links at rot (B, 3, 3), pos (B, 3) against `goals` rows."""
        e = goal[:, :3] - pos
        mm = e.norm(dim=-1) * 1000.0
        if not self.pose:
            return e, mm, None
        r = goal[:, 3:].reshape(-1, 3, 3)
        return torch.cat([e, rotation_vector(r @ rot.transpose(-1, -2))], -1), mm, rotation_error_deg(rot, r)

    def _tolerances(self, mm: torch.Tensor, deg: torch.Tensor | None) -> torch.Tensor:
        """Errors in tolerances (B,): mm / tol_mm + deg / tol_deg."""
        return mm / self.tol_mm + (deg / self.tol_deg if deg is not None else 0.0)

    def cost(self, q: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Errors (B,) of joints q (B, n) against `goals` rows, in tolerances (forward kinematics only)."""
        rot, pos, _ = self._kinematics(q, False)
        return self._tolerances(*self._error(rot, pos, goal)[1:])

    def _step(self, a: torch.Tensor, e: torch.Tensor, lam: torch.Tensor, jac: torch.Tensor) -> torch.Tensor:
        eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device)
        return (jac.transpose(-1, -2) @ spd_solve(a + lam[:, None, None] * eye, e)[:, :, None])[:, :, 0]

    def polish(self, q: torch.Tensor, goal: torch.Tensor, iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(joints (B, n), their cost (B,)) after `iterations` steps from q (B, n) toward `goals` rows: the
        solver's damped-least-squares step with its joints carried past a limit held there
        (`IKSolver._direction`) and the line search of `IKSolver._step`, on every row."""
        low, high = self.low.to(q), self.high.to(q)
        scales = torch.tensor(STEP_SCALES, dtype=q.dtype, device=q.device)
        e, cost, jac = self._errors(q, goal)
        b, n, s = q.shape[0], q.shape[1], scales.shape[0]
        for _ in range(iterations):
            lam = self.damping + self.error_damping * e.square().sum(-1)
            dq = shortened(self.max_step, self._step(jac @ jac.transpose(-1, -2), e, lam, jac))
            # the joints it carries past a limit moved to it, the others taking the error left
            below, above = q + dq < low, q + dq > high
            held = below | above
            to_limit = torch.where(below, low - q, high - q) * held.to(q.dtype)
            e_h = e - (jac @ to_limit[:, :, None])[:, :, 0]
            jh = jac * (~held)[:, None, :].to(jac.dtype)
            dq_h = shortened(self.max_step, self._step(jh @ jh.transpose(-1, -2), e_h, lam, jh) + to_limit)
            dq = torch.where(held.any(-1, keepdim=True), dq_h, dq)
            # The full step and the line search's multiples of it (the full step among them) in one pass
            trials = torch.minimum(torch.maximum(q[:, None] + scales[None, :, None] * dq[:, None], low), high)
            trial_cost = self.cost(trials.reshape(b * s, n), goal.repeat_interleave(s, 0)).reshape(b, s)
            slow = trial_cost[:, FULL] > PROGRESS * cost
            pick = torch.where(slow, trial_cost.argmin(1), torch.full_like(slow, FULL, dtype=torch.long))
            q = trials.gather(1, pick[:, None, None].expand(b, 1, n))[:, 0]
            e, cost, jac = self._errors(q, goal)
        return q, cost

    def forward(self, seeds: torch.Tensor, closeness: torch.Tensor, x: torch.Tensor):
        b, k, n = seeds.shape
        if self.redundant is not None:  # the redundant joint at the value asked
            r = self.redundant
            seeds = torch.cat([seeds[..., :r], x[:, None, -1:].expand(b, k, 1), seeds[..., r + 1 :]], -1)
        goal = goals(x, self.pose)
        t = min(PRESELECT, k)
        idx = closeness.topk(t, dim=1, largest=False).indices
        ranked = seeds.gather(1, idx[..., None].expand(b, t, n))
        cost = self._costs(ranked, goal)
        ranked = ranked.gather(1, cost.argsort(1)[..., None].expand(b, t, n))
        # The best WIDE and the RETRY after them polished together (every row: a static graph), then
        # the best NARROW of the first WIDE and every retry the remaining steps; the nearest kept.
        c, w = min(WIDE + RETRY, t), min(WIDE, t)
        q, cost = self._polished(ranked[:, :c], goal, FIRST_STEPS)
        keep = cost[:, :w].argsort(1)[:, : min(NARROW, w)]
        q = torch.cat([q[:, :w].gather(1, keep[..., None].expand(b, keep.shape[1], n)), q[:, w:]], 1)
        q, cost = self._polished(q, goal, STEPS - FIRST_STEPS)
        q = q.gather(1, cost.argmin(1)[:, None, None].expand(b, 1, n))[:, 0]
        rot, pos, _ = self._kinematics(q, False)
        _, mm, deg = self._error(rot, pos, goal)
        ok = mm <= self.tol_mm
        return q, ok if deg is None else ok & (deg <= self.tol_deg)

    def _polished(self, q: torch.Tensor, goal: torch.Tensor, iterations: int) -> tuple[torch.Tensor, torch.Tensor]:
        """`polish` of joints q (B, T, n) toward `goals` rows (B, ...): (joints (B, T, n), cost (B, T))."""
        b, t, n = q.shape
        q, cost = self.polish(q.reshape(-1, n), goal.repeat_interleave(t, 0), iterations)
        return q.reshape(b, t, n), cost.reshape(b, t)

    def _costs(self, q: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """`cost` of joints q (B, T, n) against `goals` rows (B, ...): (B, T)."""
        b, t, n = q.shape
        return self.cost(q.reshape(-1, n), goal.repeat_interleave(t, 0)).reshape(b, t)


def graph_polish(robot: Robot, model) -> GraphPolish:
    """The `GraphPolish` of charted network `model` for `robot`, with the solver's settings for it
    (`rbfn.solver.load_solver`'s error damping)."""
    return GraphPolish(robot, IKSolver(model, robot, error_damping=CHARTED_ERROR_DAMPING))
