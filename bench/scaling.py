"""How cost grows: time of one ACO iteration's objective (K ants' RBF fits) against the training
set size N, the number of centres M and the number of ants K, and time of one closed-loop step
against the batch B; each with the fitted exponent p of time ~ x^p (log-log least squares).
"""

from __future__ import annotations

from pathlib import Path

import torch

from .select_time import selection_objective
from .timing import fit_exponent, median_seconds

__all__ = ["objective_seconds", "scaling_curves", "plot_curves"]


def objective_seconds(objective, m: int, k: int, device: str = "cpu", repeats: int = 3) -> float:
    """Median seconds of one objective call on K random centre sets of M training inputs."""
    g = torch.Generator().manual_seed(0)
    z = objective.z_train
    idx = torch.stack([torch.randperm(z.shape[0], generator=g)[:m] for _ in range(k)]).to(z.device)
    centers = z[idx]  # (K, M, d)
    widths = torch.full((k, m), 0.3, dtype=z.dtype, device=z.device)
    return median_seconds(lambda: objective(centers, widths), repeats, device)[0]


def _curve(x: list[int], t: list[float], fixed: str) -> dict:
    return {"x": list(x), "seconds": t, "exponent": fit_exponent(x, t), "fixed": fixed}


def scaling_curves(
    ns, ms, ks, sim_rows: list[dict], device: str = "cpu", n0: int = 2000, m0: int = 40, k0: int = 20, repeats: int = 3
) -> dict:
    """Curves {"N", "M", "K", "B"}: x, seconds, exponent; B from the simulator rows (seconds per
    step), with the exponent also over the three largest B (`exponent_large_B`)."""
    curves = {}
    curves["N"] = _curve(
        ns,
        [objective_seconds(selection_objective(n, device), m0, k0, device, repeats) for n in ns],
        f"M = {m0}, K = {k0}",
    )
    obj = selection_objective(n0, device)
    curves["M"] = _curve(ms, [objective_seconds(obj, m, k0, device, repeats) for m in ms], f"N = {n0}, K = {k0}")
    curves["K"] = _curve(ks, [objective_seconds(obj, m0, k, device, repeats) for k in ks], f"N = {n0}, M = {m0}")
    bs = [r["B"] for r in sim_rows]
    ts = [r["step_s"] for r in sim_rows]
    curves["B"] = _curve(bs, ts, "one closed-loop step, smc_obs, float32")
    if len(bs) >= 3:
        curves["B"]["exponent_large_B"] = fit_exponent(bs[-3:], ts[-3:])
    return curves


def plot_curves(curves: dict, path: Path, title: str) -> Path:
    """Log-log plot of every curve with its fitted line, one panel each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.ticker import NullFormatter

    labels = {"N": "training set size N", "M": "centres M", "K": "ants K", "B": "environments B"}
    what = {
        "N": "s per ACO iteration",
        "M": "s per ACO iteration",
        "K": "s per ACO iteration",
        "B": "s per closed-loop step",
    }
    fig, axes = plt.subplots(1, len(curves), figsize=(4 * len(curves), 3.6))
    for ax, (key, c) in zip(np.atleast_1d(axes), curves.items()):
        x, t = np.array(c["x"], float), np.array(c["seconds"], float)
        ax.loglog(x, t, "o", label="measured")
        p, b = np.polyfit(np.log(x), np.log(t), 1)
        ax.loglog(x, np.exp(b) * x**p, "-", label=f"fit: time ~ {key}^{p:.2f}")
        ax.set_xlabel(labels[key])
        ax.set_ylabel(what[key])
        ax.set_title(c["fixed"], fontsize=9)
        ax.set_xticks(x, [f"{v:g}" for v in x])  # the measured values, no minor labels
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
