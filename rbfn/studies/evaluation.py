"""Evaluating a checkpoint and the controllers into a run directory: evaluate.py's procedure.

Parts: `ik` (accuracy; needs a checkpoint), `online` (`online.enabled`; needs a checkpoint),
`control` (`control.enabled`). Every part evaluates one robot: the checkpoint's where one is
evaluated (`for_checkpoint` composes the config for it; its URDF text, not a file, is what the
control part loads), else the `robot` group's. Every setting is checked before any part starts
(`check`); the checkpoint's parts run in a forked process beside the control part where that is
safe (rbfn.studies.beside).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import fields
from pathlib import Path
from typing import cast

import torch
from hydra import compose
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf
from torch.utils.tensorboard import SummaryWriter

from ..checkpoint import CHARTS_KIND, read_checkpoint, refuse_url
from ..config import ROBOT_PRESETS, EvalConfig, RobotConfig, network_method, validate_evaluate
from ..control.robot_setup import payload_cases
from ..memory import check_evaluate
from ..robots.derive import derive_evaluate
from ..robots.dynamics import urdf_source
from ..solver import CHARTED_ITERATIONS, DEFAULT_ITERATIONS
from .beside import Beside, can_fork
from .cli import announced
from .control import check_control, evaluate_control
from .ik import evaluate_ik
from .online import check_online, evaluate_online
from .plots import robot_label
from .rundir import RunDir, write_json, write_text

__all__ = [
    "check",
    "checkpoint_parts",
    "evaluate_parts",
    "evaluated_robots",
    "find_checkpoint",
    "for_checkpoint",
    "run",
    "same_robot",
]

log = logging.getLogger("evaluate")


def find_checkpoint(cfg: EvalConfig) -> Path | None:
    """`cfg.checkpoint`, or the newest checkpoint.pt under `cfg.outputs_dir` (None when there is none)."""
    if cfg.checkpoint:
        refuse_url(cfg.checkpoint, f"checkpoint={cfg.checkpoint}")  # before the "//" folds into a path
        path = Path(to_absolute_path(cfg.checkpoint))
        if not path.exists():
            raise FileNotFoundError(f"checkpoint={cfg.checkpoint}: no such file ({path})")
        return path
    root = Path(to_absolute_path(cfg.outputs_dir))
    found = sorted(root.glob("**/checkpoint.pt"), key=lambda p: p.stat().st_mtime)
    return found[-1] if found else None


# A checkpoint's robot entry -> the robot keys it fixes (the box and target it was trained on).
_ENTRY_KEYS = ("end_link", "locked", "target", "joint_low", "joint_high", "redundancy")


def _entry_label(record: dict) -> str:
    """A checkpoint's robot as metrics.json's `robots` names it: "name (end link, n joints)"."""
    name = robot_label(record.get("name", ""), record["urdf"])
    return f"{name} ({record['end_link']}, {len(record['joint_low'])} joints)"


def _is_preset(record: dict) -> bool:
    """Whether a checkpoint's robot entry is a shipped preset's robot (its name and packaged URDF)."""
    name = record.get("name", "")
    return name in ROBOT_PRESETS and record["urdf"] == urdf_source(name)[0]


def same_robot(robot: RobotConfig, record: dict) -> bool:
    """Whether `robot` is the robot of a checkpoint's robot entry `record`: the same end link and
    locked joints, and the same URDF text or name (robot_label: a URDF's own name where robot.name
    is a leftover preset's). A robot.urdf file that has moved or gone is taken for the checkpoint's
    URDF text, which is what every part loads."""
    if robot.end_link != record["end_link"] or dict(robot.locked) != dict(record.get("locked", {})):
        return False
    source: str | Path = robot.name
    if robot.urdf:
        source = Path(robot.urdf) if Path(robot.urdf).is_file() else record["urdf"]
        if isinstance(source, Path) and urdf_source(source)[0] == record["urdf"]:
            return True
    return robot_label(robot.name, source) == robot_label(record.get("name", ""), record["urdf"])


def _another_robot(path: Path, newest: bool, record: dict, given: str, robot: str | None = None) -> ValueError:
    """The refusal of a config whose robot, chosen by the overrides `given` (after robot=`robot`
    where they leave the group to the checkpoint), is not the checkpoint's."""
    which = f"the newest checkpoint, {path}," if newest else f"checkpoint={path}"
    other = f"robot={robot} {given}" if robot else given
    return ValueError(
        f"{which} holds a network of {_entry_label(record)}, but {given} chooses another robot, and every "
        f"part evaluates the checkpoint's robot: leave {given} out, or evaluate the control part on that robot "
        f"without a checkpoint (ik=false online.enabled=false {other}), or give checkpoint= one of its checkpoints"
    )


def for_checkpoint(dcfg: DictConfig, overrides: Sequence[str]) -> DictConfig:
    """evaluate.py's config `dcfg`, composed from the command-line `overrides` (Hydra initialised),
    for the robot of the checkpoint it evaluates: `dcfg` itself where that is its robot, or where no
    checkpoint part runs or none is found; else composed again with robot=NAME for a shipped preset
    (robot=urdf with the training run's robot keys, robot.derive=false, for a user's arm) before the
    user's overrides, the checkpoint's end link, locked joints, target and box filled in where the
    overrides leave them. So the gains (`gains/robot@gains: ${robot}_${gains}`) and the realistic
    loop's rate and encoders are the checkpoint robot's. ValueError naming both robots, before any
    work, where `overrides` choose another robot (robot=NAME, or robot.* keys)."""
    cfg = cast(EvalConfig, OmegaConf.to_object(dcfg))
    path = find_checkpoint(cfg) if _uses_checkpoint(cfg) else None
    if path is None:
        return dcfg  # the `robot` group decides
    ckpt = read_checkpoint(path)
    record = ckpt["robot"]
    if same_robot(cfg.robot, record):
        return dcfg
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    lines = {o.key_or_group: o.input_line or o.key_or_group for o in parsed}
    given = {k: line for k, line in lines.items() if k == "robot" or k.startswith("robot.")}
    newest = not cfg.checkpoint
    if "robot" in given:
        raise _another_robot(path, newest, record, " ".join(given.values()))
    trained = (ckpt.get("config") or {}).get("robot")
    # A preset's robot, unless trained as robot=urdf (its derived keys, not the preset's, then)
    preset = _is_preset(record) and not (isinstance(trained, dict) and trained.get("derive"))
    choice = record["name"] if preset else "urdf"
    dcfg = compose(config_name="evaluate", overrides=[f"robot={choice}", *overrides])
    values = {k: record[k] for k in _ENTRY_KEYS if k in record}
    if not preset:
        if not isinstance(trained, dict):
            raise ValueError(
                f"{path}: its config holds no robot entry (the training run's robot keys), which "
                f"evaluating its robot, {_entry_label(record)}, needs; retrain with this aco-rbfn"
            )
        known = {f.name for f in fields(RobotConfig)}
        values = {**{k: v for k, v in trained.items() if k in known}, **values, "derive": False}
    for key, value in values.items():
        if not any(k == f"robot.{key}" or k.startswith(f"robot.{key}.") for k in given):
            dcfg.robot[key] = value  # the overrides' robot.* keys win
    if "robot.home" not in given and len(dcfg.robot.home) not in (0, len(record["joint_names"])):
        dcfg.robot.home = []  # the preset's home has other free joints (an earlier preset's checkpoint): box centre
    robot = cast(RobotConfig, OmegaConf.to_object(dcfg.robot))
    if not same_robot(robot, record):  # the overrides' robot.* keys made it another robot
        raise _another_robot(path, newest, record, " ".join(given.values()), choice)
    return dcfg


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
def _timed(seconds: dict, part: str, cfg: EvalConfig, charted: bool = False):
    """One part announced (what and how big) and timed (rbfn.studies.cli.announced); its wall
    seconds recorded under `seconds[part]`; yields the part's `Progress` for its loops."""
    with announced(log, part, _what(part, cfg, charted), cfg.progress) as timing:
        yield timing["progress"]
    seconds[part] = timing["seconds"]


def _what(part: str, cfg: EvalConfig, charted: bool = False) -> str:
    """What `part` will do and how big, for its first log line (`charted`: the checkpoint holds a
    charted network, robot.workspace=full)."""
    if part == "ik" and charted:
        return (
            f"the charted network on {cfg.n_test} fresh poses in the box and over the whole joint range, polished "
            f"by {CHARTED_ITERATIONS} solver steps"
        )
    if part == "ik":
        return (
            f"accuracy on {cfg.n_test} fresh test samples, float64 and float32, then polished by "
            f"{DEFAULT_ITERATIONS} solver steps"
        )
    if part == "online":
        o = cfg.online
        return (
            f"{o.learner} adaptation at {len(o.sizes)} perturbation sizes, adapted and frozen, "
            f"{o.duration:g} s at {1 / o.dt:g} Hz"
        )
    c = cfg.control
    payloads = len(payload_cases(c, cfg.robot.rated_payload))  # without loading the URDF
    said = (
        f"{len(c.controllers)} controllers x {payloads} payloads, {c.duration:g} s at {1 / c.dt:g} Hz, "
        f"{cfg.loop.name} loop"
    )
    if c.pick_and_place.picks:
        said += f", then {c.pick_and_place.picks} picks and places in {c.pick_and_place.duration:g} s"
    if any(network_method(name) for name in c.controllers):
        net = c.network.resolved(realistic=not cfg.loop.ideal)
        said += f"; the adaptive network's law {net.law}, its centres' objective {net.objective}"
    return said


def checkpoint_parts(ckpt: dict, path: Path, cfg: EvalConfig, out_dir: Path) -> tuple[dict, dict[str, float]]:
    """The parts that evaluate the checkpoint, `ik` and `online` (as enabled), with a TensorBoard
    writer of their own (they may run in another process): (metrics, wall seconds per part)."""
    metrics: dict = {}
    seconds: dict[str, float] = {}
    writer = SummaryWriter(log_dir=str(out_dir), filename_suffix=".checkpoint")
    try:
        if cfg.ik:
            with _timed(seconds, "ik", cfg, charted=ckpt["kind"] == CHARTS_KIND):
                metrics["ik"] = evaluate_ik(ckpt, path, cfg, out_dir, writer)
            # Flat IK keys at the top level too, as train.py writes them.
            metrics.update({k: v for k, v in metrics["ik"].items() if k.startswith("test_")})
        if cfg.online.enabled and ckpt["kind"] != CHARTS_KIND:
            with _timed(seconds, "online", cfg):
                metrics["online"] = evaluate_online(ckpt, cfg.online, cfg.gains, cfg.device, writer, out_dir)
    finally:
        writer.close()
    return metrics, seconds


def _uses_checkpoint(cfg: EvalConfig) -> bool:
    """Whether a checkpoint decides the run: a part evaluates one (ik, online), or one is named
    (`checkpoint=PATH`: its robot is the closed loop's too, with ik and online off)."""
    return bool(cfg.ik or cfg.online.enabled or cfg.checkpoint)


def check(cfg: EvalConfig) -> tuple[Path | None, dict | None]:
    """Every setting checked before any work: (the checkpoint's path, its dict), both None when
    no part needs one or none was found. A checkpoint of another robot than `cfg.robot` is refused
    (`for_checkpoint` composes the config for the checkpoint's robot)."""
    validate_evaluate(cfg)
    check_evaluate(cfg)  # the parts fit in memory
    if not (cfg.ik or cfg.online.enabled or cfg.control.enabled):
        raise ValueError("nothing to evaluate: ik, online.enabled and control.enabled are all false; enable a part")
    path = find_checkpoint(cfg) if _uses_checkpoint(cfg) else None
    ckpt = read_checkpoint(path) if path is not None else None  # a bad file stops before any work
    if path is not None and ckpt is not None and not same_robot(cfg.robot, ckpt["robot"]):
        r = cfg.robot
        raise _another_robot(
            path, not cfg.checkpoint, ckpt["robot"], f"robot.urdf={r.urdf}" if r.urdf else f"robot={r.name}"
        )
    if cfg.control.enabled:
        # the robot's URDF (the checkpoint's text), joints and payload link, before any work
        check_control(cfg.control, cfg.robot, urdf_text=ckpt["robot"]["urdf"] if ckpt is not None else None)
    if ckpt is None and not cfg.control.enabled:
        root = Path(to_absolute_path(cfg.outputs_dir))
        why = "no such directory" if not root.is_dir() else "no checkpoint.pt below it"
        raise ValueError(
            f"nothing to evaluate: outputs_dir={cfg.outputs_dir!r} ({root}): {why}, and "
            "control.enabled=false; train first, pass checkpoint=PATH, or enable the control part"
        )
    if ckpt is not None and cfg.online.enabled and ckpt["kind"] == CHARTS_KIND:
        log.warning(
            "online: skipped, %s holds a charted network (robot.workspace=full) and online adaptation adapts one "
            "box network (a robot.workspace=box checkpoint); online.enabled=false silences this",
            path,
        )
    elif ckpt is not None and cfg.online.enabled:
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
    if robots:
        log.info("robot: %s%s", next(iter(robots.values())), " (the checkpoint's)" if ckpt is not None else "")
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    metrics: dict = {}
    seconds: dict[str, float] = {}
    # The checkpoint's parts run in a forked process beside the control part where that is safe
    # (rbfn.studies.beside), started before this process's TensorBoard writer and its thread.
    both = (
        ckpt is not None
        and (cfg.ik or cfg.online.enabled)
        and cfg.control.enabled
        and cfg.parallel
        and can_fork(cfg.device)
    )
    # The forked parts keep a core busy: this process takes one thread too while they run. Two
    # threads here beside them measured the control part 1.2x slower and its centre selection 2-4x.
    one = both and not cfg.num_threads
    with _torch_threads(1 if one else None), Beside(checkpoint_parts, ckpt, path, cfg, out_dir, fork=both) as beside:
        if cfg.control.enabled:
            writer = SummaryWriter(log_dir=str(out_dir))
            try:
                with _timed(seconds, "control", cfg) as progress:
                    control = evaluate_control(
                        cfg.control,
                        cfg.gains,
                        device=cfg.device,
                        writer=writer,
                        out_dir=out_dir,
                        robot=cfg.robot,
                        parallel=cfg.parallel,
                        loop=cfg.loop,
                        urdf_text=ckpt["robot"]["urdf"] if ckpt is not None else None,
                        progress=progress,
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
    """(the robot each part that runs evaluates, as "name (end link, n joints)": the checkpoint's
    where there is one (`check`: the config's robot is it), else `cfg.robot`; each enabled part
    that does not run, and why): metrics.json's `robots` and `skipped`."""
    skipped = {}
    if ckpt is not None:
        label = _entry_label(ckpt["robot"])
    else:
        why = f"no checkpoint.pt under outputs_dir={cfg.outputs_dir!r} (train first, or pass checkpoint=PATH)"
        skipped.update({part: why for part, on in (("ik", cfg.ik), ("online", cfg.online.enabled)) if on})
        r = cfg.robot
        label = f"{robot_label(r.name, Path(r.urdf) if r.urdf else r.name)} ({r.end_link}, {len(r.joint_low)} joints)"
    parts = (("ik", cfg.ik and ckpt is not None), ("online", cfg.online.enabled and ckpt is not None))
    return {part: label for part, on in (*parts, ("control", cfg.control.enabled)) if on}, skipped
