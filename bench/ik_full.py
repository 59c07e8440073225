"""IK over the whole joint range with charts (`rbfn.charts`): train a charted network for a shipped
pose arm, then measure it on poses drawn over the whole URDF range, beside TRAC-IK and (for a 6R
arm eaik decomposes) the analytic solutions.

    python -m bench.ik_full [--robot ur5] [--charts 64] [--centers 300] [--method kmeans]
                            [--samples 3000] [--n 10000] [--tracik-n 1000] [--all-n 500]
                            [--repeats 3] [--threads 1] [--out DIR] [--set KEY=VALUE ...]

Training: `rbfn.charts.train_charts` with the train config of `--robot`, `robot.workspace=full`,
`robot.charts=--charts`, `robot.chart_centers=--centers`, `robot.chart_samples=--samples`,
`centers=--method`; `--out DIR` keeps the charted checkpoint (DIR/charts.pt,
which `python -m bench.tracik DIR/charts.pt` and `rbfn.load_solver` read). Test poses:
`rbfn.data.full_range_split`, evaluation stream of seed 0 (`--n` of them; the trained box's poses,
`rbfn.data.evaluation_split`, beside them). Rows, one thread, the machine quiet:

- raw: the best-ranked chart's answer (`IKSolver.network`), its median position and rotation error;
- polished: `IKSolver.solve` (the charts in turn, `CHARTED_ITERATIONS` steps an answer, no
  restarts) on the whole batch: success within 0.1 mm and 0.1 deg, solves per second (median of
  `--repeats`; on the whole range in turns with TRAC-IK, `ratio` the median of the turns' ratios of
  the rates: `bench.tracik.side_by_side`), answers outside the URDF limits;
- all: `IKSolver.solve_all` on `--all-n` poses: distinct solutions a pose; with eaik, the share of
  the analytic solutions (those within the URDF limits that our forward kinematics confirms, whole
  turns counted once) that `solve_all` found;
- TRAC-IK (`bench.tracik`, Speed mode, 20 ms) on the first `--tracik-n` of the whole-range poses.

Prints one JSON line per row.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from rbfn.charts import embed, save_charts, train_charts
from rbfn.data import evaluation_split, full_limits, full_range_split
from rbfn.robots.derive import derive_train
from rbfn.robots.robot import Robot, load_robot
from rbfn.solver import CHARTED_ERROR_DAMPING, CHARTED_ITERATIONS, IKSolver

from .polish import polish_row
from .timing import machine_info
from .tracik import side_by_side
from .tuning_time import composed

__all__ = ["analytic_solutions", "found_share", "main"]

SAME = 1e-2  # solutions this close in (cos q, sin q) count as one when matching ours to eaik's


def analytic_solutions(robot: Robot, x: torch.Tensor) -> list[torch.Tensor] | None:
    """eaik's solutions (k, n) for each pose of x (B, 7), those our forward kinematics confirms within
    0.1 mm and 0.1 deg and the URDF limits allow (a whole turn moved into them where it fits); None
    where eaik has no decomposition of the arm (or is not installed)."""
    try:
        from eaik.IK_URDF import UrdfRobot
    except ImportError:
        return None
    with tempfile.NamedTemporaryFile("w", suffix=".urdf") as f:
        f.write(robot.urdf_text)
        f.flush()
        arm = UrdfRobot(f.name)
    if robot.locked or not arm.hasKnownDecomposition():
        return None
    q0 = torch.zeros(1, len(robot.joint_names), dtype=torch.float64)
    offset = np.linalg.inv(robot.pose(q0)[0].numpy()) @ arm.fwdKin(q0[0].numpy())  # their tool frame in ours
    low, high = full_limits(robot)
    from pytorch_kinematics import transforms as tf

    poses = torch.eye(4, dtype=torch.float64).repeat(x.shape[0], 1, 1)
    poses[:, :3, :3], poses[:, :3, 3] = tf.quaternion_to_matrix(x[:, 3:7]), x[:, :3]
    out = []
    for i, pose in enumerate(poses.numpy()):
        q = torch.tensor(np.array(arm.IK(pose @ offset).Q), dtype=torch.float64).reshape(-1, len(low))
        q = q + 2 * math.pi * (q < low) - 2 * math.pi * (q > high)
        q = q[((q >= low) & (q <= high)).all(-1)]
        if q.shape[0]:
            pos, rot = robot.errors(q, x[i : i + 1].expand(q.shape[0], -1))
            q = q[(pos <= 0.1) & (rot <= 0.1)]
        out.append(q)
    return out


def found_share(ours: torch.Tensor, ok: torch.Tensor, theirs: list[torch.Tensor], revolute, low, high) -> float:
    """The share of the analytic solutions `theirs` (one (k, n) a pose) within `SAME` of one of ours
    (`solve_all`'s (B, K, n), converged (B, K))."""
    found = total = 0
    for b, q in enumerate(theirs):
        if not q.shape[0]:
            continue
        e_t = embed(q, revolute, low, high)
        e_o = embed(ours[b, ok[b]], revolute, low, high)
        total += q.shape[0]
        if e_o.shape[0]:
            found += int((torch.cdist(e_t, e_o).amin(1) < SAME).sum())
    return found / max(total, 1)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m bench.ik_full", description=__doc__.splitlines()[0])
    p.add_argument("--robot", default="ur5", help="the robot group (ur5, panda, urdf with --set robot.urdf=...)")
    p.add_argument("--charts", type=int, default=64)
    p.add_argument("--centers", type=int, default=300)
    p.add_argument("--method", default="kmeans", help="the centres' selector (centers=...)")
    p.add_argument("--samples", type=int, default=3000, help="training samples a chart, on average")
    p.add_argument("--n", type=int, default=10000)
    p.add_argument("--tracik-n", type=int, default=1000)
    p.add_argument("--all-n", type=int, default=500)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--set", action="append", default=[], help="another train override, e.g. robot.redundancy=J")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    over = [
        f"robot={a.robot}",
        "robot.workspace=full",
        f"robot.charts={a.charts}",
        f"robot.chart_centers={a.centers}",
        f"robot.chart_samples={a.samples}",
        f"centers={a.method}",
        *a.set,
    ]
    cfg = derive_train(composed("train", [*over, "progress=false"]))  # robot=urdf: its keys from the URDF
    robot = load_robot(cfg.robot)
    head = {"robot": a.robot, "charts": a.charts, "centers": a.centers, "selector": a.method, "threads": a.threads}
    t0 = time.perf_counter()
    charted = train_charts(cfg, robot)
    model, per_chart = charted.model, charted.seconds_a_chart
    print(json.dumps({**head, "train_seconds": time.perf_counter() - t0, "seconds_a_chart": per_chart}), flush=True)
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        save_charts(a.out / "charts.pt", model, robot.record(), {"overrides": over}, {})
    solver = IKSolver(model.double(), robot, error_damping=CHARTED_ERROR_DAMPING)
    test = full_range_split(robot, a.n, 0, evaluation=True)
    x, value = robot.split_inputs(test.x)
    q_raw, _ = solver.network(test.x)
    pos, rot = robot.errors(q_raw, x)
    raw = {"row": "raw", "pos_mm_median": float(pos.median()), "rot_deg_median": float(rot.median())}
    print(json.dumps({**head, **raw}))
    for name, split in (("whole joint range", test), ("trained box", evaluation_split(robot, a.n, 0))):
        xs, vs = robot.split_inputs(split.x)
        if split is test:  # beside TRAC-IK, in turns (`bench.tracik.side_by_side`)
            row, trac = side_by_side(solver, xs, a.tracik_n, 0.02, a.repeats, CHARTED_ITERATIONS, redundancy=vs)
        else:
            row = polish_row(solver, xs, CHARTED_ITERATIONS, repeats=a.repeats, redundancy=vs)
        q, _ = solver.solve(xs, redundancy=vs)
        outside = int((~((q >= solver.low) & (q <= solver.high)).all(-1)).sum())
        print(json.dumps({**head, "row": "polished", "poses": name, **row, "outside_limits": outside}), flush=True)
    k = a.all_n
    xa, va = x[:k], None if value is None else value[:k]
    t = time.perf_counter()
    qa, oka = solver.solve_all(xa, redundancy=va)
    row = {"row": "all", "poses": k, "seconds": time.perf_counter() - t, "distinct": float(oka.sum(1).double().mean())}
    theirs = analytic_solutions(robot, xa) if value is None else None
    if theirs is not None:
        row["analytic"] = sum(t.shape[0] for t in theirs) / k
        row["analytic_found"] = found_share(qa, oka, theirs, model.revolute, *full_limits(robot))
    print(json.dumps({**head, **row}), flush=True)
    print(json.dumps({**head, "row": "tracik", "poses": "whole joint range", **trac}), flush=True)
    print(json.dumps({"machine": machine_info("cpu", a.threads)}))


if __name__ == "__main__":
    main()
