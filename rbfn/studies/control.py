"""evaluate.py's `control` part: run the comparison, then its table, figures and TensorBoard scalars."""
from __future__ import annotations

import logging
from pathlib import Path

from ..config import ControlConfig, GainsConfig
from ..control.comparison import ControlComparison, compare_controllers
from .plots import tracking_figure

__all__ = ["evaluate_control", "control_table"]

log = logging.getLogger(__name__)


def evaluate_control(cfg: ControlConfig, gains: GainsConfig, device: str, writer, out_dir: Path) -> dict:
    """metrics.json's `control` (controller -> case -> metric -> per joint) and `control_info`."""
    res = compare_controllers(cfg, gains, device)
    metrics = {name: run.metrics for name, run in res.runs.items()}
    info = {"gains": {k: (str(v) if not isinstance(v, (int, float)) else v) for k, v in vars(gains).items()},
            "select_seconds": {n: r.select_seconds for n, r in res.runs.items() if r.select_seconds is not None},
            "sim_seconds": {n: r.sim_seconds for n, r in res.runs.items()}}
    for name, cases in metrics.items():
        for case, m in cases.items():
            for key, vals in m.items():
                for j, v in enumerate(vals):
                    writer.add_scalar(f"control/{name}/{case}/{key}_j{j + 1}", v)
        _figure(res, name, cfg, gains, writer, out_dir)
    log.info("%s", control_table(metrics))
    return {"control": metrics, "control_info": info}


def _figure(res: ControlComparison, name: str, cfg: ControlConfig, gains: GainsConfig, writer, out_dir: Path) -> None:
    """control_<name>.png: the case whose payload is closest to `cfg.figure_payload`."""
    i = min(range(len(res.payloads)), key=lambda i: abs(res.payloads[i] - cfg.figure_payload))
    roll = res.runs[name].rollout
    fig = tracking_figure(roll.t.cpu().numpy(), roll.q[:, i].cpu().numpy(), res.q_des.cpu().numpy(),
                          roll.tau[:, i].cpu().numpy(),
                          f"{name}, payload {res.payloads[i]:g} kg, K = {gains.K:g}, Lambda = {gains.Lambda:g}",
                          (cfg.payload_on, cfg.payload_off))
    fig.savefig(out_dir / f"control_{name}.png", dpi=110)
    writer.add_figure(f"control/{name}", fig, close=False)


def control_table(metrics: dict) -> str:
    """RMS error per joint (t > 0.5 s), max joint-3 error in the payload window, peak torques."""
    lines = [f"{'controller':14s} {'case':>5s}  {'RMS e1, e2 [rad], e3 [m]':>30s}  {'max e3 window [m]':>17s}  "
             f"{'peak |tau| [N m, N m, N]':>26s}"]
    for name, cases in metrics.items():
        for case, m in cases.items():
            rms = " ".join(f"{v:9.2e}" for v in m["rms_err"])
            peak = " ".join(f"{v:8.1f}" for v in m["peak_tau"])
            lines.append(f"{name:14s} {case:>5s}  {rms:>30s}  {m['max_err_payload'][-1]:17.3e}  {peak:>26s}")
    return "\nClosed loop\n" + "\n".join(lines)
