"""Memory a setting needs, estimated before any work, against what the machine has.

Sizes that cannot fit (`data.n_train=1000000000`, `control.duration=1e12`, `n_test=1000000000`)
fail at once with the key, the estimate and the limit, instead of dying in the allocator after
minutes of work, or grinding through swap. The estimates are lower bounds: the arrays a run
certainly holds at once (float64 data, the least-squares design matrix, recorded trajectories),
so a setting that is refused cannot fit, and a setting that fits is never refused. The limit is
the memory available now (Linux: MemAvailable, or the cgroup's limit where smaller; elsewhere the
physical memory), or on CUDA the device's free memory.

Like rbfn.config this module imports no other part of the package.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

__all__ = ["available_bytes", "check_fits", "FLOAT64"]

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


def _size(n: float) -> str:
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
            f"{key}={value!r} needs at least {_size(need)}{f' ({what})' if what else ''}, "
            f"more than {where} ({_size(have)}); {advice or f'use a smaller {key}'}"
        )
