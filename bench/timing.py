"""Timing helpers shared by the suite's sections: medians of repeated runs, GPU-synchronised,
the machine's description, and log-log exponent fits."""

from __future__ import annotations

import math
import os
import platform
import statistics
import time
from collections.abc import Callable

import torch

__all__ = ["sync", "timed", "median_seconds", "interleaved_medians", "machine_info", "fit_exponent", "profile_table"]


def sync(device: str) -> None:
    """Wait for queued GPU work, so a wall-clock reading covers it."""
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()


def timed(fn: Callable[[], object], device: str = "cpu") -> float:
    """Wall seconds of one call of fn, GPU work included."""
    sync(device)
    t = time.perf_counter()
    fn()
    sync(device)
    return time.perf_counter() - t


def median_seconds(
    fn: Callable[[], object], repeats: int = 5, device: str = "cpu", warmup: int = 1
) -> tuple[float, list[float]]:
    """(median, all) wall seconds of `repeats` calls of fn after `warmup` untimed calls."""
    for _ in range(warmup):
        fn()
    ts = [timed(fn, device) for _ in range(repeats)]
    return statistics.median(ts), ts


def interleaved_medians(
    fns: dict[str, Callable[[], object]], repeats: int = 5, device: str = "cpu", warmup: int = 1
) -> dict[str, float]:
    """Median wall seconds of each fn over `repeats` rounds that call every fn once in turn, after
    `warmup` untimed rounds: on a machine shared with other jobs, the load changes during the
    measurement, and taking the methods turn by turn lets their ratios see the same load."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    ts = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            ts[k].append(timed(fn, device))
    return {k: statistics.median(v) for k, v in ts.items()}


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info(device: str, threads: int) -> dict:
    """Platform, CPU model, core counts (all, and usable by this process), torch, threads, device."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    info = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu": _cpu_model(),
        "nproc": os.cpu_count(),
        "usable_cpus": usable,
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "threads_requested": threads,
        "device": device,
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    if str(device).startswith("cuda"):
        info["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return info


def fit_exponent(x: list[float], t: list[float]) -> float:
    """Slope p of the least-squares line log t = p log x + c (time ~ x^p)."""
    lx, lt = [math.log(v) for v in x], [math.log(v) for v in t]
    mx, mt = sum(lx) / len(lx), sum(lt) / len(lt)
    var = sum((a - mx) ** 2 for a in lx)
    return sum((a - mx) * (b - mt) for a, b in zip(lx, lt)) / var if var > 0 else float("nan")


def profile_table(fn: Callable[[], object], device: str = "cpu", rows: int = 12) -> str:
    """torch.profiler's table of one call of fn: the top ops by self CPU time."""
    from torch.profiler import ProfilerActivity, profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if str(device).startswith("cuda") else [])
    with profile(activities=acts) as prof:
        fn()
        sync(device)
    return prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=rows)
