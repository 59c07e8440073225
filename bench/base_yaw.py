"""The whole base rotation: a trained checkpoint's targets with the first joint anywhere in
[-pi, pi] (the other joints in the trained box) against the same targets inside the box, raw
(the network's answer) and polished (`IKSolver.solve`, no restarts), with the base turn
(`rbfn.yaw`, the default where the arm allows it) and without it (the network as trained).

    python -m bench.base_yaw CHECKPOINT [--n 10000] [--iterations 3] [--threads 1]

The box's targets are the evaluation stream of seed 0 (as `bench.polish`); the turned ones are the
same joints with the first joint redrawn uniformly in [-pi, pi] (seeded). Raw errors are medians
and 95th percentiles (mm, deg); success is the share within 0.1 mm and 0.1 deg. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math

import torch

from rbfn import load_solver
from rbfn.data import evaluation_split

from .timing import machine_info

__all__ = ["turned_targets", "row"]


def turned_targets(robot, q: torch.Tensor, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """(joints (B, n) with the first redrawn in [-pi, pi], their targets)."""
    g = torch.Generator().manual_seed(seed)
    q = q.clone()
    q[:, 0] = (2 * torch.rand(q.shape[0], generator=g, dtype=torch.float64) - 1) * math.pi
    return q, robot.targets(q)


def row(solver, x: torch.Tensor, iterations: int, label: str) -> dict:
    """Raw and polished accuracy of `solver` on targets x."""
    q_raw, _ = solver.network(x)
    pos, rot = solver.robot.errors(q_raw, x)
    _, ok = solver.solve(x, iterations)
    out = {
        "targets": label,
        "base_yaw": solver.yaw is not None,
        "n": x.shape[0],
        "raw_pos_mm_median": float(pos.median()),
        "raw_pos_mm_p95": float(pos.quantile(0.95)),
        "polished_success": float(ok.double().mean()),
    }
    if rot is not None:
        out.update(raw_rot_deg_median=float(rot.median()), raw_rot_deg_p95=float(rot.quantile(0.95)))
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m bench.base_yaw", description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--n", type=int, default=10_000)
    p.add_argument("--iterations", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    solver = load_solver(a.checkpoint)
    if solver.yaw is None:
        raise SystemExit(f"{a.checkpoint}: the robot's first joint does not turn about the base's vertical axis")
    plain = load_solver(a.checkpoint, base_yaw=False)
    box = evaluation_split(solver.robot, a.n, seed=0)
    _, x_turned = turned_targets(solver.robot, box.q)
    rows = [
        row(s, x, a.iterations, label)
        for s in (solver, plain)
        for x, label in ((box.x, "box"), (x_turned, "first joint in [-pi, pi]"))
    ]
    print(json.dumps({"machine": machine_info("cpu", a.threads), "robot": solver.robot.name, "rows": rows}))


if __name__ == "__main__":
    main()
