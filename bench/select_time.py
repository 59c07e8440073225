"""Centre-selection time: ACO (ACO_R, and the paper's Ant System) at the paper's NC_max = 100
against scikit-learn KMeans (k-means++, n_init = 10), on the SCARA IK training set.

    python -m bench.select_time [--n 10000] [--m 40] [--iterations 100] [--threads 1] [--repeats 3]

`aco` is ACO_R over centres and per-centre widths on the validation fit objective (seeded by
k-means), `aco_paper` the Ant System over 500 candidate points with the paper's width rule, both
with 20 ants. The colony reports after every iteration (`on_state`), which times each one: a
run's time is its set-up (k-means seed, first archive, candidate pool) plus its iterations. Where
a full run would take longer than the caller allows, the time of 100 iterations is extrapolated
from a short probe run (set-up + 100 x the median iteration) and marked so. The command times
KMeans and each colony in interleaved rounds, torch and every other thread pool (scikit-learn's
OpenMP, BLAS) on `--threads` threads (set here, and reported in every row), and reports medians.
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from rbfn.config import CentersConfig, RobotConfig
from rbfn.data import input_scaling, make_dataset
from rbfn.objectives import FitObjective
from rbfn.robots.robot import load_robot
from rbfn.select import select

from .timing import machine_info, median_seconds, sync

__all__ = [
    "COLONIES",
    "selection_objective",
    "aco_config",
    "time_aco",
    "time_kmeans",
    "select_rows",
    "ratio_rows",
    "main",
]

COLONIES = {"aco": ("acor", "per_center"), "aco_paper": ("ant_system", "paper")}  # colony, width rule
NC_MAX = 100


def selection_objective(n: int, device: str = "cpu", seed: int = 0) -> FitObjective:
    """The fit objective on N training pairs (N / 2 validation pairs), inputs centred in metres."""
    data = make_dataset(load_robot(RobotConfig()), (n, n // 2, 10), seed=seed)
    off, sc = input_scaling(data.train.x, "metres")
    tr, val = data.train.to(device=device), data.val.to(device=device)
    off, sc = off.to(device), sc.to(device)
    return FitObjective((tr.x - off) / sc, tr.q, (val.x - off) / sc, val.q, eval_dtype=torch.float32)


def aco_config(name: str, iterations: int = NC_MAX) -> CentersConfig:
    """The `centers=aco` or `centers=aco_paper` selection with `iterations` (NC_max)."""
    colony, rule = COLONIES[name]
    c = CentersConfig(name=name, method="aco", width_rule=rule)
    c.aco.colony, c.aco.objective, c.aco.iterations = colony, "fit", iterations
    return c


def time_aco(objective: FitObjective, name: str, m: int, iterations: int, device: str = "cpu") -> dict:
    """One selection run; its wall seconds, set-up seconds and per-iteration seconds."""
    stamps: list[float] = []

    def on_state(_state: dict) -> None:
        sync(device)
        stamps.append(time.perf_counter())

    sync(device)
    t0 = time.perf_counter()
    select(aco_config(name, iterations), objective, m, seed=0, max_width=2.0, on_state=on_state)
    sync(device)
    total = time.perf_counter() - t0
    iters = [b - a for a, b in itertools.pairwise(stamps)]
    per_iter = statistics.median(iters) if iters else (stamps[0] - t0 if stamps else total)
    setup = (stamps[0] - t0 - per_iter) if stamps else total
    return {"seconds": total, "setup_s": max(setup, 0.0), "per_iter_s": per_iter, "iterations": len(stamps)}


def time_kmeans(objective: FitObjective, m: int, repeats: int) -> float:
    """Median seconds of scikit-learn KMeans(m, n_init=10) on the training inputs."""
    from sklearn.cluster import KMeans

    z = objective.z_train.cpu().numpy()
    return median_seconds(lambda: KMeans(m, n_init=10, random_state=0).fit(z), repeats, warmup=0)[0]


def select_rows(
    ns=(2000, 10000, 50000),
    ms=(40, 160),
    device: str = "cpu",
    max_full_s: float = 20.0,
    always_full=((10000, 40),),
    probe: int = 2,
    repeats: int = 3,
    on_row: Callable[[list[dict]], None] | None = None,
) -> list[dict]:
    """Rows (N, M, method): seconds for NC_max = 100 (measured, or extrapolated from a `probe`-
    iteration run when a full run is predicted above `max_full_s`, except (N, M) in
    `always_full`), iterations run, and the ratio to KMeans on the same data. `on_row(rows)`
    sees the rows so far after each one."""
    rows = []
    for n in ns:
        obj = selection_objective(n, device)
        for m in ms:
            km = time_kmeans(obj, m, repeats)
            rows.append(
                {
                    "N": n,
                    "M": m,
                    "method": "sklearn KMeans (n_init = 10)",
                    "device": "cpu",
                    "seconds": km,
                    "iterations": None,
                    "how": f"median of {repeats}",
                    "x_kmeans": 1.0,
                }
            )
            for name in COLONIES:
                p = time_aco(obj, name, m, probe, device)
                predicted = p["setup_s"] + NC_MAX * p["per_iter_s"]
                if predicted <= max_full_s or (n, m) in always_full:
                    reps = repeats if predicted * repeats <= max_full_s else 1
                    runs = [time_aco(obj, name, m, NC_MAX, device) for _ in range(reps)]
                    secs = statistics.median(r["seconds"] for r in runs)
                    its, how = runs[0]["iterations"], f"median of {reps}"
                    per_iter = statistics.median(r["per_iter_s"] for r in runs)
                else:
                    secs, its, per_iter = predicted, NC_MAX, p["per_iter_s"]
                    how = f"extrapolated: set-up {p['setup_s']:.2f} s + 100 x {p['per_iter_s']:.3f} s/iteration"
                rows.append(
                    {
                        "N": n,
                        "M": m,
                        "method": f"{name} ({COLONIES[name][0]}, NC_max = 100)",
                        "device": device,
                        "seconds": secs,
                        "iterations": its,
                        "how": how,
                        "per_iter_s": per_iter,
                        "predicted_s": predicted,
                        "x_kmeans": secs / km,
                    }
                )
                if on_row is not None:
                    on_row(rows)
    return rows


def ratio_rows(
    n: int = 10000, m: int = 40, iterations: int = NC_MAX, names=tuple(COLONIES), device: str = "cpu", repeats: int = 3
) -> list[dict]:
    """Rows (one per colony): KMeans' and the colony's median seconds at (N, M) over `repeats`
    interleaved rounds (KMeans a median of 3 in each), the colony's set-up and per-iteration
    seconds, and the median of the rounds' ratios colony / KMeans."""
    obj = selection_objective(n, device)
    time_aco(obj, names[0], m, 2, device)  # warm-up
    rows = []
    for name in names:
        rounds = [(time_kmeans(obj, m, 3), time_aco(obj, name, m, iterations, device)) for _ in range(repeats)]
        runs = {key: statistics.median(r[key] for _, r in rounds) for key in ("seconds", "setup_s", "per_iter_s")}
        rows.append(
            {
                "N": n,
                "M": m,
                "method": f"{name} ({COLONIES[name][0]})",
                "device": device,
                "threads": torch.get_num_threads(),
                "iterations": rounds[0][1]["iterations"],
                "kmeans_s": statistics.median(km for km, _ in rounds),
                **runs,
                "x_kmeans": statistics.median(r["seconds"] / km for km, r in rounds),
                "how": f"median of {repeats} interleaved rounds",
            }
        )
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(prog="python -m bench.select_time", description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=10000, help="training pairs N (N / 2 validation pairs; default 10000)")
    p.add_argument("--m", type=int, default=40, help="centres M (default 40)")
    p.add_argument("--iterations", type=int, default=NC_MAX, help=f"NC_max (default {NC_MAX})")
    p.add_argument("--colonies", default=",".join(COLONIES), help="comma-separated subset of " + ", ".join(COLONIES))
    p.add_argument("--threads", type=int, default=1, help="torch and other thread pools (default 1)")
    p.add_argument("--repeats", type=int, default=3, help="interleaved rounds (medians are reported)")
    p.add_argument("--device", default="cpu", help="the colony's device, cpu or cuda (KMeans runs on CPU)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows and the machine to this file")
    a = p.parse_args(argv)
    names = tuple(a.colonies.split(","))
    if a.threads < 1:
        p.error(f"--threads {a.threads} must be >= 1")
    if not set(names) <= set(COLONIES):
        p.error(f"--colonies {a.colonies}: choose from {', '.join(COLONIES)}")
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(a.threads)
    with threadpool_limits(a.threads):
        rows = ratio_rows(a.n, a.m, a.iterations, names, a.device, a.repeats)
    info = machine_info(a.device, a.threads)
    print(
        f"Selection at N = {a.n}, M = {a.m}, {a.iterations} iterations, {info['threads']} thread(s), "
        f"{info['cpu']} (load {info['load_average_1min']}), median of {a.repeats} rounds:"
    )
    for r in rows:
        print(
            f"  {r['method']:22s} {r['seconds']:8.2f} s (set-up {r['setup_s']:.2f} s + {r['iterations']} x "
            f"{r['per_iter_s'] * 1e3:.1f} ms)  KMeans {r['kmeans_s']:.3f} s  {r['x_kmeans']:6.1f}x KMeans"
        )
    if a.json:
        a.json.write_text(json.dumps({"machine": info, "rows": rows}, indent=1))
    return rows


if __name__ == "__main__":
    main()
