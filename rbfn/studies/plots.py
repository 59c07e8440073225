"""Figures: the IK error figure, the closed loop's n x 3 figure, the online error curve.

The IK figure is a map over the x-y workspace for position targets (`workspace_error_map`) and,
for pose targets, the error against how far the sample lies toward the edge of the trained joint
box (`pose_error_figure`): a map of a 6-joint arm's poses is a cloud no one can read. Every title
starts with the robot the figure shows (`robot_label`), passed in by the caller from the data it
draws. Layouts are matplotlib's constrained layout, sized by the joint count, so tick labels and
axis labels of neighbouring panels never overlap, for 3 joints as for 7.

Built on matplotlib's object-oriented API (`matplotlib.figure.Figure`), not pyplot, so importing
this module never changes the process's backend and figures need no closing.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from ..config import ROBOT_PRESETS
from ..robots.dynamics import urdf_source
from ..robots.kinematics import urdf_tree

__all__ = [
    "robot_label",
    "workspace_error_map",
    "pose_error_figure",
    "tracking_figure",
    "pick_and_place_figure",
    "online_figure",
    "MAX_POINTS",
    "PAYLOAD_LABEL",
    "LIMIT_LABEL",
    "BEYOND_LABEL",
]

MAX_POINTS = 2500  # samples drawn per line of the tracking figure
PAYLOAD_LABEL = "payload on"  # the legend entry of the shaded payload interval
LIMIT_LABEL = "URDF joint limit"  # the legend entries of the position limits and the samples beyond them
BEYOND_LABEL = "beyond the limit"
FLOOR_MM = 1e-4  # errors below this are drawn at it (a log axis has no 0)


def robot_label(name: str, urdf: str | os.PathLike) -> str:
    """The robot's name as figures and metrics.json's `robots` give it: `name` (robot.name, or a
    checkpoint's robot `name`), unless that is a shipped preset's name beside another URDF
    (robot.name keeps its default "scara" when only robot.urdf is given): then the URDF's own
    `<robot name="...">`. `urdf`: the URDF's text, a preset's name or a `pathlib.Path` of the file.
    """
    text, source = urdf_source(urdf, "urdf")
    own = urdf_tree(text, source).get("name") or ""
    if not name or (name in ROBOT_PRESETS and own != name):
        return own or "unnamed robot"
    return name


def _title(robot: str, *parts: str | None) -> str:
    """ "robot: part, part, ..." with the empty and None parts left out; `robot` must be named."""
    if not robot or robot == "None":
        raise ValueError(f"robot={robot!r}: a figure names the robot it shows (robot_label)")
    return f"{robot}: " + ", ".join(p for p in parts if p)


def workspace_error_map(x: np.ndarray, err_mm: np.ndarray, inside: np.ndarray, *, robot: str, num_centers: int):
    """Figure of position error (mm, log colour) over the x-y workspace; x (N, 3) in m, err_mm
    (N,), inside (N,) bool. Points the network flags as outside its trained workspace are drawn as
    grey crosses."""
    fig = Figure(figsize=(6.4, 5.6), layout="constrained")
    ax = fig.subplots()
    e = np.clip(err_mm, FLOOR_MM, None)
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
    ax.set_aspect("equal", adjustable="datalim")  # the box stays where the layout put it: no label clipped
    ax.set_title(_title(robot, f"IK position error, M = {num_centers}"))
    return fig


def pose_error_figure(
    q: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    err_mm: np.ndarray,
    inside: np.ndarray,
    *,
    robot: str,
    num_centers: int,
    bins: int = 10,
) -> Figure:
    """Position error (mm, log) against each sample's distance from the centre c of the trained
    joint box, d = max_j |q_j - c_j| / h_j (h: the half-widths; 0 at the centre, 1 on a face), with
    the median and 95th percentile of each of `bins` bins of d holding 5 samples or more.

    q (N, n) the true joints in the URDF's units, low and high (n,) the box, err_mm (N,), inside
    (N,) bool: points flagged outside the trained workspace are grey crosses. Reads the same for
    any joint count, where a map of the targets does not.
    """
    c, h = (high + low) / 2, (high - low) / 2
    d = np.abs((q - c) / h).max(axis=1)
    e = np.clip(err_mm, FLOOR_MM, None)
    fig = Figure(figsize=(7.0, 4.8), layout="constrained")
    ax = fig.subplots()
    ax.scatter(d[inside], e[inside], s=4, alpha=0.3, lw=0, color="C0", label="test sample")
    if (~inside).any():
        ax.scatter(d[~inside], e[~inside], c="0.5", s=10, marker="x", label="flagged outside")
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(d, edges) - 1, 0, bins - 1)
    full = [b for b in range(bins) if (which == b).sum() >= 5]
    mids = (edges[:-1] + edges[1:])[full] / 2
    ax.plot(mids, [np.median(e[which == b]) for b in full], "o-", color="C1", label="median per bin")
    ax.plot(mids, [np.quantile(e[which == b], 0.95) for b in full], "s--", color="C3", label="95th percentile")
    ax.set_yscale("log")
    ax.set_xlim(0.0, 1.0)
    ax.set_xlabel(r"distance from the joint box's centre, $\max_j\,|q_j - c_j| / h_j$ (1: on its edge)")
    ax.set_ylabel("FK position error (mm)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(_title(robot, f"IK position error against the joint box, M = {num_centers}, {q.shape[1]} joints"))
    return fig


def tracking_figure(
    t: np.ndarray,
    q: np.ndarray,
    q_des: np.ndarray,
    tau: np.ndarray,
    *,
    robot: str,
    detail: str,
    window: tuple[float, float] | None = None,
    units: list[tuple[str, str]] | None = None,
    limits: tuple[Sequence[float], Sequence[float]] | None = None,
    cases: Sequence[str] | None = None,
    joint_names: Sequence[str] | None = None,
) -> Figure:
    """The paper's n x 3 figure: per joint (rows), position against desired, error, control input,
    one line per case (payload) in each panel.

    t (T,) s; q (T, P, n) for P cases, or (T, n) for one; q_des (T, n); tau as q; `cases` (P,) the
    cases' names in the legend; title "robot: detail"; `units` per joint (position, torque),
    default the SCARA's (rad, N m), (rad, N m), (m, N) for 3 joints, else (rad, N m) on every
    joint; `joint_names` (n,) the rows' labels (default "joint j"); `window` (s) shades the payload
    interval, named in the legend. Lines show every k-th sample, at most MAX_POINTS per line. Rows
    are shorter, with fewer ticks and smaller labels, past 3 joints. `limits` (lower, upper) (n,)
    the joints' position limits (rad or m, +-inf where none): a limit near the drawn range is a
    dotted line on the position panel, and stretches of time where any case is beyond one are
    marked (a stretch shorter than a drawn sample still shows).
    """
    q = q[:, None] if q.ndim == 2 else q
    tau = tau[:, None] if tau.ndim == 2 else tau
    p, n = q.shape[1], q.shape[2]
    cases = list(cases) if cases is not None else (["actual"] if p == 1 else [f"case {c + 1}" for c in range(p)])
    if len(cases) != p:
        raise ValueError(f"cases={cases!r}: one name per case of q, {p}")
    names = list(joint_names) if joint_names is not None else [f"joint {j + 1}" for j in range(n)]
    units = units or ([("rad", "N m"), ("rad", "N m"), ("m", "N")] if n == 3 else [("rad", "N m")] * n)
    colours = [f"C{c}" for c in (0, 1, 2, 4, 5, 6, 7, 8, 9)]  # C3 (red) marks the limits
    k = max(1, -(-t.shape[0] // MAX_POINTS))  # every k-th sample: a figure, not a record
    lower, upper = (np.full(n, -np.inf), np.full(n, np.inf)) if limits is None else map(np.asarray, limits)
    out = ((q < lower) | (q > upper)).any(axis=1)  # (T, n): any case beyond
    beyond = np.maximum.reduceat(out, np.arange(0, t.shape[0], k), axis=0)  # (T/k, n)
    worst = np.abs(q - q_des[:, None]).sum(axis=(0, 2)).argmax()  # the case whose curve marks a breach
    t, q, q_des, tau = t[::k], q[::k], q_des[::k], tau[::k]
    many = n > 3
    fig = Figure(figsize=(13, (2.1 if many else 2.7) * n + 0.8), layout="constrained")
    axes = fig.subplots(n, 3, sharex=True, squeeze=False)
    for c, heading in enumerate(("position", "tracking error e = q_d - q", "torque")):
        axes[0, c].set_title(heading, fontsize=9 if many else 10)
    for j in range(n):
        panels = (
            (q[:, :, j], f"{names[j]} [{units[j][0]}]"),
            (q_des[:, None, j] - q[:, :, j], f"[{units[j][0]}]"),
            (tau[:, :, j], f"[{units[j][1]}]"),
        )
        for c, (y, label) in enumerate(panels):
            ax = axes[j, c]
            if c == 0:
                ax.plot(t, q_des[:, j], "--", lw=0.9, color="k", zorder=3)
            for i in range(p):
                ax.plot(t, y[:, i], lw=0.8, color=colours[i % len(colours)])
            if c == 0:
                _draw_limits(ax, t, q[:, worst, j], q_des[:, j], lower[j], upper[j], beyond[:, j])
            if window is not None:
                ax.axvspan(*window, color="0.9", zorder=0)
            ax.set_ylabel(label, fontsize=9 if many else None)
            ax.grid(alpha=0.3)
            if many:
                ax.yaxis.set_major_locator(MaxNLocator(4))
                ax.tick_params(labelsize=8)
                ax.yaxis.get_offset_text().set_fontsize(8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    _tracking_legend(fig, axes, cases, window)
    fig.suptitle(_title(robot, detail))
    return fig


def _tracking_legend(fig: Figure, axes, cases: list[str], window: tuple[float, float] | None) -> None:
    """The tracking figure's legend, below its panels: the desired path, each case's line, the
    joint limits and breaches where drawn, the payload band."""
    handles = [axes[0, 0].lines[0], *axes[0, 0].lines[1 : 1 + len(cases)]]
    labels = ["desired", *cases]
    for label in (LIMIT_LABEL, BEYOND_LABEL):
        drawn = [ln for ax in axes[:, 0] for ln in ax.lines if ln.get_label() == label]
        if drawn:
            handles.append(drawn[0])
            labels.append(label)
    if window is not None:
        handles.append(Patch(color="0.9", label=PAYLOAD_LABEL))
        labels.append(f"{PAYLOAD_LABEL} ({window[0]:g}-{window[1]:g} s)")
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=8, frameon=False)


def pick_and_place_figure(
    t: np.ndarray,
    err: np.ndarray,
    names: Sequence[str],
    carried: np.ndarray,
    *,
    robot: str,
    units: list[str],
    joint_names: Sequence[str],
    window: float = 0.5,
) -> Figure:
    """The pick-and-place run: the mass carried (kg) over time on top, then per joint each
    controller's tracking error as its RMS over a sliding `window` (s), on a log scale.

    t (T,) s, evenly spaced; err (T, C, n) desired minus actual joints for the C controllers
    `names`; carried (T,) kg; `units` the joints' position units (n,)."""
    n = err.shape[2]
    w = max(1, int(round(window / float(t[1] - t[0]))))
    sq = np.concatenate([np.zeros((1, *err.shape[1:])), np.cumsum(err**2, 0)])
    rms = np.sqrt(np.maximum(sq[w:] - sq[:-w], 0.0) / w)  # (T - w + 1, C, n), the window ending at each row
    tr = t[w - 1 :]
    k = max(1, -(-tr.shape[0] // MAX_POINTS))
    fig = Figure(figsize=(11, 1.6 * (n + 1) + 0.8), layout="constrained")
    axes = fig.subplots(n + 1, 1, sharex=True, squeeze=False)[:, 0]
    axes[0].fill_between(t, carried, step="post", color="0.75")
    axes[0].set_ylabel("payload [kg]")
    for j in range(n):
        ax = axes[j + 1]
        for c, name in enumerate(names):
            ax.semilogy(tr[::k], np.maximum(rms[::k, c, j], 1e-12), lw=0.8, label=name)
        ax.set_ylabel(f"{joint_names[j]}\nRMS e [{units[j]}]", fontsize=8)
        ax.tick_params(labelsize=8)
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    axes[-1].set_xlabel("t [s]")
    handles, labels = axes[1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize=8, frameon=False)
    fig.suptitle(_title(robot, f"pick and place, tracking error as RMS over {window:g} s"))
    return fig


def _draw_limits(ax, t, q, q_des, low: float, high: float, beyond: np.ndarray) -> None:
    """A joint's position limits as dotted lines where they lie within a quarter of the drawn
    range of q and q_des (a far limit would flatten the curves), and the samples beyond one."""
    span = max(float(np.ptp(q)), float(np.ptp(q_des)), 1e-9)
    bottom, top = min(q.min(), q_des.min()) - span / 4, max(q.max(), q_des.max()) + span / 4
    for v in (low, high):
        if np.isfinite(v) and bottom <= v <= top:
            ax.axhline(v, ls=":", lw=1.0, color="C3", label=LIMIT_LABEL)
    if beyond.any():
        ax.plot(t[beyond], q[beyond], ".", ms=2, color="C3", label=BEYOND_LABEL)


def online_figure(
    t: np.ndarray,
    adapted: np.ndarray,
    frozen: np.ndarray,
    analytic: np.ndarray,
    t_update: np.ndarray,
    dw: np.ndarray,
    *,
    robot: str,
    learner: str,
    path: str | None = None,
    link_error: float | None = None,
):
    """Task-space error (mm) over time for the adapted and frozen networks and the nominal
    analytic IK, and the norm of the weight change; t (T,) s, errors (T,) mm, t_update (U,) s,
    dw (U,). Title: the robot, the learner, the path and the link-1 error (fraction), each left
    out where None."""
    fig = Figure(figsize=(9, 6), layout="constrained")
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
    a2.set_ylabel("|W - W0| (Frobenius)\n[the joints' units: rad, m]")
    a2.set_xlabel("t [s]")
    a2.grid(alpha=0.3)
    fig.suptitle(
        _title(
            robot,
            f"online adaptation ({learner})",
            None if path is None else f"path {path}",
            None if link_error is None else f"link-1 error {100 * link_error:g} %",
        )
    )
    return fig
