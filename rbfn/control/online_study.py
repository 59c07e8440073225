"""evaluate.py's `online` part: the IK network adapting on a perturbed robot, metrics and figures."""
from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import torch

from ..checkpoint import model_from_checkpoint, read_checkpoint, save_sealed
from ..config import GainsConfig, OnlineConfig
from ..plots import online_figure  # sets the Agg backend before pyplot is used
from ..robots.scara import ScaraParams, ik
from .task_space import desired_path, run_online, with_weights

__all__ = ["evaluate_online", "DEFAULT_SIZE"]

DEFAULT_SIZE = 0.03        # the sweep size that is the configured perturbation itself


def _rms(e: torch.Tensor, mask: torch.Tensor) -> list[float]:
    return e[mask].square().mean(0).sqrt().tolist()


def evaluate_online(ckpt_path: Path, cfg: OnlineConfig, gains: GainsConfig, device: str = "cpu",
                    writer=None, out_dir: Path | None = None) -> dict:
    """Metrics: task_err_mm_rms_first_2s / _last_2s (adapted), _no_adapt and _analytic_nominal
    (last 2 s), for the configured perturbation; `sweep` rows for every size; joint error and
    weight change. Writes online_task_error.png and checkpoint_online.pt to out_dir."""
    ckpt = read_checkpoint(ckpt_path)
    net = model_from_checkpoint(ckpt)
    sizes = list(cfg.sizes)
    r = run_online(net, cfg, gains, sizes, device)
    t = r["t"]
    first, last = t <= 2.0, t >= cfg.duration - 2.0
    i = sizes.index(DEFAULT_SIZE)
    adapt_first, adapt_last = _rms(r["err_adapt"], first), _rms(r["err_adapt"], last)
    frozen, analytic = _rms(r["err_frozen"], last), _rms(r["err_analytic"], last)
    # Joint error against the real robot's exact IK (same branch), default perturbation.
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
        "duration_s": cfg.duration, "learner": cfg.learner, "path": cfg.path,
        "sweep": [{"size": s, "task_err_mm_rms_first_2s": a0, "task_err_mm_rms_last_2s": a1,
                   "task_err_mm_rms_no_adapt": f, "task_err_mm_rms_analytic_nominal": an}
                  for s, a0, a1, f, an in zip(sizes, adapt_first, adapt_last, frozen, analytic)],
    }
    if writer is not None:
        stride = max(1, round(0.01 / cfg.dt))
        for k in range(0, t.shape[0], stride):
            step = int(round(float(t[k]) * 1000))      # ms
            writer.add_scalars("online/task_err_mm", {"adapted": float(r["err_adapt"][k, i]),
                                                      "no_adapt": float(r["err_frozen"][k, i]),
                                                      "analytic_nominal": float(r["err_analytic"][k, i])}, step)
        for k, v in out.items():
            if isinstance(v, float):
                writer.add_scalar(f"online/{k}", v)
    if out_dir is not None:
        fig = online_figure(t.cpu().numpy(), r["err_adapt"][:, i].cpu().numpy(), r["err_frozen"][:, i].cpu().numpy(),
                            r["err_analytic"][:, i].cpu().numpy(), r["t_update"].cpu().numpy(),
                            r["dw"][:, i].cpu().numpy(), f"online {cfg.learner}, path {cfg.path}")
        fig.savefig(out_dir / "online_task_error.png", dpi=110)
        if writer is not None:
            writer.add_figure("online/task_error", fig)
        plt.close(fig)
        if cfg.save_checkpoint:
            adapted = with_weights(net, r["weights"][i].to(net.centers.dtype))
            new = dict(ckpt)
            new["state_dict"] = {k: v.cpu() for k, v in adapted.state_dict().items()}
            new["metrics"] = {**ckpt.get("metrics", {}), "online": {k: v for k, v in out.items() if k != "sweep"}}
            save_sealed(out_dir / "checkpoint_online.pt", new)
            out["checkpoint"] = str(out_dir / "checkpoint_online.pt")
    print_online_table(out)
    return out


def print_online_table(m: dict) -> None:
    print(f"\nOnline IK adaptation ({m['learner']}, {m['duration_s']:g} s, path {m['path']}): task-space RMS error [mm]")
    print(f"{'link-1 error':>12s} {'first 2 s':>10s} {'last 2 s':>10s} {'no adapt':>10s} {'analytic':>10s}")
    for row in m["sweep"]:
        print(f"{row['size'] * 100:11.0f}% {row['task_err_mm_rms_first_2s']:10.3f} "
              f"{row['task_err_mm_rms_last_2s']:10.3f} {row['task_err_mm_rms_no_adapt']:10.3f} "
              f"{row['task_err_mm_rms_analytic_nominal']:10.3f}")
