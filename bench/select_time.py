"""Centre-selection time: ACO_R and the paper's Ant System against k-means, and where ACO's time goes.

    python bench/select_time.py [--n 2000] [--m 40] [--iterations 100] [--threads 1] [--device cpu]

Times (median of --repeats runs) the selection alone on the SCARA IK training set: `aco`
(ACO_R over centres and per-centre widths, fit objective), `aco_paper` (Ant System, paper
width rule, fit objective), the Ant System with the `cluster` objective, and scikit-learn
KMeans (k-means++, n_init = 10). Then profiles one ACO_R run with torch.profiler.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import torch


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--n", type=int, default=2000)
    p.add_argument("--m", type=int, default=40)
    p.add_argument("--iterations", type=int, default=100)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--device", default="cpu")
    a = p.parse_args()
    torch.set_num_threads(a.threads)

    from sklearn.cluster import KMeans

    from rbfn.config import CentersConfig
    from rbfn.data import input_scaling, make_dataset
    from rbfn.objectives import FitObjective
    from rbfn.robots import load_serial_chain, scara
    from rbfn.select import select

    chain = load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float64, a.device)
    low = torch.tensor([0.0, 0.3, 0.5], dtype=torch.float64)
    high = torch.tensor([2.0, 2.0, 1.5], dtype=torch.float64)
    data = make_dataset(chain, low, high, (a.n, a.n // 2, 10), seed=0)
    off, sc = input_scaling(data.train.x, "metres")
    obj = FitObjective((data.train.x - off) / sc, data.train.q, (data.val.x - off) / sc, data.val.q,
                       eval_dtype=torch.float32)

    def cfg(colony: str, objective: str, rule: str) -> CentersConfig:
        c = CentersConfig(method="aco", width_rule=rule)
        c.aco.colony, c.aco.objective, c.aco.iterations = colony, objective, a.iterations
        return c

    cases = {
        "aco (ACO_R, fit, centres + widths)": lambda: select(cfg("acor", "fit", "per_center"), obj, a.m, 0, 2.0),
        "aco_paper (Ant System, fit, paper widths)": lambda: select(cfg("ant_system", "fit", "paper"), obj, a.m, 0, 2.0),
        "Ant System, cluster objective": lambda: select(cfg("ant_system", "cluster", "paper"), obj, a.m, 0, 2.0),
        "sklearn KMeans (k-means++, n_init=10)": lambda: KMeans(a.m, n_init=10, random_state=0).fit(
            obj.z_train.cpu().numpy()),
    }
    print(f"# selection time, N = {a.n}, M = {a.m}, {a.iterations} iterations, 20 ants; torch "
          f"{torch.__version__}, {a.threads} thread(s), device {a.device}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}")
    print("| method | median s | runs |\n|---|---|---|")
    for name, fn in cases.items():
        ts = []
        for _ in range(a.repeats):
            t = time.perf_counter()
            fn()
            if a.device.startswith("cuda"):
                torch.cuda.synchronize()
            ts.append(time.perf_counter() - t)
        print(f"| {name} | {statistics.median(ts):.3f} | {', '.join(f'{t:.3f}' for t in ts)} |")

    from torch.profiler import ProfilerActivity, profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if a.device.startswith("cuda") else [])
    with profile(activities=acts) as prof:
        cases["aco (ACO_R, fit, centres + widths)"]()
    print("\n# where ACO_R's time goes (torch.profiler, self time)")
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=12))


if __name__ == "__main__":
    main()
