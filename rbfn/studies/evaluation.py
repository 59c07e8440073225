"""Evaluating a checkpoint and the controllers into a run directory: evaluate.py's procedure.

Parts: `ik` (accuracy; needs a checkpoint), `online` (`online.enabled`; needs a checkpoint; runs
on the checkpoint's robot), `control` (`control.enabled`, on `robot`). Every setting is checked
before any part starts (`check`); the checkpoint's parts run in a forked process beside the
control part where that is safe (rbfn.studies.beside).
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from pathlib import Path

import torch
from hydra.utils import to_absolute_path
from torch.utils.tensorboard import SummaryWriter

from ..checkpoint import read_checkpoint
from ..config import EvalConfig, validate_evaluate
from ..robots.derive import derive_evaluate
from .beside import Beside, can_fork
from .control import check_control, evaluate_control
from .ik import evaluate_ik
from .online import check_online, evaluate_online
from .plots import robot_label
from .rundir import RunDir, write_json, write_text

__all__ = ["check", "checkpoint_parts", "evaluate_parts", "evaluated_robots", "find_checkpoint", "run"]

log = logging.getLogger("evaluate")


def find_checkpoint(cfg: EvalConfig) -> Path | None:
    """`cfg.checkpoint`, or the newest checkpoint.pt under `cfg.outputs_dir` (None when there is none)."""
    if cfg.checkpoint:
        path = Path(to_absolute_path(cfg.checkpoint))
        if not path.exists():
            raise FileNotFoundError(f"checkpoint={cfg.checkpoint}: no such file ({path})")
        return path
    root = Path(to_absolute_path(cfg.outputs_dir))
    found = sorted(root.glob("**/checkpoint.pt"), key=lambda p: p.stat().st_mtime)
    return found[-1] if found else None


@contextmanager
def _torch_threads(n: int | None):
    """torch's intra-op threads set to `n` inside the block and restored after it (None: unchanged)."""
    before = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if n is not None:
            torch.set_num_threads(before)


@contextmanager
def _timed(seconds: dict, part: str):
    """Record the wall seconds of one part under `seconds[part]` and log them."""
    t0 = time.perf_counter()
    yield
    seconds[part] = time.perf_counter() - t0
    log.info("%s part: %.1f s", part, seconds[part])


def checkpoint_parts(ckpt: dict, path: Path, cfg: EvalConfig, out_dir: Path) -> tuple[dict, dict[str, float]]:
    """The parts that evaluate the checkpoint, `ik` and `online` (as enabled), with a TensorBoard
    writer of their own (they may run in another process): (metrics, wall seconds per part)."""
    metrics: dict = {}
    seconds: dict[str, float] = {}
    writer = SummaryWriter(log_dir=str(out_dir), filename_suffix=".checkpoint")
    try:
        if cfg.ik:
            with _timed(seconds, "ik"):
                metrics["ik"] = evaluate_ik(ckpt, path, cfg, out_dir, writer)
            # Flat IK keys at the top level too, as train.py writes them.
            metrics.update({k: v for k, v in metrics["ik"].items() if k.startswith("test_")})
        if cfg.online.enabled:
            with _timed(seconds, "online"):
                metrics["online"] = evaluate_online(ckpt, cfg.online, cfg.gains, cfg.device, writer, out_dir)
    finally:
        writer.close()
    return metrics, seconds


def check(cfg: EvalConfig) -> tuple[Path | None, dict | None]:
    """Every setting checked before any work: (the checkpoint's path, its dict), both None when
    no part needs one or none was found."""
    validate_evaluate(cfg)
    if cfg.control.enabled:
        check_control(cfg.control, cfg.robot)  # the robot's URDF, joints and payload link, before any work
    if not (cfg.ik or cfg.online.enabled or cfg.control.enabled):
        raise ValueError("nothing to evaluate: ik, online.enabled and control.enabled are all false; enable a part")
    path = find_checkpoint(cfg) if cfg.ik or cfg.online.enabled else None
    ckpt = read_checkpoint(path) if path is not None else None  # a bad file stops before any work
    if ckpt is None and not cfg.control.enabled:
        root = Path(to_absolute_path(cfg.outputs_dir))
        why = "no such directory" if not root.is_dir() else "no checkpoint.pt below it"
        raise ValueError(
            f"nothing to evaluate: outputs_dir={cfg.outputs_dir!r} ({root}): {why}, and "
            "control.enabled=false; train first, pass checkpoint=PATH, or enable the control part"
        )
    if ckpt is not None and cfg.online.enabled:
        check_online(cfg.online, ckpt["robot"])  # the path and perturbation suit the checkpoint's robot
    return path, ckpt


