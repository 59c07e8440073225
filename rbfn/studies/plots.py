"""Figures: the IK workspace error map, the closed loop's 3x3 figure, the online error curve.

Built on matplotlib's object-oriented API (`matplotlib.figure.Figure`), not pyplot, so importing
this module never changes the process's backend and figures need no closing.
"""

from __future__ import annotations

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

__all__ = ["workspace_error_map", "tracking_figure", "online_figure", "MAX_POINTS"]

MAX_POINTS = 2500  # samples drawn per line of the tracking figure


def workspace_error_map(x: np.ndarray, err_mm: np.ndarray, inside: np.ndarray, title: str):
    """Figure of position error (mm, log colour) over the x-y workspace; x (N, 3) in m.

    Points the network flags as outside its trained workspace are drawn as grey crosses.
    """
    fig = Figure(figsize=(6.4, 5.6), layout="constrained")
    ax = fig.subplots()
    e = np.clip(err_mm, 1e-4, None)
    sc = ax.scatter(
        x[inside, 0],
        x[inside, 1],
        c=e[inside],
        s=6,
        cmap="viridis",
        norm=LogNorm(
            vmin=max(e[inside].min(), 1e-3) if inside.any() else 1e-3,
            vmax=max(e[inside].max(), 1e-2) if inside.any() else 1.0,
        ),
    )
    if (~inside).any():
        ax.scatter(x[~inside, 0], x[~inside, 1], c="0.6", s=8, marker="x", label="flagged outside")
        ax.legend(loc="lower left")
    fig.colorbar(sc, ax=ax, label="FK position error (mm)", shrink=0.75)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.set_title(title)
    return fig


def tracking_figure(
    t: np.ndarray,
    q: np.ndarray,
    q_des: np.ndarray,
    tau: np.ndarray,
    title: str,
    window: tuple[float, float] | None = None,
    units: list[tuple[str, str]] | None = None,
) -> Figure:
    """The paper's n x 3 figure: per joint (rows), position vs desired, error, control input.

    t (T,) s; q, q_des (T, n); tau (T, n); `units` per joint (position, torque), default the
    SCARA's (rad, N m), (rad, N m), (m, N) for 3 joints, else (rad, N m) on every joint; `window`
    shades the payload interval. Lines show every k-th sample, at most MAX_POINTS per line.
    """
    n = q.shape[1]
    units = units or ([("rad", "N m"), ("rad", "N m"), ("m", "N")] if n == 3 else [("rad", "N m")] * n)
    k = max(1, -(-t.shape[0] // MAX_POINTS))  # every k-th sample: a figure, not a record
    t, q, q_des, tau = t[::k], q[::k], q_des[::k], tau[::k]
    fig = Figure(figsize=(13, 2.7 * n))
    axes = fig.subplots(n, 3, sharex=True, squeeze=False)
    for j in range(n):
        panels = (
            (q[:, j], f"q{j + 1} [{units[j][0]}]"),
            (q_des[:, j] - q[:, j], f"e{j + 1} [{units[j][0]}]"),
            (tau[:, j], f"tau{j + 1} [{units[j][1]}]"),
        )
        for c, (y, label) in enumerate(panels):
            ax = axes[j, c]
            ax.plot(t, y, lw=0.8, label="actual" if c == 0 else None)
            if c == 0:
                ax.plot(t, q_des[:, j], "--", lw=0.8, label="desired")
                ax.legend(loc="upper right", fontsize=7)
            if window is not None:
                ax.axvspan(*window, color="0.9", zorder=0)
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.suptitle(title)
    # Fixed margins: tight_layout measured as a third of the figure's cost.
    fig.subplots_adjust(
        left=0.07, right=0.99, bottom=0.5 / (2.7 * n), top=1 - 0.65 / (2.7 * n), wspace=0.28, hspace=0.15
    )
    return fig


def online_figure(
    t: np.ndarray,
    adapted: np.ndarray,
    frozen: np.ndarray,
    analytic: np.ndarray,
    t_update: np.ndarray,
    dw: np.ndarray,
    title: str,
):
    """Task-space error (mm) over time for the adapted and frozen networks and the nominal
    analytic IK, and the norm of the weight change."""
    fig = Figure(figsize=(9, 6))
    a1, a2 = fig.subplots(2, 1, sharex=True)
    for y, label in (
        (adapted, "adapted network"),
        (frozen, "network, no adaptation"),
        (analytic, "nominal analytic IK"),
    ):
        a1.semilogy(t, np.maximum(y, 1e-6), lw=0.8, label=label)
    a1.set_ylabel("task-space error [mm]")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3, which="both")
    a2.plot(t_update, dw, lw=0.8)
    a2.set_ylabel("|W - W0|")
    a2.set_xlabel("t [s]")
    a2.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    return fig
