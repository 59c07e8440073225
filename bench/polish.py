"""Exact IK throughput: `rbfn.load_solver(...).solve` (the network's answer polished by damped
least squares) against pytorch-kinematics' `PseudoInverseIK` (random restarts), on the same
poses of a trained checkpoint's robot, one thread, each with its success rate (share of targets
reached within 0.1 mm and 0.1 deg).

    python -m bench.polish CHECKPOINT [--n 10000] [--iterations 3] [--restarts 0] [--pk-n 500] [--retries 10]

The targets are FK images of joints drawn in the checkpoint's trained box (the evaluation stream
of seed 0). PseudoInverseIK samples its restarts in the same box (its joint limits), so both
solve the same problem in the same branch; it is slow, so it runs on fewer targets (`--pk-n`)
and its rate is per target. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math

import pytorch_kinematics as pk
import torch

from rbfn import load_solver
from rbfn.data import evaluation_split

from .timing import machine_info, median_seconds, timed

__all__ = ["rate_row", "polish_row", "polish_method", "pk_row"]


def rate_row(method: str, n: int, seconds: float, ok: torch.Tensor) -> dict:
    """A benchmark row: `method` solved n targets in `seconds`, `ok` (n,) where it reached them."""
    return {
        "method": method,
        "n": n,
        "seconds": seconds,
        "queries_per_s": n / seconds,
        "success": float(ok.double().mean()),
    }


def polish_row(solver, x: torch.Tensor, iterations: int | None, restarts: int = 0, repeats: int = 5, **solve) -> dict:
    """Queries/s and success of `solver.solve(x, iterations, restarts, **solve)` (median of
    `repeats` runs; `solve`: its other keywords, e.g. a redundant joint's `redundancy`)."""
    t, _ = median_seconds(lambda: solver.solve(x, iterations, restarts, **solve), repeats, str(x.device))
    _, ok = solver.solve(x, iterations, restarts, **solve)
    return rate_row(polish_method(solver, iterations, restarts), x.shape[0], t, ok)


def polish_method(solver, iterations: int | None, restarts: int = 0) -> str:
    """A row's `method` for `solver.solve(x, iterations, restarts)`."""
    more = f", up to {restarts} restarts of the rest" if restarts else ""
    steps = iterations if iterations is not None else solver.default_iterations
    return f"network + {steps} polish steps{more}"


def pk_row(solver, x: torch.Tensor, retries: int, max_iterations: int = 50) -> dict:
    """Queries/s and success of pytorch-kinematics' PseudoInverseIK with `retries` restarts."""
    robot = solver.robot
    if robot.locked:
        raise ValueError("PseudoInverseIK solves for every chain joint; this robot holds joints fixed")
    limits = torch.stack([robot.low, robot.high], -1)
    ik = pk.PseudoInverseIK(
        robot.chain,
        num_retries=retries,
        joint_limits=limits,
        max_iterations=max_iterations,
        pos_tolerance=1e-4,
        rot_tolerance=math.radians(0.1),
        orientation_weight=1.0 if solver.pose_target else 0.0,
        early_stopping_any_converged=True,
    )
    if solver.pose_target:
        from pytorch_kinematics import transforms as tf

        goal = pk.Transform3d(pos=x[:, :3], rot=tf.quaternion_to_matrix(x[:, 3:]), dtype=x.dtype)
    else:
        goal = pk.Transform3d(pos=x[:, :3], dtype=x.dtype)
    torch.manual_seed(0)
    out = []
    t = timed(lambda: out.append(ik.solve(goal)))  # one run: it is slow
    sol = out[0]
    # Each target's best restart by our own error measure, so both rows are scored alike.
    n, r, dof = sol.solutions.shape
    q = sol.solutions.reshape(n * r, dof)
    pos, rot = robot.errors(q, x.repeat_interleave(r, 0))
    score = pos / 0.1 + (rot / 0.1 if rot is not None else 0.0)
    best = score.reshape(n, r).argmin(-1)
    ok = (pos.reshape(n, r) <= 0.1) & ((rot.reshape(n, r) <= 0.1) if rot is not None else True)
    method = f"pytorch-kinematics PseudoInverseIK ({retries} restarts, {max_iterations} iterations)"
    return rate_row(method, n, t, ok.gather(1, best[:, None]))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m bench.polish", description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--n", type=int, default=10_000)
    p.add_argument("--iterations", type=int, default=3)
    p.add_argument("--restarts", type=int, default=0)
    p.add_argument("--pk-n", type=int, default=500)
    p.add_argument("--retries", type=int, default=10)
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    solver = load_solver(a.checkpoint)
    x = evaluation_split(solver.robot, a.n, seed=0).x
    rows = [polish_row(solver, x, a.iterations, a.restarts), pk_row(solver, x[: a.pk_n], a.retries)]
    print(
        json.dumps(
            {
                "machine": machine_info("cpu", a.threads),
                "rows": rows,
                "speedup": rows[0]["queries_per_s"] / rows[1]["queries_per_s"],
            }
        )
    )


if __name__ == "__main__":
    main()
