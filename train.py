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

import signal

if __name__ == "__main__":  # Ctrl-C while the imports below load: ends at once, status 130 (then rbfn.studies.stop)
    signal.signal(signal.SIGINT, signal.SIG_DFL)

import atexit
import gc
import logging
from typing import cast

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from rbfn.config import TrainConfig
from rbfn.resume import DifferentRun
from rbfn.studies.cli import check_overrides, one_line_errors, register_configs, run_main, settings
from rbfn.studies.rundir import RunDirInUse, hydra_run_dir, hydra_run_files, relabel, write_json
from rbfn.studies.stop import job
from rbfn.studies.training import run

__all__ = ["main", "run"]

register_configs()
log = logging.getLogger("train")


@hydra.main(version_base="1.3", config_path="conf", config_name="train")
def main(dcfg: DictConfig) -> float:
    hc = HydraConfig.get()
    with one_line_errors(hc.mode == RunMode.RUN), job(), hydra_run_dir() as out_dir:
        try:
            check_overrides(TrainConfig, hc.overrides.task)  # as typed: OmegaConf would take export=2 for true
            out_dir = relabel(out_dir, dcfg.robot.name or "urdf")  # TIME_ROBOT: TensorBoard's run name
            metrics = run(cast(TrainConfig, settings(dcfg)), out_dir, hydra_run_files(dcfg, out_dir))
        except Exception as e:
            # A multirun goes on past a failed job; its error and overrides go to RUN_DIR/failed.json
            # for `python -m rbfn.studies.summarize` (never into a directory another process is using).
            # A refused job (directory in use, or another config's run there) writes nothing.
            if hc.mode == RunMode.MULTIRUN and not isinstance(e, (RunDirInUse, DifferentRun)):
                log.error("job failed: %s: %s", type(e).__name__, e)
                write_json(
                    out_dir / "failed.json",
                    {"error": type(e).__name__, "message": str(e), "overrides": list(hc.overrides.task)},
                )
            raise
    return metrics["val_E"]  # the validation objective, for sweepers


if __name__ == "__main__":
    # Exit without the interpreter's final garbage collections over the ~300k objects torch, Hydra
    # and matplotlib hold (0.6-0.8 s a run, measured): frozen objects are not scanned.
    atexit.register(gc.freeze)
    run_main(main)
