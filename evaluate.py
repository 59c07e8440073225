"""Evaluate: IK accuracy of a trained network on a fresh test set, and the closed-loop scenario.

    python evaluate.py                          # newest outputs/**/checkpoint.pt, then control
    python evaluate.py checkpoint=PATH n_test=20000
    python evaluate.py gains=paper ik=false     # the closed loop alone, the paper's gains

With no checkpoint given and none found, the IK part is skipped and the control part runs alone.
Parts: `ik` (accuracy on a fresh test set), `online` (the network adapting by LMS on a robot
whose kinematics differ from its model; writes checkpoint_online.pt), `control` (every
controller on every payload case). Writes metrics.json (`ik`, `online`, `control`),
workspace_error_map.png, online_task_error.png, control_<controller>.png and TensorBoard events
into the Hydra run directory.
"""
from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import hydra
import numpy as np
import torch
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf
from torch.utils.tensorboard import SummaryWriter

from rbfn.config import ControlConfig, GainsConfig, OnlineConfig, validate_control, validate_online
from rbfn.control.online_study import evaluate_online
from rbfn.control.study import print_control_table, run_control
from rbfn.checkpoint import atomic_write_bytes, model_from_checkpoint, read_checkpoint
from rbfn.data import make_split
from rbfn.plots import workspace_error_map
from rbfn.robots import forward_kinematics, load_serial_chain

# Test-set stream index: training draws streams seed * 1000 + {0, 1, 2}, never this one.
EVAL_STREAM = 777


