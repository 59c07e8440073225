"""evaluate.py's `online` part: the IK network adapting on a perturbed robot; metrics, figure,
TensorBoard curves and checkpoint_online.pt."""

from __future__ import annotations

import copy
import logging
import math
from pathlib import Path
from typing import Any

import torch

from ..checkpoint import model_from_checkpoint, save_sealed
from ..config import GainsConfig, OnlineConfig
from ..control.task_space import OnlineRun, check_online, path_name, run_online
from ..layer import RBFNetwork
from .plots import online_figure, robot_label
from .rundir import write_figure, write_summary

__all__ = ["evaluate_online", "online_table", "check_online"]

log = logging.getLogger(__name__)


def _rms(e: torch.Tensor, mask: torch.Tensor) -> list[float]:
    return e[mask].square().mean(0).sqrt().tolist()


def evaluate_online(
    ckpt: dict, cfg: OnlineConfig, gains: GainsConfig, device: str = "cpu", writer=None, out_dir: Path | None = None
) -> dict:
    """Metrics for the checkpoint dict `ckpt`: task_err_mm_rms_first_2s / _last_2s (adapted),
    _no_adapt and _analytic_nominal (last 2 s) for the configured perturbation, and the same
    task_rot_err_deg_rms_* for pose targets; `sweep`, one row per size with its real link and
    offset errors; joint error (null where the real robot's exact IK is not known: URDF arms) and
    weight change. With `out_dir`, writes online_task_error.png and checkpoint_online.pt."""
    net = model_from_checkpoint(ckpt)
    sizes = list(cfg.sizes)
    r = run_online(net, ckpt["robot"], cfg, gains, sizes, device=device)
    t = r.t
    first, last = t <= 2.0, t >= cfg.duration - 2.0
    i = next(k for k, s in enumerate(sizes) if math.isclose(s, cfg.link_error[0], rel_tol=1e-9, abs_tol=1e-12))
    adapt_first, adapt_last = _rms(r.err_adapt, first), _rms(r.err_adapt, last)
    frozen, analytic = _rms(r.err_frozen, last), _rms(r.err_analytic, last)
    # Joint error against the real robot's exact IK (same branch), where it is known.
    jerr = None if r.q_real is None else (r.q_adapt[:, i] - r.q_real).norm(dim=-1)
    robot, path = robot_label(ckpt["robot"].get("name", ""), ckpt["robot"]["urdf"]), path_name(cfg, ckpt["robot"])
    out: dict = {
        "task_err_mm_rms_first_2s": adapt_first[i],
        "task_err_mm_rms_last_2s": adapt_last[i],
        "task_err_mm_rms_no_adapt": frozen[i],
        "task_err_mm_rms_analytic_nominal": analytic[i],
        "joint_err_rms_last_2s": None if jerr is None else float(jerr[last].square().mean().sqrt()),
        "weight_change_norm": float(r.dw[-1, i]),
        "rejected_pairs": r.rejected,
        "duration_s": cfg.duration,
        "learner": str(cfg.learner),
        "path": path,
        "robot": robot,
        "sweep": [
            {
                "size": s,
                "link_error": le,
                "offset_error": oe,
                "task_err_mm_rms_first_2s": a0,
                "task_err_mm_rms_last_2s": a1,
                "task_err_mm_rms_no_adapt": f,
                "task_err_mm_rms_analytic_nominal": an,
            }
            for s, le, oe, a0, a1, f, an in zip(
                sizes, r.link_error.tolist(), r.offset_error.tolist(), adapt_first, adapt_last, frozen, analytic
            )
        ],
    }
    if r.rot_adapt is not None:  # pose targets: the orientation error too
        assert r.rot_frozen is not None and r.rot_analytic is not None
        rot = {
            "first_2s": _rms(r.rot_adapt, first),
            "last_2s": _rms(r.rot_adapt, last),
            "no_adapt": _rms(r.rot_frozen, last),
            "analytic_nominal": _rms(r.rot_analytic, last),
        }
        out.update({f"task_rot_err_deg_rms_{k}": v[i] for k, v in rot.items()})
        for j, row in enumerate(out["sweep"]):
            row.update({f"task_rot_err_deg_rms_{k}": v[j] for k, v in rot.items()})
    if writer is not None:
        _write_curves(writer, r, i, cfg.dt)
        write_summary(writer, "online/summary", out)
    if out_dir is not None:
        _write_outputs(out_dir, ckpt, net, r, i, cfg=cfg, out=out, writer=writer, robot=robot, path=path)
    log.info("%s", online_table(out))
    return out


