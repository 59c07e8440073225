"""The IK side by side with TRAC-IK: a checkpoint's network plus its polish (`rbfn.load_solver`)
against TRAC-IK (`pytracik`, KDL's chain from the same URDF text, one pose at a time), on the same
poses, one thread, each with its success rate (within 0.1 mm and 0.1 deg, checked by the same
forward kinematics) and its solves per second. Two pose sets: FK images of joints drawn in the
checkpoint's trained box, and of joints drawn over the free joints' whole URDF range
(`rbfn.data.full_range_split`, evaluation stream of seed 0), where every branch occurs.

    python -m bench.tracik CHECKPOINT [--n 10000] [--iterations K] [--restarts R] [--tracik-n 1000] [--timeout 0.02]
                          [--device cuda]   # our solver on a GPU, TRAC-IK on the CPU

TRAC-IK runs in its Speed mode (its first solution within `--timeout` s, wall time, so the
machine must be quiet), seeded with the middle of the joint limits; held joints (`robot.locked`)
are held by limits equal to their value. A redundant network (`robot.redundancy`) is given the
sampled joint's value, as a caller passing `near` would. Our solver runs the whole batch at once
(`--n` targets); TRAC-IK solves `--tracik-n` of them one at a time (our row's
`success_on_tracik_poses`: ours on those same poses). The two take turns, `--repeats` turns each
(`side_by_side`): the ratio of the rates is the median of the turns' ratios, so a change in the
machine's load between the two does not move it. Prints one JSON line per row, and the table.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import numpy as np
import torch

from rbfn import load_solver
from rbfn.data import evaluation_split, full_range_split
from rbfn.robots.kinematics import joint_limits

from .polish import polish_method, rate_row
from .timing import machine_info, timed

__all__ = ["tracik_solver", "tracik_row", "side_by_side", "main"]

_TRACIK = "TRAC-IK (Speed, {:g} ms timeout)"  # its rows' `method`, of the timeout in ms


def tracik_solver(robot, timeout: float):
    """pytracik's TRAC_IK for `robot`'s chain (its URDF text, root link -> end link), Speed mode,
    within the URDF limits as our chain reads them (pytracik reads some URDFs' limits as zero,
    which would hold every joint; +-2 pi for a joint without limits), held joints held by their
    limits."""
    import pytracik

    root = robot.chain.get_frame_names(exclude_fixed=False)[0]
    solver = pytracik.TRAC_IK(root, robot.end_link, robot.urdf_text, timeout, 1e-5, pytracik.SolveType.Speed)
    names = robot.chain.get_joint_parameter_names()
    if pytracik.get_num_joints(solver) != len(names):
        raise ValueError(
            f"TRAC-IK reads {pytracik.get_num_joints(solver)} joints from the URDF, the chain has {len(names)}"
        )
    low, high = (t.cpu().tolist() for t in joint_limits(robot.chain))
    low = [max(v, -2 * math.pi) for v in low]
    high = [min(v, 2 * math.pi) for v in high]
    for j, v in robot.locked.items():
        low[names.index(j)] = high[names.index(j)] = float(v)
    pytracik.set_joint_limits(solver, low, high)
    return solver, np.array(low), np.array(high)


def _tracik_run(robot, x: torch.Tensor, timeout: float):
    """A call that solves targets x (B, 7) (poses) with TRAC-IK one at a time, seeded with the middle
    of the limits: (wall seconds, reached (B,) bool, within 0.1 mm and 0.1 deg by our forward
    kinematics)."""
    import pytracik

    solver, low, high = tracik_solver(robot, timeout)
    seed = np.where(np.isfinite(low + high), 0.5 * (low + high), 0.0)
    poses = x[:, :7].cpu().numpy()

    def run() -> tuple[float, torch.Tensor]:
        answers = np.zeros((poses.shape[0], len(low)))
        t0 = time.perf_counter()
        for i, p in enumerate(poses):  # x, y, z, then the quaternion as (x, y, z, w)
            out = np.asarray(pytracik.ik(solver, seed, p[0], p[1], p[2], p[4], p[5], p[6], p[3]))
            answers[i] = out[1:] if out[0] > 0 else np.nan
        seconds = time.perf_counter() - t0
        q = torch.from_numpy(answers).to(x.device)[:, robot.free]
        found = ~torch.isnan(q).any(-1)
        pos, rot = robot.errors(torch.nan_to_num(q), x)
        return seconds, found & (pos <= 0.1) & (rot <= 0.1)

    return run


def tracik_row(robot, x: torch.Tensor, timeout: float) -> dict:
    """Solves/s and success of TRAC-IK on targets x (B, 7) (poses), one at a time."""
    seconds, ok = _tracik_run(robot, x, timeout)()
    return rate_row(_TRACIK.format(1000 * timeout), x.shape[0], seconds, ok)


def side_by_side(
    solver,
    x: torch.Tensor,
    m: int,
    timeout: float,
    repeats: int,
    iterations: int | None = None,
    restarts: int = 0,
    redundancy: torch.Tensor | None = None,
    device: str = "cpu",
) -> tuple[dict, dict]:
    """(our row, TRAC-IK's row) on poses x (B, 7): `solver.solve(x, iterations, restarts,
    redundancy=...)` on the whole batch and TRAC-IK one at a time on the first m, timed in turn
    `repeats` times after one untimed solve of ours. On a machine shared with other jobs the load
    changes from second to second; a turn's ratio of the two rates sees one load. Our row's `ratio`
    is the median of the turns' ratios (`ratio_runs`: each turn's), each row's `queries_per_s` the
    median of its turns'; TRAC-IK's `success` is that of its median turn (its timeout is wall time;
    `success_runs`: each turn's), our `success_on_tracik_poses` ours on its m poses."""
    if not 1 <= m <= x.shape[0] or repeats < 1:
        raise ValueError(f"m={m} and repeats={repeats}: use 1 <= m <= {x.shape[0]} (the poses) and repeats >= 1")
    theirs = _tracik_run(solver.robot, x[:m], timeout)
    ours = lambda: solver.solve(x, iterations, restarts, redundancy=redundancy)  # noqa: E731
    ok = ours()[1]
    turns = [(timed(ours, device), *theirs()) for _ in range(repeats)]
    ratios = [(x.shape[0] / t) / (m / s) for t, s, _ in turns]
    row = rate_row(
        polish_method(solver, iterations, restarts), x.shape[0], statistics.median(t for t, _, _ in turns), ok
    )
    row.update(
        ratio=statistics.median(ratios), ratio_runs=ratios, success_on_tracik_poses=float(ok[:m].double().mean())
    )
    mid = sorted(range(repeats), key=lambda i: turns[i][1])[(repeats - 1) // 2]
    trac = rate_row(_TRACIK.format(1000 * timeout), m, turns[mid][1], turns[mid][2])
    trac["success_runs"] = [float(o.double().mean()) for _, _, o in turns]
    return row, trac


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("--n", type=int, default=10000, help="targets our solver takes in one batch")
    p.add_argument("--iterations", type=int, default=None, help="polish steps (default: the solver's)")
    p.add_argument("--restarts", type=int, default=0, help="rounds of random restarts for the targets left (solve's)")
    p.add_argument("--tracik-n", type=int, default=1000, help="of them, solved one at a time by TRAC-IK")
    p.add_argument("--timeout", type=float, default=0.02, help="TRAC-IK's wall-time limit a pose, s")
    p.add_argument("--repeats", type=int, default=5, help="turns of the two solvers")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--device", default="cpu", help="where our solver runs (TRAC-IK runs on the CPU)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    solver = load_solver(args.checkpoint, device=args.device)
    robot = solver.robot
    if robot.target != "pose":
        raise SystemExit("bench.tracik compares pose IK: this checkpoint's targets are positions")
    print(json.dumps({"machine": machine_info(args.device, args.threads)}))
    rows = []
    for name, split in (
        ("trained box", evaluation_split(robot, args.n, 0)),
        ("whole joint range", full_range_split(robot, args.n, 0, evaluation=True)),
    ):
        x, value = robot.split_inputs(split.x)
        ours, theirs = side_by_side(
            solver, x, args.tracik_n, args.timeout, args.repeats, args.iterations, args.restarts, value, args.device
        )
        for row in (ours, theirs):
            row.update(poses=name, threads=args.threads, device=args.device if row is ours else "cpu")
            rows.append(row)
            print(json.dumps(row), flush=True)
        runs = ", ".join(f"{r:.2f}" for r in ours["ratio_runs"])
        print(f"# {name}: {ours['ratio']:.2f}x TRAC-IK's solves/s (median of the turns' ratios: {runs})")
    print(f"\n{'poses':18s} {'method':42s} {'success':>9s} {'solves/s':>10s}")
    for r in rows:
        print(f"{r['poses']:18s} {r['method']:42s} {100 * r['success']:8.2f}% {r['queries_per_s']:10.0f}")


if __name__ == "__main__":
    main()
