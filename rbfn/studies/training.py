"""Training one IK network into a run directory: train.py's procedure (rbfn.pipeline does the
fitting), with the run directory's checks, resumable state and outputs around it."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torch.utils.tensorboard import SummaryWriter

from ..charts import save_charts, train_charts
from ..config import TrainConfig, Workspace, plain, validate_train
from ..data import check_finite, full_range_split, make_dataset
from ..export import export_all
from ..memory import check_train
from ..pipeline import train_ik
from ..resume import DifferentRun, StateFile, TrainState, comparable
from ..robots.derive import derive_train
from ..robots.robot import Robot, check_ik_is_function, load_robot
from .cli import announced
from .ik import charted_line, charted_metrics, training_metrics, write_training
from .rundir import RunDir, bookkeeping, write_json, write_summary, write_text

__all__ = ["claim", "outputs", "run"]

log = logging.getLogger("train")


def run(cfg: TrainConfig, out_dir: Path, run_files: dict[str, str] | None = None) -> dict:
    """Train one IK network with `cfg` into `out_dir`; return its metrics.

    Every check (config, robot, data, a run already in the directory) happens before anything is
    written; `run_files` (relative path -> text, e.g. the composed config) are written after them.
    robot=urdf's keys left to derive are filled from the URDF first (rbfn.robots.derive).
    """
    cfg = derive_train(cfg)
    validate_train(cfg)
    check_train(cfg)  # the run fits in memory
    robot = load_robot(cfg.robot, cfg.device)
    check_ik_is_function(robot.target, robot.joint_names, cfg.robot.locked, cfg.robot.redundancy)
    full = cfg.robot.workspace == Workspace.full
    with RunDir(out_dir):
        states = StateFile(out_dir)
        state = states.load(plain(cfg))  # refuses another config's run before any write
        claim(out_dir, state, cfg.export, (run_files or {}).get(_CONFIG_FILE))
        if state.finished is not None:
            log.info("%s holds a finished run with this config; nothing to do (delete it to train again)", out_dir)
            return state.finished
        if state.done or state.current:
            log.info("resuming from %s: %d growth step(s) done", states.path, len(state.done))
        if cfg.num_threads:
            torch.set_num_threads(cfg.num_threads)
        torch.manual_seed(cfg.seed)
        if full:
            metrics = _fit_charts(cfg, robot, out_dir, run_files)
        else:
            metrics = _fit_box(cfg, robot, out_dir, run_files, states, state)
        state.finished = metrics
        states.save(state)
    if full:
        log.info("%s, trained in %.0f s -> %s", charted_line(metrics), metrics["train_seconds"], out_dir)
        return metrics
    log.info(
        "M = %d, test position error median %.3f mm, p95 %.3f mm, max %.3f mm (float32 median %.3f mm); "
        "centres chosen by %s, selection %.1f s, total %.1f s -> %s",
        metrics["num_centers"],
        metrics["test_pos_err_mm_median"],
        metrics["test_pos_err_mm_p95"],
        metrics["test_pos_err_mm_max"],
        metrics["test_pos_err_mm_median_float32"],
        metrics.get("centers_chosen_by", cfg.centers.method),  # (a finished run's metrics from before it)
        metrics["select_seconds"],
        metrics["train_seconds"],
        out_dir,
    )
    return metrics


_CONFIG_FILE = ".hydra/config.yaml"


def _fit_box(
    cfg: TrainConfig,
    robot: Robot,
    out_dir: Path,
    run_files: dict[str, str] | None,
    states: StateFile,
    state: TrainState,
) -> dict:
    """`run`'s work for one box network (robot.workspace=box): data, the fit (resumable through
    `states` and `state`), checkpoint.pt, the exports, metrics.json; returns the metrics."""
    # 1. Data: seeded joint samples in the branch's box, FK positions from the URDF.
    d = cfg.data
    with announced(log, "data", f"{d.n_train} / {d.n_val} / {d.n_test} samples (train / val / test)", cfg.progress):
        data = make_dataset(robot, (d.n_train, d.n_val, d.n_test), cfg.seed)
        for name, split in (("train", data.train), ("val", data.val), ("test", data.test)):
            check_finite(f"{name} positions", split.x)
            check_finite(f"{name} joints", split.q)
    for rel, text in (run_files or {}).items():
        write_text(out_dir / rel, text)

    # 2-5. Centres and widths, weights, growth, refinement (rbfn.pipeline); 6. outputs.
    writer = SummaryWriter(log_dir=str(out_dir))
    try:
        with announced(log, "fit", _fit_what(cfg), cfg.progress) as fit:
            result = train_ik(cfg, data, states, state, robot, progress=fit["progress"])
        outputs = "checkpoint.pt" + (", ik.onnx, ik.pt2" if cfg.export else "") + ", metrics.json"
        with announced(log, "outputs", f"test accuracy (raw and polished), {outputs}", cfg.progress):
            metrics = training_metrics(cfg, result, robot, data)
            write_training(out_dir, cfg, robot, result, metrics, writer)
    finally:
        writer.close()
    return metrics


def _fit_charts(cfg: TrainConfig, robot: Robot, out_dir: Path, run_files: dict[str, str] | None) -> dict:
    """`run`'s work for robot.workspace=full: the charted network (`rbfn.charts.train_charts`) into
    checkpoint.pt (`rbfn.charts.save_charts`) and metrics.json (`rbfn.studies.ik.charted_metrics`);
    returns the metrics. The charts train in one piece (a stopped run starts over)."""
    for rel, text in (run_files or {}).items():
        write_text(out_dir / rel, text)
    r = cfg.robot
    what = f"{r.charts} charts of the joint space, {r.chart_samples} samples and M = {r.chart_centers} each"
    with announced(log, "fit", f"{what}, centers={cfg.centers.name}", cfg.progress) as fit:
        t0 = time.perf_counter()
        charted = train_charts(cfg, robot, progress=fit["progress"])
        seconds, model = time.perf_counter() - t0, charted.model
    files = "checkpoint.pt" + (", ik.onnx, ik.pt2" if cfg.export else "") + ", metrics.json"
    with announced(log, "outputs", f"box and whole-range figures, {files}", cfg.progress):
        d = cfg.data
        box = make_dataset(robot, (2, 1, d.n_test), cfg.seed).test  # the box run's test poses
        full = full_range_split(robot, d.n_test, cfg.seed)
        metrics = {
            "num_centers": model.first.num_centers,
            "selector": cfg.centers.name,
            "target": str(robot.target),
            **charted_metrics(model, robot, box, full),
            "val_E": charted.val_E,
            "train_seconds": seconds,
            "seconds_a_chart": charted.seconds_a_chart,
        }
        save_charts(out_dir / "checkpoint.pt", model, robot.record(), plain(cfg), metrics)
        if cfg.export:
            export_all(model, out_dir, robot=robot)  # every chart's answer, to deploy without this package
        write_json(out_dir / "metrics.json", metrics)
        writer = SummaryWriter(log_dir=str(out_dir))
        try:
            write_summary(writer, "train/summary", metrics)
        finally:
            writer.close()
    return metrics


def outputs(export: bool) -> tuple[str, ...]:
    """The files a finished training run leaves in its directory, beside last.pt and its bookkeeping
    (`rbfn.studies.rundir`: .hydra/, train.log, TensorBoard events)."""
    return ("checkpoint.pt", *(("ik.onnx", "ik.pt2") if export else ()), "metrics.json")


def claim(out_dir: Path, state: TrainState, export: bool, config_text: str | None = None) -> None:
    """Refuse `out_dir` unless it is this run's to write: new or empty, this configuration's
    interrupted run (its last.pt, loaded as `state`), or this configuration's finished run with
    every output in place. Every file a run writes decides: results (checkpoint.pt, metrics.json,
    the exports) without the last.pt that says whose they are, files no run wrote, another
    configuration's composed config (.hydra/config.yaml; `config_text` is this run's), or a finished
    run missing some of its outputs are refused, and the directory is left exactly as it was."""
    names = sorted(os.listdir(out_dir))
    listed = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
    fix = "give train.py a new or empty hydra.run.dir"
    if state.finished is not None:
        missing = [name for name in outputs(export) if not (out_dir / name).is_file()]
        if missing:
            raise DifferentRun(
                f"hydra.run.dir={out_dir} holds a finished run with this config whose "
                f"{', '.join(missing)} {'is' if len(missing) == 1 else 'are'} missing, so it is not reported as done "
                f"nor written again; restore {'it' if len(missing) == 1 else 'them'} (`python -m rbfn.export "
                f"{out_dir / 'checkpoint.pt'}` writes the exports), delete the directory to train again, or {fix}"
            )
        return
    if state.done or state.current:
        return  # this configuration's interrupted run: its own files, resumed
    # A multirun job's failed.json (train.py) records a failure a rerun of the sweep replaces.
    foreign = [name for name in names if not bookkeeping(name) and name != "failed.json"]
    if foreign:
        raise DifferentRun(
            f"hydra.run.dir={out_dir} holds files ({listed}) but no training state (last.pt) saying whose "
            f"they are: another run's results, or files no run wrote, which training would write over; {fix}"
        )
    config = out_dir / _CONFIG_FILE
    if config_text is not None and config.is_file() and not _same_config(config.read_text(), config_text):
        raise DifferentRun(
            f"hydra.run.dir={out_dir} holds {_CONFIG_FILE} of a run with a different configuration (stopped "
            f"before its first result), which this run would write over; resume it with the same overrides, or {fix}"
        )


def _same_config(a: str, b: str) -> bool:
    """Whether two composed configs (YAML) differ only in keys a resumed run may change."""
    plain_a, plain_b = (OmegaConf.to_container(OmegaConf.create(text)) for text in (a, b))
    if not isinstance(plain_a, dict) or not isinstance(plain_b, dict):
        return False
    return comparable(plain_a) == comparable(plain_b)


def _fit_what(cfg: TrainConfig) -> str:
    """What the fit will do and how big, for its first log line."""
    r = cfg.rbfn
    growth = f"grown from M = {r.growth.start}" if r.growth.start else "no growth"
    return f"centers={cfg.centers.name}, M = {r.num_centers} ({growth}), weights by {r.solver}"
