"""Memory a setting needs, estimated before any work, against what the machine has.

Sizes that cannot fit (`data.n_train=1000000000`, `control.duration=1e12`, `n_test=1000000000`)
fail at once with the key, the estimate and the limit, instead of dying in the allocator after
minutes of work, or grinding through swap. The estimates are lower bounds: the arrays a run
certainly holds at once (float64 data, the least-squares design matrix, recorded trajectories),
so a setting that is refused cannot fit, and a setting that fits is never refused. The limit is
the memory available now (Linux: MemAvailable, or the cgroup's limit where smaller; elsewhere the
physical memory), or on CUDA the device's free memory.

`check_train` and `check_evaluate` hold a checked configuration (`rbfn.config`) against it;
`check_fits` is the rule itself.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

from .config import PILOT_STRIDE, Colony, Method, Objective, Target, network_method

if TYPE_CHECKING:
    from .config import ACOConfig, EvalConfig, TrainConfig

__all__ = ["available_bytes", "check_fits", "check_train", "check_evaluate", "colony_fits", "size_text", "FLOAT64"]

FLOAT64 = 8  # bytes


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_available() -> int | None:
    """The cgroup v2 memory limit less its current use, where one is set."""
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int(Path("/sys/fs/cgroup/memory.current").read_text().strip())
    except (OSError, ValueError):
        return None


def available_bytes(device: str = "cpu") -> int | None:
    """Bytes that can be allocated now on `device` (the host's for "cpu"); None where unknown."""
    if str(device).startswith("cuda"):
        import torch

        free, _ = torch.cuda.mem_get_info(torch.device(device))
        return int(free)
    found = [b for b in (_meminfo_available(), _cgroup_available()) if b is not None]
    if not found:
        try:
            found = [os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")]
        except (ValueError, OSError, AttributeError):
            return None
    return max(0, min(found))


def size_text(n: float) -> str:
    """`n` bytes in words: "512 B", "1.5 GiB"."""
    if not math.isfinite(n):
        return "an unbounded amount"
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"):
        if n < 1024 or unit == "EiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.3g} EiB"


def check_fits(key: str, value, need: float, device: str = "cpu", what: str = "", advice: str = "") -> None:
    """ValueError naming `key`=`value` when `need` bytes (a lower bound, described by `what`)
    exceed the memory available on `device` (the host's memory for "cpu"); it ends with `advice`
    (default: use a smaller `key`)."""
    have = available_bytes(device)
    if have is not None and need > have:
        where = "this machine's available memory" if str(device) == "cpu" else f"the free memory of {device}"
        raise ValueError(
            f"{key}={value!r} needs at least {size_text(need)}{f' ({what})' if what else ''}, "
            f"more than {where} ({size_text(have)}); {advice or f'use a smaller {key}'}"
        )


def colony_fits(aco: ACOConfig, key: str, m: int, d: int, device: str, pool: int) -> None:
    """One iteration of the colony `aco` (config key `key`) fits in memory: every ant's M = `m`
    centres (d) and widths, and for the Ant System its choice probabilities over the `pool`
    candidates, at once. (With the fit objective ACO_R's ants are bounded by its budget; the
    objective ranks ants in batches of bounded memory.)"""
    if aco.colony == Colony.ant_system:
        check_fits(
            f"{key}.ants",
            aco.ants,
            aco.ants * (pool + m * (d + 1)) * FLOAT64,
            device,
            f"one iteration's choice probabilities over {pool} candidates and M = {m} centres and "
            "widths per ant, in float64",
        )
    elif aco.objective != Objective.fit:  # (the fit objective's budget bounds ACO_R's ants)
        check_fits(
            f"{key}.ants",
            aco.ants,
            aco.ants * m * (d + 1) * FLOAT64,
            device,
            f"one iteration's M = {m} centres and widths per ant, in float64",
        )


def check_train(cfg: TrainConfig) -> None:
    """A training run's data and least-squares design matrix (float64), and its colony, fit in
    memory; ValueError naming the key to make smaller."""
    d, n_q = cfg.data, len(cfg.robot.joint_low)
    pose = cfg.robot.target == Target.pose
    row = (7 if pose else 3) + n_q  # target and joints of one sample
    p = cfg.rbfn.num_centers + (9 if pose else 3) + 1  # design columns: M Gaussians, the tail, a bias
    parts = {"n_train": d.n_train * (row + p), "n_val": d.n_val * row, "n_test": d.n_test * row}
    key = max(parts, key=lambda k: parts[k])
    check_fits(
        f"data.{key}",
        getattr(d, key),
        sum(parts.values()) * FLOAT64,
        cfg.device,
        f"float64 samples of data.n_train + n_val + n_test and the data.n_train x {p} least-squares "
        f"design matrix of rbfn.num_centers={cfg.rbfn.num_centers}",
    )
    if cfg.centers.method == Method.aco:
        a = cfg.centers.aco
        colony_fits(
            a,
            "centers.aco",
            cfg.rbfn.num_centers,
            9 if pose else 3,
            cfg.device,
            min(a.ant_system.candidates, d.n_train),
        )


def check_evaluate(cfg: EvalConfig) -> None:
    """An evaluation's test set, recorded closed loops, online runs and closed-loop colony fit in
    memory (lower bounds); ValueError naming the key to make smaller."""
    if cfg.ik:  # targets (up to 7), joints (up to 7 free ones assumed), FK poses (16) per sample
        check_fits(
            "n_test",
            cfg.n_test,
            cfg.n_test * (7 + 7 + 16) * FLOAT64,
            cfg.device,
            "float64 test targets, joints and forward-kinematics poses",
        )
    n = len(cfg.robot.joint_low)
    c = cfg.control
    if c.enabled:  # q, qd and tau (n each) recorded every step, for each payload case at least
        _trajectory_fits("control.duration", c.duration, c.dt, max(1, len(c.payloads)), 3 * n, cfg.device)
        if any(network_method(name) for name in c.controllers):
            # desired states of one joint at least: d >= 2; candidates at most the pilot's training samples
            n_train = (int(round(c.duration / c.dt)) // PILOT_STRIDE + 1) // 2
            a = c.network.aco
            colony_fits(
                a, "control.network.aco", c.network.num_centers, 2, "cpu", min(a.ant_system.candidates, n_train)
            )
    o = cfg.online
    if o.enabled:  # joints and task position recorded every step, for each perturbation size
        _trajectory_fits("online.duration", o.duration, o.dt, len(o.sizes), 3 + 3, cfg.device)


def _trajectory_fits(key: str, duration: float, dt: float, batch: int, columns: int, device: str) -> None:
    """A run of duration / dt steps recording `columns` float64 values per step for `batch`
    environments fits in memory."""
    steps = duration / dt + 1
    check_fits(
        key,
        duration,
        steps * batch * columns * FLOAT64,
        device,
        f"{steps:.3g} steps of {dt:g} s, each recording {columns} float64 values for {batch} run(s)",
    )
