"""A prototype toward IK over the whole joint range: one network per chart of the joint torus, the
best charts' answers polished, on a shipped pose arm. Not a feature of the package: it measures
how many charts, and how many of their answers, the whole workspace needs.

    python -m bench.ik_charts [--robot ur5] [--charts 64] [--centers 300] [--samples 3000]
                              [--band 0] [--test 2000] [--steps 5] [--threads 1]

Training joints are drawn uniformly over one turn of every free joint ([-pi, pi]; with `--band B` >
0 the first joint only over [-B/2, B/2], what turning targets about the base would reduce it to,
and the test poses' first joint likewise). The charts are k-means clusters
(`rbfn.centers.kmeans_centers`) of the joints' (cos q, sin q); each chart's network
(`rbfn.pipeline.train_ik`, k-means centres, `--centers` of them) learns the poses of the samples
within 1.15 times their nearest chart's distance, its joints unwrapped around the chart's centre. A
test pose is answered by every chart; the answers are ranked by their forward-kinematics error and
the best 1, 2 and 4 are polished `--steps` steps (`IKSolver`, `error_damping=0.01`, the joints
within the URDF limits); a pose counts as solved where any of them reaches it within 0.1 mm and 0.1
deg. Test poses: `rbfn.data.full_range_split`, evaluation stream of seed 0. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import torch

from rbfn.centers import kmeans_centers
from rbfn.data import Dataset, Split, full_range_split
from rbfn.pipeline import train_ik
from rbfn.robots.kinematics import joint_limits
from rbfn.robots.robot import load_robot
from rbfn.solver import IKSolver

from .timing import machine_info
from .tuning_time import composed

__all__ = ["wrapped", "main"]

OVERLAP = 1.15  # a sample trains every chart within this factor of its nearest chart's distance


def wrapped(q: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """Angles q (..., n) moved by whole turns to within pi of `centre` (n,)."""
    return centre + torch.remainder(q - centre + math.pi, 2 * math.pi) - math.pi


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m bench.ik_charts", description=__doc__.splitlines()[0])
    p.add_argument("--robot", default="ur5", choices=["ur5", "panda"])
    p.add_argument("--charts", type=int, default=64)
    p.add_argument("--centers", type=int, default=300)
    p.add_argument("--samples", type=int, default=3000, help="training samples a chart, on average")
    p.add_argument("--band", type=float, default=0.0, help="rad: the first joint's range (0: a whole turn)")
    p.add_argument("--test", type=int, default=2000)
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--threads", type=int, default=1)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    cfg = composed(
        "train",
        [
            f"robot={a.robot}",
            "centers=kmeans",
            f"rbfn.num_centers={a.centers}",
            "rbfn.growth.start=0",
            "progress=false",
        ],
    )
    robot = load_robot(cfg.robot)
    n = len(robot.joint_names)
    g = torch.Generator().manual_seed(0)
    q = (2 * torch.rand(a.charts * a.samples, n, generator=g, dtype=torch.float64) - 1) * math.pi
    if a.band > 0:
        q[:, 0] *= 0.5 * a.band / math.pi
    t0 = time.perf_counter()
    feats = torch.cat([q.cos(), q.sin()], -1)
    centres = kmeans_centers(feats[:50000], a.charts, seed=0, restarts=3)
    angles = torch.atan2(centres[:, n:], centres[:, :n])  # (K, n) the charts' centres as angles
    dist = torch.cdist(feats, centres)
    nearest = dist.min(1).values
    x = robot.inputs(q)
    nets = []
    for k in range(a.charts):
        mine = (dist[:, k] <= OVERLAP * nearest).nonzero().squeeze(-1)
        qk, xk = wrapped(q[mine], angles[k]), x[mine]
        v = qk.shape[0] // 6
        nets.append(train_ik(cfg, Dataset(Split(xk[v:], qk[v:]), Split(xk[:v], qk[:v]), Split(xk[:v], qk[:v]))).model)
    train_s = time.perf_counter() - t0
    low, high = (t[robot.free] for t in joint_limits(robot.chain))
    robot.low, robot.high = low.clone(), high.clone()  # the polish ranges over the URDF limits
    solver = IKSolver(nets[0], robot, base_yaw=False, margin=0.0, error_damping=0.01)
    test = full_range_split(robot, a.test, 0, evaluation=True)
    if a.band > 0:
        tq = test.q.clone()
        tq[:, 0] = wrapped(tq[:, 0], torch.zeros(())) * 0.5 * a.band / math.pi
        test = Split(robot.inputs(tq), tq)
    with torch.no_grad():
        seeds = torch.stack([net(test.x).clamp(low, high) for net in nets])  # (K, B, n)
    cost = solver._cost(seeds.reshape(-1, n), test.x.repeat(a.charts, 1)).reshape(a.charts, -1)
    order = cost.argsort(0)
    rows = torch.arange(a.test)
    solved = torch.zeros(a.test, dtype=torch.bool)
    out = {"robot": a.robot, "charts": a.charts, "centers": a.centers, "samples": a.samples, "band": a.band,
           "test": a.test, "steps": a.steps, "train_seconds": round(train_s, 1)}  # fmt: skip
    for j in range(min(4, a.charts)):
        solved |= solver._polish(seeds[order[j], rows], test.x, a.steps)[1]
        if j in (0, 1, 3):
            out[f"solved_best_{j + 1}"] = float(solved.double().mean())
    print(json.dumps({**out, "machine": machine_info("cpu", a.threads)}))


if __name__ == "__main__":
    main()
