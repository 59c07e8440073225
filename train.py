"""Train the IK network: data -> centres and widths -> weights -> growth -> refinement -> checkpoint.

    python train.py                       # ACO centres and widths, refined, M = 80
    python train.py centers=kmeans rbfn.num_centers=40 seed=1
    python train.py -m centers=aco,kmeans rbfn.num_centers=10,40,160

Writes checkpoint.pt, ik.onnx, ik.pt2, metrics.json, TensorBoard events and train.log into the
Hydra run directory. Running again in a directory holding an interrupted run's last.pt continues
it (name it: hydra.run.dir=DIR), ending with the result an uninterrupted run has; a directory
another process is using, a finished run with another config, or another command's metrics.json
(evaluate.py's) is refused and left exactly as it was. The default directory is named after the
clock: a second run started in the same second takes DIR_1 (rbfn.studies.rundir). SIGTERM or
SIGHUP stop the run, its multirun's workers included, after their cleanup, with exit status
128 + the signal's number (rbfn.studies.stop).
"""
from __future__ import annotations

import atexit
import gc
import logging
from pathlib import Path
from typing import cast

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from torch.utils.tensorboard import SummaryWriter

from rbfn.config import TrainConfig, plain, register_configs, validate_train
from rbfn.data import check_finite, make_dataset
from rbfn.pipeline import train_ik
from rbfn.resume import DifferentRun, StateFile
from rbfn.robots.robot import load_robot
from rbfn.studies.cli import one_line_errors
from rbfn.studies.ik import training_metrics, write_training
from rbfn.studies.rundir import RunDir, RunDirInUse, hydra_run_dir, hydra_run_files, write_json, write_text
from rbfn.studies.stop import job, stop_on_signals

register_configs()
log = logging.getLogger("train")


def run(cfg: TrainConfig, out_dir: Path, run_files: dict[str, str] | None = None) -> dict:
    """Train one IK network with `cfg` into `out_dir`; return its metrics.

    Every check (config, robot, data, a run already in the directory) happens before anything is
    written; `run_files` (relative path -> text, e.g. the composed config) are written after them.
    """
    validate_train(cfg)
    with RunDir(out_dir):
        states = StateFile(out_dir)
        state = states.load(plain(cfg))       # refuses another config's run before any write
        if state.finished is not None:
            log.info("%s holds a finished run with this config; nothing to do (delete it to train again)", out_dir)
            return state.finished
        if state.done or state.current:
            log.info("resuming from %s: %d growth step(s) done", states.path, len(state.done))
        if cfg.num_threads:
            torch.set_num_threads(cfg.num_threads)
        torch.manual_seed(cfg.seed)

        # 1. Data: seeded joint samples in the branch's box, FK positions from the URDF.
        robot = load_robot(cfg.robot, cfg.device)
        data = make_dataset(robot, (cfg.data.n_train, cfg.data.n_val, cfg.data.n_test), cfg.seed)
        for name, split in (("train", data.train), ("val", data.val), ("test", data.test)):
            check_finite(f"{name} positions", split.x)
            check_finite(f"{name} joints", split.q)
        for rel, text in (run_files or {}).items():
            write_text(out_dir / rel, text)

        # 2-5. Centres and widths, weights, growth, refinement (rbfn.pipeline); 6. outputs.
        writer = SummaryWriter(log_dir=str(out_dir))
        try:
            result = train_ik(cfg, data, states, state, robot)
            metrics = training_metrics(cfg, result, robot, data)
            write_training(out_dir, cfg, robot, result, metrics, writer)
        finally:
            writer.close()
        state.finished = metrics
        states.save(state)
    log.info("M = %d, test position error median %.3f mm, p95 %.3f mm, max %.3f mm (float32 median %.3f mm); "
             "selection %.1f s, total %.1f s -> %s", metrics["num_centers"], metrics["test_pos_err_mm_median"],
             metrics["test_pos_err_mm_p95"], metrics["test_pos_err_mm_max"],
             metrics["test_pos_err_mm_median_float32"], metrics["select_seconds"], metrics["train_seconds"], out_dir)
    return metrics


@hydra.main(version_base="1.3", config_path="conf", config_name="train")
def main(dcfg: DictConfig) -> float:
    cfg = cast(TrainConfig, OmegaConf.to_object(dcfg))
    hc = HydraConfig.get()
    with one_line_errors(hc.mode == RunMode.RUN), job(), hydra_run_dir() as out_dir:
        try:
            metrics = run(cfg, out_dir, hydra_run_files(dcfg, out_dir))
        except Exception as e:
            # A multirun goes on past a failed job; its error and overrides go to RUN_DIR/failed.json
            # for `python -m rbfn.summarize` (never into a directory another process is using).
            # A refused job (directory in use, or another config's run there) writes nothing.
            if hc.mode == RunMode.MULTIRUN and not isinstance(e, (RunDirInUse, DifferentRun)):
                log.error("job failed: %s: %s", type(e).__name__, e)
                write_json(out_dir / "failed.json", {"error": type(e).__name__, "message": str(e),
                                                     "overrides": list(hc.overrides.task)})
            raise
    return metrics["val_E"]  # the validation objective, for sweepers


if __name__ == "__main__":
    # Exit without the interpreter's final garbage collections over the ~300k objects torch, Hydra
    # and matplotlib hold (0.6-0.8 s a run, measured): frozen objects are not scanned.
    atexit.register(gc.freeze)
    stop_on_signals()
    main()