def _write_curves(writer: Any, r: OnlineRun, i: int, dt: float) -> None:
    """The task-space error (mm) of row i's adapted, frozen and nominal IK against time (step: ms),
    every 10 ms (a point every `dt` s where that is coarser)."""
    stride = max(1, round(0.01 / dt))
    for k in range(0, r.t.shape[0], stride):
        step = int(round(float(r.t[k]) * 1000))  # ms
        for name, err in (
            ("adapted", r.err_adapt),
            ("no_adapt", r.err_frozen),
            ("analytic_nominal", r.err_analytic),
        ):
            writer.add_scalar(f"online/task_err_mm/{name}", float(err[k, i]), step)


def _write_outputs(
    out_dir: Path,
    ckpt: dict,
    net: RBFNetwork,
    r: OnlineRun,
    i: int,
    *,
    cfg: OnlineConfig,
    out: dict,
    writer: Any,
    robot: str,
    path: str,
) -> None:
    """online_task_error.png of row i and, with `cfg.save_checkpoint`, checkpoint_online.pt: the
    checkpoint with row i's adapted weights and the metrics `out` (its path added to `out`)."""
    sizes = list(cfg.sizes)
    t = r.t
    fig = online_figure(
        t.cpu().numpy(),
        r.err_adapt[:, i].cpu().numpy(),
        r.err_frozen[:, i].cpu().numpy(),
        r.err_analytic[:, i].cpu().numpy(),
        r.t_update.cpu().numpy(),
        r.dw[:, i].cpu().numpy(),
        robot=robot,
        learner=str(cfg.learner),
        path=path,
        link_error=sizes[i],
    )
    write_figure(fig, out_dir / "online_task_error.png", 110, writer, "figures/online_task_error")
    if cfg.save_checkpoint:
        adapted = copy.deepcopy(net)
        adapted.set_output_weights(r.weights[i].to(net.centers.dtype))
        new = dict(ckpt)
        new["state_dict"] = {k: v.cpu() for k, v in adapted.state_dict().items()}
        new["metrics"] = {**ckpt.get("metrics", {}), "online": {k: v for k, v in out.items() if k != "sweep"}}
        save_sealed(out_dir / "checkpoint_online.pt", new)
        out["checkpoint"] = str(out_dir / "checkpoint_online.pt")


def online_table(m: dict) -> str:
    rot = "task_rot_err_deg_rms_last_2s" in m
    unit = "position [mm] / rotation [deg]" if rot else "[mm]"
    lines = [
        f"\nOnline IK adaptation ({m['learner']}, {m['duration_s']:g} s, path {m['path']}): "
        f"task-space RMS error {unit}",
        f"{'link-1 error':>12s} {'first 2 s':>16s} {'last 2 s':>16s} {'no adapt':>16s} {'analytic':>16s}",
    ]
    keys = ("first_2s", "last_2s", "no_adapt", "analytic_nominal")
    for row in m["sweep"]:
        cells = [
            f"{row['task_err_mm_rms_' + k]:.3f}" + (f" / {row['task_rot_err_deg_rms_' + k]:.3f}" if rot else "")
            for k in keys
        ]
        lines.append(f"{row['size'] * 100:11.3g}% " + " ".join(f"{c:>16s}" for c in cells))
    return "\n".join(lines)
