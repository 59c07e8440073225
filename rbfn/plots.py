"""Figures (matplotlib, Agg backend): the IK workspace error map."""
from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

__all__ = ["workspace_error_map"]


def workspace_error_map(x: np.ndarray, err_mm: np.ndarray, inside: np.ndarray, title: str):
    """Figure of position error (mm, log colour) over the x-y workspace; x (N, 3) in m.

    Points the network flags as outside its trained workspace are drawn as grey crosses.
    """
    fig, ax = plt.subplots(figsize=(6.4, 5.6), constrained_layout=True)
    e = np.clip(err_mm, 1e-4, None)
    sc = ax.scatter(x[inside, 0], x[inside, 1], c=e[inside], s=6, cmap="viridis",
                    norm=LogNorm(vmin=max(e[inside].min(), 1e-3) if inside.any() else 1e-3,
                                 vmax=max(e[inside].max(), 1e-2) if inside.any() else 1.0))
    if (~inside).any():
        ax.scatter(x[~inside, 0], x[~inside, 1], c="0.6", s=8, marker="x", label="flagged outside")
        ax.legend(loc="lower left")
    fig.colorbar(sc, ax=ax, label="FK position error (mm)", shrink=0.75)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.set_title(title)
    return fig
