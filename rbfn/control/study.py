"""The closed-loop comparison that evaluate.py runs: every controller on every payload case.

Payload cases run as one batch per controller (B = number of cases). The adaptive RBFN's centres
come from a pilot run of `smc_obs` without payload (see rbfn.control.network).
"""
from __future__ import annotations

import time
from pathlib import Path

import matplotlib.pyplot as plt
import torch

from ..config import ControlConfig, GainsConfig
from ..plots import tracking_figure  # sets the Agg backend before pyplot is used
from ..robots.scara import ScaraParams
from .controllers import NominalModel, make_controller
from .network import control_network, desired_states, pilot_residuals
from .plant import ScaraPlant
from .scenario import Scenario, control_metrics, simulate
from .trajectory import paper_trajectory

__all__ = ["run_control", "print_control_table", "case_name", "PILOT_STRIDE"]

PILOT_STRIDE = 10        # pilot samples every 10 control periods


def case_name(payload: float) -> str:
    """Payload case key: 10.0 -> "10kg"."""
    return f"{payload:g}kg"


def run_control(cfg: ControlConfig, gains: GainsConfig, device: str = "cpu", writer=None,
                out_dir: Path | None = None, params: ScaraParams = ScaraParams()) -> dict:
    """metrics[controller][case] = {rms_err, max_err, max_err_payload, peak_tau, chattering}, plus
    metrics["_info"] with timings and the networks' selection times. Figures go to out_dir."""
    dtype = {"float64": torch.float64, "float32": torch.float32}[cfg.dtype]
    kw = {"dtype": dtype, "device": device}
    sc = Scenario(cfg.duration, cfg.dt, cfg.integrator, cfg.payload_on, cfg.payload_off)
    sc.validate()
    ref = tuple(r.to(**kw) for r in paper_trajectory(sc.times(torch.float64)))
    plant = ScaraPlant(params, friction=cfg.friction)
    model = NominalModel(params)
    payload = torch.tensor(cfg.payloads, **kw)
    b = payload.shape[0]
    q0, qd0 = ref[0][:1].expand(b, 3).clone(), ref[1][:1].expand(b, 3).clone()
    pilot = None
    out: dict = {}
    info: dict = {"gains": vars(gains).copy(), "select_seconds": {}, "sim_seconds": {}}
    for name in cfg.controllers:
        features = w0 = None
        if name.startswith("arbfn_"):
            if pilot is None:
                pilot = pilot_residuals(plant, sc, ref, gains, model, PILOT_STRIDE)
            net = control_network(name[6:], pilot[0].double().cpu(), pilot[1].double().cpu(),
                                  cfg.network.num_centers, cfg.network.seed, sc.dt * PILOT_STRIDE,
                                  cfg.network.aco, cfg.network.warm_start)
            features, w0 = net.features(desired_states(ref)), net.w0
            info["select_seconds"][name] = net.seconds
        ctrl = make_controller(name, gains, sc.dt, model, features, w0, cfg.network.observer)
        t0 = time.perf_counter()
        roll = simulate(plant, ctrl, sc, ref, q0, qd0, payload, compile=cfg.compile)
        info["sim_seconds"][name] = time.perf_counter() - t0
        per_case = control_metrics(roll, ref[0], sc)
        out[name] = {case_name(p): m for p, m in zip(cfg.payloads, per_case)}
        if writer is not None:
            for case, m in out[name].items():
                for key, vals in m.items():
                    for j, v in enumerate(vals):
                        writer.add_scalar(f"control/{name}/{case}/{key}_j{j + 1}", v)
        if out_dir is not None:
            i = min(range(b), key=lambda i: abs(cfg.payloads[i] - cfg.figure_payload))
            fig = tracking_figure(roll.t.cpu().numpy(), roll.q[:, i].cpu().numpy(), ref[0].cpu().numpy(),
                                  roll.tau[:, i].cpu().numpy(),
                                  f"{name}, payload {cfg.payloads[i]:g} kg, K = {gains.K:g}, "
                                  f"Lambda = {gains.Lambda:g}", (cfg.payload_on, cfg.payload_off))
            fig.savefig(out_dir / f"control_{name}.png", dpi=110)
            if writer is not None:
                writer.add_figure(f"control/{name}", fig)
            plt.close(fig)
    out["_info"] = info
    return out


def print_control_table(metrics: dict) -> None:
    """RMS error per joint (t > 0.5 s), max joint-3 error in the payload window, peak torques."""
    print(f"\n{'controller':14s} {'case':>5s}  {'RMS e1, e2 [rad], e3 [m]':>30s}  {'max e3 window [m]':>17s}  "
          f"{'peak |tau| [N m, N m, N]':>26s}")
    for name, cases in metrics.items():
        if name.startswith("_"):
            continue
        for case, m in cases.items():
            rms = " ".join(f"{v:9.2e}" for v in m["rms_err"])
            peak = " ".join(f"{v:8.1f}" for v in m["peak_tau"])
            print(f"{name:14s} {case:>5s}  {rms:>30s}  {m['max_err_payload'][2]:17.3e}  {peak:>26s}")
