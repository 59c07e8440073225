"""Branch jumps along a dense path: `IKSolver.solve` point by point with the previous answer as
`near`, against each point solved alone (the network's answer polished), on a trained
checkpoint's robot.

    python -m bench.ik_path CHECKPOINT [--n 1000] [--reach 0.25] [--iterations K] [--threads 1]

The path: the poses (or positions) of a straight joint-space line through the trained box (for a
charted network, robot.workspace=full: the URDF limits, so it crosses the workspace), every
joint from `reach` times the box's width below its middle to as far above (0.25: away from the
box's singular corners; 0.45: into them), `n` points. A jump is a step between consecutive answers in which some joint
moves more than `--jump` (rad or m; default 0.1, ten times the path's own largest step at n = 1000),
or a point not solved within 0.1 mm / 0.1 deg. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json

import torch

from rbfn import load_solver

from .timing import machine_info

__all__ = ["path_joints", "jumps"]


def path_joints(low: torch.Tensor, high: torch.Tensor, n: int, reach: float = 0.25) -> torch.Tensor:
    """Joints (n, dof) of the straight line from mid - reach * width to mid + reach * width."""
    mid, width = 0.5 * (low + high), high - low
    s = torch.linspace(0.0, 1.0, n, dtype=torch.float64)[:, None]
    return mid - reach * width + 2 * reach * s * width


def jumps(q: torch.Tensor, ok: torch.Tensor, limit: float) -> int:
    """Steps (of n - 1) where a joint moves more than `limit`, or that end at an unsolved point."""
    step = (q[1:] - q[:-1]).abs().amax(-1)
    return int(((step > limit) | ~ok[1:]).sum())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m bench.ik_path", description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--reach", type=float, default=0.25)
    p.add_argument("--iterations", type=int, default=None, help="polish steps (default: the solver's)")
    p.add_argument("--jump", type=float, default=0.1)
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    solver = load_solver(a.checkpoint)
    robot = solver.robot
    truth = path_joints(solver.box_low, solver.box_high, a.n, a.reach)
    x = robot.targets(truth)
    alone, ok_alone = solver.solve(x, a.iterations)
    q = truth[:1].clone()  # the robot starts on the path
    near, ok_near = [], []
    for i in range(a.n):
        q, ok = solver.solve(x[i : i + 1], a.iterations, near=q)
        near.append(q[0])
        ok_near.append(ok[0])
    q_near, okn = torch.stack(near), torch.stack(ok_near)
    print(
        json.dumps(
            {
                "machine": machine_info("cpu", a.threads),
                "robot": robot.name,
                "n": a.n,
                "reach": a.reach,
                "iterations": a.iterations,
                "jump_rad": a.jump,
                "path_largest_step": float((truth[1:] - truth[:-1]).abs().max()),
                "jumps_with_near": jumps(q_near, okn, a.jump),
                "jumps_alone": jumps(alone, ok_alone, a.jump),
                "solved_with_near": float(okn.double().mean()),
                "solved_alone": float(ok_alone.double().mean()),
                "largest_step_with_near": float((q_near[1:] - q_near[:-1]).abs().max()),
                "largest_step_alone": float((alone[1:] - alone[:-1]).abs().max()),
            }
        )
    )


if __name__ == "__main__":
    main()
