"""evaluate.py's `online` part: the IK network adapting on a perturbed robot; metrics, figure,
TensorBoard curves and checkpoint_online.pt."""
from __future__ import annotations

import copy
import logging
import math
from pathlib import Path

import torch

from ..checkpoint import model_from_checkpoint, save_sealed
from ..config import GainsConfig, OnlineConfig
from ..control.task_space import desired_path, run_online
from ..robots.scara import ScaraParams, ik
from .plots import online_figure
from .rundir import write_figure

__all__ = ["evaluate_online", "online_table"]

log = logging.getLogger(__name__)


def _rms(e: torch.Tensor, mask: torch.Tensor) -> list[float]:
    return e[mask].square().mean(0).sqrt().tolist()


def evaluate_online(ckpt: dict, cfg: OnlineConfig, gains: GainsConfig, device: str = "cpu",
                    writer=None, out_dir: Path | None = None) -> dict:
    """Metrics for the checkpoint dict `ckpt`: task_err_mm_rms_first_2s / _last_2s (adapted),
    _no_adapt and _analytic_nominal (last 2 s) for the configured perturbation; `sweep`, one row
    per size with its real link and offset errors; joint error and weight change. With `out_dir`,
    writes online_task_error.png and checkpoint_online.pt."""
    net = model_from_checkpoint(ckpt)
    sizes = list(cfg.sizes)
    r = run_online(net, cfg, gains, sizes, device)
    t = r["t"]
    first, last = t <= 2.0, t >= cfg.duration - 2.0
    i = next(k for k, s in enumerate(sizes) if math.isclose(s, cfg.link_error[0], rel_tol=1e-9, abs_tol=1e-12))
    adapt_first, adapt_last = _rms(r["err_adapt"], first), _rms(r["err_adapt"], last)
    frozen, analytic = _rms(r["err_frozen"], last), _rms(r["err_analytic"], last)
    # Joint error against the real robot's exact IK (same branch), configured perturbation.
    p = ScaraParams()
    real = ScaraParams(l1=p.l1 * (1 + cfg.link_error[0]), l2=p.l2 * (1 + cfg.link_error[1]))
    x_d = desired_path(cfg.path, t).to(r["q_adapt"])
    q_true = ik(x_d, real) - torch.tensor(cfg.offset_error, dtype=x_d.dtype, device=x_d.device)
    jerr = (r["q_adapt"][:, i] - q_true).norm(dim=-1)
    out = {
        "task_err_mm_rms_first_2s": adapt_first[i],
        "task_err_mm_rms_last_2s": adapt_last[i],
        "task_err_mm_rms_no_adapt": frozen[i],
        "task_err_mm_rms_analytic_nominal": analytic[i],
        "joint_err_rms_last_2s": float(jerr[last].square().mean().sqrt()),
        "weight_change_norm": float(r["dw"][-1, i]),
        "rejected_pairs": r["rejected"],
        "duration_s": cfg.duration, "learner": str(cfg.learner), "path": str(cfg.path),
        "sweep": [{"size": s, "link_error": le, "offset_error": oe,
                   "task_err_mm_rms_first_2s": a0, "task_err_mm_rms_last_2s": a1,
                   "task_err_mm_rms_no_adapt": f, "task_err_mm_rms_analytic_nominal": an}
                  for s, le, oe, a0, a1, f, an in zip(sizes, r["link_error"].tolist(), r["offset_error"].tolist(),
                                                      adapt_first, adapt_last, frozen, analytic)],
    }
    if writer is not None:
        stride = max(1, round(0.01 / cfg.dt))
        for k in range(0, t.shape[0], stride):
            step = int(round(float(t[k]) * 1000))      # ms
            for name, err in (("adapted", r["err_adapt"]), ("no_adapt", r["err_frozen"]),
                              ("analytic_nominal", r["err_analytic"])):
                writer.add_scalar(f"online/task_err_mm/{name}", float(err[k, i]), step)
        for k, v in out.items():
            if isinstance(v, float):
                writer.add_scalar(f"online/{k}", v)
    if out_dir is not None:
        fig = online_figure(t.cpu().numpy(), r["err_adapt"][:, i].cpu().numpy(), r["err_frozen"][:, i].cpu().numpy(),
                            r["err_analytic"][:, i].cpu().numpy(), r["t_update"].cpu().numpy(),
                            r["dw"][:, i].cpu().numpy(), f"online {cfg.learner}, path {cfg.path}")
        write_figure(fig, out_dir / "online_task_error.png", 110, writer, "online/task_error")
        if cfg.save_checkpoint:
            adapted = copy.deepcopy(net)
            adapted.set_output_weights(r["weights"][i].to(net.centers.dtype))
            new = dict(ckpt)
            new["state_dict"] = {k: v.cpu() for k, v in adapted.state_dict().items()}
            new["metrics"] = {**ckpt.get("metrics", {}), "online": {k: v for k, v in out.items() if k != "sweep"}}
            save_sealed(out_dir / "checkpoint_online.pt", new)
            out["checkpoint"] = str(out_dir / "checkpoint_online.pt")
    log.info("%s", online_table(out))
    return out


def online_table(m: dict) -> str:
    lines = [f"\nOnline IK adaptation ({m['learner']}, {m['duration_s']:g} s, path {m['path']}): "
             "task-space RMS error [mm]",
             f"{'link-1 error':>12s} {'first 2 s':>10s} {'last 2 s':>10s} {'no adapt':>10s} {'analytic':>10s}"]
    for row in m["sweep"]:
        lines.append(f"{row['size'] * 100:11.3g}% {row['task_err_mm_rms_first_2s']:10.3f} "
                     f"{row['task_err_mm_rms_last_2s']:10.3f} {row['task_err_mm_rms_no_adapt']:10.3f} "
                     f"{row['task_err_mm_rms_analytic_nominal']:10.3f}")
    return "\n".join(lines)
