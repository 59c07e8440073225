"""Evaluate: IK accuracy of a trained network on a fresh test set, its online adaptation on a robot
whose kinematics differ from its model, and the closed-loop controller comparison.

    python evaluate.py                          # newest outputs/**/checkpoint.pt; every part
    python evaluate.py checkpoint=PATH n_test=20000
    python evaluate.py gains=paper ik=false online.enabled=false   # the closed loop alone

Parts: `ik` (accuracy; needs a checkpoint), `online` (`online.enabled`; needs a checkpoint; writes
checkpoint_online.pt), `control` (`control.enabled`: every controller on every payload case).
Every part runs on the checkpoint's robot, with its gains and realistic-loop facts (the config is
composed again for it: rbfn.studies.evaluation.for_checkpoint); a robot= or robot.* override naming
another robot is refused. With no checkpoint given and none found, the two checkpoint parts are
skipped (and said so), and the `robot` group chooses the control part's robot.
The checkpoint's parts run in a forked process beside the control part, and half the control
figures in another (`parallel`, on by default; used where the machine forks, has two cores or
more, and the device is the CPU); each process then runs one torch thread (unless `num_threads`
says otherwise).
Every setting is checked before any part starts. Writes metrics.json (`ik`, `online`, `control`,
`control_info`, `evaluate_seconds`: each part's wall seconds), workspace_error_map.png,
online_task_error.png, control_<controller>.png, TensorBoard events, evaluate.log and .hydra/ into
the Hydra run directory, which must be new or empty: a directory holding files (a training run's,
another evaluation's) is refused, never written over. The default directory is named after the
clock: a second evaluation started in the same second takes DIR_1 (rbfn.studies.rundir). A refused
evaluation writes nothing and leaves no directory behind. SIGTERM or SIGHUP stop it, its forked
parts included, after their cleanup, with exit status 128 + the signal's number (rbfn.studies.stop).
"""

from __future__ import annotations

import signal

if __name__ == "__main__":  # Ctrl-C while the imports below load: ends at once, status 130 (then rbfn.studies.stop)
    signal.signal(signal.SIGINT, signal.SIG_DFL)

import atexit
import gc
from typing import cast

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from rbfn.config import EvalConfig
from rbfn.studies.cli import check_overrides, one_line_errors, register_configs, run_main, settings
from rbfn.studies.evaluation import for_checkpoint, run
from rbfn.studies.rundir import hydra_run_dir, hydra_run_files, relabel
from rbfn.studies.stop import job

__all__ = ["main", "run"]

register_configs()


@hydra.main(version_base="1.3", config_path="conf", config_name="evaluate")
def main(dcfg: DictConfig) -> None:
    with one_line_errors(HydraConfig.get().mode == RunMode.RUN), job(), hydra_run_dir(own=True) as out_dir:
        check_overrides(EvalConfig, HydraConfig.get().overrides.task)  # as typed: OmegaConf would take ik=2 for true
        dcfg = for_checkpoint(dcfg, HydraConfig.get().overrides.task)  # the checkpoint's robot, before any work
        out_dir = relabel(out_dir, dcfg.robot.name or "urdf")  # TIME_ROBOT: TensorBoard's run name
        run(cast(EvalConfig, settings(dcfg)), out_dir, hydra_run_files(dcfg, out_dir))


if __name__ == "__main__":
    # Exit without the interpreter's final garbage collections over the ~300k objects torch, Hydra
    # and matplotlib hold (0.6-0.8 s a run, measured): frozen objects are not scanned.
    atexit.register(gc.freeze)
    run_main(main)