@dataclass
class EvalConfig:
    checkpoint: Optional[str] = None   # null: the newest checkpoint.pt under outputs_dir
    outputs_dir: str = "outputs"
    ik: bool = True                    # the IK part (needs a checkpoint)
    n_test: int = 10000
    seed: Optional[int] = None         # null: the training seed's fresh evaluation stream
    device: str = "cpu"
    num_threads: int = 0
    gains: GainsConfig = field(default_factory=GainsConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    online: OnlineConfig = field(default_factory=OnlineConfig)


ConfigStore.instance().store(name="evaluate_schema", node=EvalConfig)
ConfigStore.instance().store(group="gains", name="gains_schema", node=GainsConfig)


def find_checkpoint(cfg: EvalConfig) -> Optional[Path]:
    """The checkpoint to evaluate: `cfg.checkpoint`, or the newest one under `cfg.outputs_dir`
    (None when there is none)."""
    if cfg.checkpoint:
        path = Path(to_absolute_path(cfg.checkpoint))
        if not path.is_file():
            raise FileNotFoundError(f"checkpoint={cfg.checkpoint}: no such file ({path})")
        return path
    root = Path(to_absolute_path(cfg.outputs_dir))
    found = sorted(root.glob("**/checkpoint.pt"), key=lambda p: p.stat().st_mtime)
    if not found:
        print(f"no checkpoint.pt under {root} (run `python train.py` or pass checkpoint=PATH): "
              "skipping the IK part")
        return None
    print(f"evaluating the newest checkpoint: {found[-1]}")
    return found[-1]


def evaluate_ik(ckpt_path: Path, cfg: EvalConfig, out_dir: Path, writer: SummaryWriter) -> dict:
    """IK accuracy of a checkpoint on a fresh test set, in float64 and float32."""
    ckpt = read_checkpoint(ckpt_path)
    model = model_from_checkpoint(ckpt).to(cfg.device)
    robot = ckpt["robot"]
    chain = load_serial_chain(robot["urdf"], robot["end_link"], torch.float64, cfg.device)
    low = torch.tensor(robot["joint_low"], dtype=torch.float64)
    high = torch.tensor(robot["joint_high"], dtype=torch.float64)
    seed = ckpt["config"]["seed"] * 1000 + EVAL_STREAM if cfg.seed is None else cfg.seed
    test = make_split(chain, low, high, cfg.n_test, seed)
    out: dict = {"checkpoint": str(ckpt_path), "num_centers": model.num_centers, "test_seed": seed}
    for dtype, suffix in ((torch.float64, ""), (torch.float32, "_float32")):
        m = copy.deepcopy(model).to(dtype)
        with torch.no_grad():
            q_hat, inside = m.solve(test.x.to(dtype))
        q_hat = q_hat.double()
        err_mm = (forward_kinematics(chain, q_hat) - test.x).norm(dim=-1) * 1000.0
        jerr = q_hat - test.q
        out[f"test_joint_rmse{suffix}"] = float(jerr.square().mean().sqrt())
        for j, r in enumerate(jerr.square().mean(0).sqrt().tolist()):
            out[f"test_joint{j + 1}_rmse{suffix}"] = r
        out[f"test_pos_err_mm_median{suffix}"] = float(err_mm.median())
        out[f"test_pos_err_mm_p95{suffix}"] = float(err_mm.quantile(0.95))
        out[f"test_pos_err_mm_max{suffix}"] = float(err_mm.max())
        out[f"test_in_workspace{suffix}"] = float(inside.double().mean())
        if dtype == torch.float64:
            fig = workspace_error_map(test.x.cpu().numpy(), err_mm.cpu().numpy(), inside.cpu().numpy(),
                                      f"IK position error, M = {model.num_centers}")
            fig.savefig(out_dir / "workspace_error_map.png", dpi=120)
            writer.add_figure("ik/workspace_error_map", fig)
    for k, v in out.items():
        if isinstance(v, float):
            writer.add_scalar(f"ik/{k}", v)
    print_table("IK accuracy on a fresh test set "
                f"({cfg.n_test} samples, seed {seed})", out)
    return out


def print_table(title: str, m: dict) -> None:
    rows = [("joint RMSE", "test_joint_rmse", 1.0, ""), ("position error median", "test_pos_err_mm_median", 1, "mm"),
            ("position error p95", "test_pos_err_mm_p95", 1, "mm"), ("position error max", "test_pos_err_mm_max", 1, "mm"),
            ("flagged in workspace", "test_in_workspace", 100, "%")]
    print(f"\n{title}\n{'':24s} {'float64':>12s} {'float32':>12s}")
    for name, key, mul, unit in rows:
        print(f"{name:24s} {m[key] * mul:12.4g} {m[key + '_float32'] * mul:12.4g} {unit}")


@hydra.main(version_base="1.3", config_path="conf", config_name="evaluate")
def main(dcfg: DictConfig) -> None:
    cfg: EvalConfig = OmegaConf.to_object(dcfg)
    if cfg.n_test <= 0:
        raise ValueError(f"n_test={cfg.n_test} must be > 0")
    validate_control(cfg.control, cfg.gains)
    validate_online(cfg.online)
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    writer = SummaryWriter(log_dir=str(out_dir))
    metrics: dict = {}
    ckpt = find_checkpoint(cfg) if cfg.ik else None
    if ckpt is not None:
        metrics["ik"] = evaluate_ik(ckpt, cfg, out_dir, writer)
        # Flat IK keys at the top level too, as train.py writes them.
        metrics.update({k: v for k, v in metrics["ik"].items() if k.startswith("test_")})
    if cfg.online.enabled and ckpt is not None:
        metrics["online"] = evaluate_online(ckpt, cfg.online, cfg.gains, cfg.device, writer, out_dir)
    if cfg.control.enabled:
        control = run_control(cfg.control, cfg.gains, cfg.device, writer, out_dir)
        metrics["control_info"] = control.pop("_info")
        metrics["control"] = control
        print_control_table(control)
    writer.close()
    text = json.dumps(metrics, indent=2).encode()
    atomic_write_bytes(out_dir / "metrics.json", lambda f: f.write(text))
    print(f"-> {out_dir}")


if __name__ == "__main__":
    main()