def run(cfg: EvalConfig, out_dir: Path, run_files: dict[str, str] | None = None) -> dict:
    """Evaluate every enabled part into `out_dir`, a new or empty directory held for the run
    (rbfn.studies.rundir); return metrics.json's content. Nothing is written before every check
    passed; `run_files` (relative path -> text, e.g. the composed config) are written first then.
    robot=urdf's keys left to derive are filled from the URDF first (rbfn.robots.derive)."""
    cfg = derive_evaluate(cfg)
    path, ckpt = check(cfg)
    with RunDir(out_dir, own=True):
        for rel, text in (run_files or {}).items():
            write_text(out_dir / rel, text)
        metrics = evaluate_parts(cfg, path, ckpt, out_dir)
        write_json(out_dir / "metrics.json", metrics)
        log.info("-> %s", out_dir)
    return metrics


def evaluate_parts(cfg: EvalConfig, path: Path | None, ckpt: dict | None, out_dir: Path) -> dict:
    """Every enabled part of a checked config (`check`): the content of metrics.json."""
    if path is not None and not cfg.checkpoint:
        log.info("evaluating the newest checkpoint: %s", path)
    robots, skipped = evaluated_robots(cfg, ckpt)
    for part, why in skipped.items():
        log.info("%s part skipped: %s", part, why)
    if len(set(robots.values())) > 1:
        log.warning(
            "the parts evaluate different robots: %s (the IK and online parts run on the checkpoint's "
            "robot, the control part on robot=%s)",
            robots,
            cfg.robot.name,
        )
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    metrics: dict = {}
    seconds: dict[str, float] = {}
    # The checkpoint's parts run in a forked process beside the control part where that is safe
    # (rbfn.studies.beside), started before this process's TensorBoard writer and its thread.
    both = ckpt is not None and cfg.control.enabled and cfg.parallel and can_fork(cfg.device)
    # The forked parts keep a core busy: this process takes one thread too while they run. Two
    # threads here beside them measured the control part 1.2x slower and its centre selection 2-4x.
    one = both and not cfg.num_threads
    with _torch_threads(1 if one else None), Beside(checkpoint_parts, ckpt, path, cfg, out_dir, fork=both) as beside:
        if cfg.control.enabled:
            writer = SummaryWriter(log_dir=str(out_dir))
            try:
                with _timed(seconds, "control"):
                    control = evaluate_control(
                        cfg.control, cfg.gains, cfg.device, writer, out_dir, cfg.robot, cfg.parallel, cfg.loop
                    )
            finally:
                writer.close()
        if ckpt is not None:
            part_metrics, part_seconds = beside.result()
            metrics.update(part_metrics)
            seconds.update(part_seconds)
        if cfg.control.enabled:
            metrics.update(control)
    metrics["evaluate_seconds"] = seconds
    metrics["robots"], metrics["skipped"] = robots, skipped
    return metrics


def evaluated_robots(cfg: EvalConfig, ckpt: dict | None) -> tuple[dict[str, str], dict[str, str]]:
    """(the robot each part that runs evaluates, as "name (end link, n joints)"; each enabled part
    that does not run, and why): metrics.json's `robots` and `skipped`."""
    robots, skipped = {}, {}
    if ckpt is not None:
        r = ckpt["robot"]
        label = f"{robot_label(r.get('name', ''), r['urdf'])} ({r['end_link']}, {len(r['joint_low'])} joints)"
        robots.update({part: label for part, on in (("ik", cfg.ik), ("online", cfg.online.enabled)) if on})
    else:
        why = f"no checkpoint.pt under outputs_dir={cfg.outputs_dir!r} (train first, or pass checkpoint=PATH)"
        skipped.update({part: why for part, on in (("ik", cfg.ik), ("online", cfg.online.enabled)) if on})
    if cfg.control.enabled:
        r = cfg.robot
        name = robot_label(r.name, Path(r.urdf) if r.urdf else r.name)
        robots["control"] = f"{name} ({r.end_link}, {len(r.joint_low)} joints)"
    return robots, skipped
