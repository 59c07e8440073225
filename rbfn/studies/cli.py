"""What a user sees when an entry point (train.py, evaluate.py) refuses or fails: one line.

A refused setting, file or directory (ValueError, OSError, a run directory in use, another
config's run) or a diverged closed loop (its message names the controller, case, step and state)
is printed as one line, `error: <message>` (then `note: <where the files it wrote are kept>` for a
run that failed after writing), and the command exits with status 1;
the traceback is shown with HYDRA_FULL_ERROR=1 (as Hydra's own errors are). Anything else (a bug)
keeps its traceback. In a multirun every error is left to Hydra, which runs the other jobs and
reports the first failure at the end.

Progress: each part of a run that takes more than a few seconds says what it will do and how big
when it starts, and its time when it ends (`announced`); while it runs, a line every 30 s (with
`progress` on) says it is still at work, what its loop has done of how much, and about how long
the rest takes, on the terminal and in the job's log file.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import signal
import sys
import threading
import time
import typing
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any

from hydra.core.config_store import ConfigStore
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException, OverrideParseException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from ..config import EvalConfig, TrainConfig
from ..config.base import type_mismatch
from ..control.simulator import SimulationDiverged
from ..files import discard
from ..progress import Progress
from ..resume import DifferentRun
from .rundir import FULL_ERROR, RunDirInUse
from .stop import Stopped, stop_on_signals

__all__ = [
    "REFUSALS",
    "ConsoleHandler",
    "announced",
    "one_line_errors",
    "report_stop",
    "run_main",
    "one_line",
    "settings",
]

REFUSALS = (ValueError, OSError, RunDirInUse, DifferentRun, SimulationDiverged)


def _say(line: str, notes=()) -> None:
    print(line, file=sys.stderr, flush=True)
    for note in notes:  # e.g. what a failed run kept (rbfn.studies.rundir)
        print(f"note: {note}", file=sys.stderr, flush=True)


def report_stop(e: Stopped) -> None:
    """Say once, on stderr, in one line, that signal `e.signum` stopped this process and what it kept
    (its notes); its exit status says the same (128 + the signal's number)."""
    if not getattr(e, "reported", False):
        e.reported = True  # type: ignore[attr-defined]
        kept = "".join(f"; {note}" for note in getattr(e, "__notes__", ()))
        _say(f"stopped by {signal.Signals(e.signum).name} (exit status {e.code}){kept}")


@contextmanager
def one_line_errors(enabled: bool = True):
    """Inside, a refusal (REFUSALS) ends the process with `error: <message>` on stderr and exit
    status 1 (where `enabled` and the user did not set HYDRA_FULL_ERROR=1); a stop by a signal
    (rbfn.studies.stop) says so in one line, keeping its exit status."""
    try:
        yield
    except Stopped as e:
        if enabled:
            report_stop(e)
        raise
    except REFUSALS as e:
        if not enabled or FULL_ERROR:
            raise
        _say(f"error: {one_line(e)}", getattr(e, "__notes__", ()))
        sys.exit(1)


def run_main(main: Callable[[], Any]) -> None:
    """Run an entry point's `@hydra.main` function `main` so that every way it ends is one line:
    SIGTERM, SIGHUP and SIGINT stop it (rbfn.studies.stop) with `stopped by ...`; Hydra's own
    errors (an override it cannot parse, a config group option that does not exist, a key the
    schema lacks) and a multirun's failed job, which Hydra prints with a traceback, are
    `error: <message>` (and exit status 1) too. With HYDRA_FULL_ERROR=1 Hydra's tracebacks stay."""
    if not FULL_ERROR:
        os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises instead of printing its trace and exiting
    with one_line_errors():
        stop_on_signals()
        try:
            main()
        except (HydraException, OmegaConfBaseException) as e:
            if FULL_ERROR:
                raise
            _say(f"error: {one_line(e)}", getattr(e, "__notes__", ()))
            sys.exit(1)


def settings(dcfg: DictConfig) -> Any:
    """The typed settings (the schema's dataclasses) of a composed config, refusing a key the schema
    lacks: `+rbfn.num_centres=40` is added by Hydra and would be silently dropped here."""
    obj = OmegaConf.to_object(dcfg)
    extra = _unknown(OmegaConf.to_container(dcfg, resolve=False), obj)
    if extra:
        raise ValueError(
            f"{', '.join(extra)} {'is not a setting' if len(extra) == 1 else 'are not settings'} of this command "
            "(misspelt?); --help lists the config groups, --cfg job every key"
        )
    return obj


def check_overrides(schema: type, overrides: Sequence[str]) -> None:
    """ValueError naming the first command-line override (`key=value`, as Hydra parses it) that sets
    a key of the config dataclass `schema` to a value of another type (`type_mismatch`), before
    OmegaConf converts it: `export=2`, `export=yes` and `progress=1` would each become true, and
    `robot.name=true` "True". Overrides of groups, of keys outside `schema` (hydra.*), sweeps and
    interpolations are left to Hydra."""
    for o in OverridesParser.create().parse_overrides(list(overrides)):
        if o.is_delete() or o.is_sweep_override():
            continue
        annotation: Any = schema
        for part in o.key_or_group.split("."):
            origin = typing.get_origin(annotation)
            if dataclasses.is_dataclass(annotation):
                hints = typing.get_type_hints(annotation)
                annotation = hints.get(part)
            elif origin is dict:
                annotation = typing.get_args(annotation)[1]
            else:
                annotation = None
            if annotation is None:
                break
        value = o.value()
        if annotation is None or dataclasses.is_dataclass(annotation) or (isinstance(value, str) and "${" in value):
            continue
        error = type_mismatch(annotation, value)
        if error:
            line = o.input_line or f"{o.key_or_group}={value!r}"
            raise ValueError(f"{line} is not allowed: {error}")


def register_configs() -> None:
    """Register train.py's and evaluate.py's schemas with Hydra's ConfigStore (the first entry of
    conf/train.yaml's and conf/evaluate.yaml's defaults). A group's preset (conf/GROUP/*.yaml) is
    merged into its typed field of that schema, which checks its keys and values: the groups need
    no schema entries of their own (which `--help` would list as options)."""
    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)
    cs.store(name="evaluate_schema", node=EvalConfig)


def _unknown(node: Any, obj: Any, prefix: str = "") -> list[str]:
    """Dotted keys of container `node` that dataclass `obj` (built from it) has no field for."""
    if not (dataclasses.is_dataclass(obj) and isinstance(node, dict)):
        return []
    names = {f.name for f in dataclasses.fields(obj)}
    extra = [f"{prefix}{k}" for k in node if k not in names]
    for k in node:
        if k in names:
            extra += _unknown(node[k], getattr(obj, k), f"{prefix}{k}.")
    return extra


def one_line(e: BaseException) -> str:
    """`e`'s message in one line: its lines joined by '; ' (an OmegaConf error's full_key and
    object_type, Hydra's options listed inline, without the search path and the schemas' internal
    entries), then its cause's first line (for Hydra: what was wrong with the value)."""
    if isinstance(e, OverrideParseException):
        return (
            f"cannot parse the override {e.override!r}; quote a value holding spaces or other special "
            """characters ('key="a b"'); see --help"""
        )
    parts: list[str] = []  # sentences, or a heading ending in ':' with its list of options
    listing = False
    for line in str(e).splitlines():
        line = line.strip()
        if line.startswith("Config search path") or "hydra.cc/docs" in line:
            break
        if not line or line.endswith("_schema"):
            continue
        if listing:
            parts[-1] += (" " if parts[-1].endswith(":") else ", ") + line
        else:
            parts.append(line)
            listing = line.endswith(":")
    text = "; ".join(part.rstrip(".") for part in parts)
    cause = e.__cause__
    if isinstance(e, HydraException) and cause is not None and str(cause).strip():
        text += f": {str(cause).strip().splitlines()[0]}"
    return text


class ConsoleHandler(logging.StreamHandler):
    """The terminal's log handler (conf: hydra.job_logging.handlers.console): where its stream is
    closed under it (`python train.py | head -1`), it says so once on stderr and sends the rest to
    /dev/null (the job's log file still gets every message) instead of a BrokenPipeError block a
    message. The run goes on."""

    def handleError(self, record: logging.LogRecord) -> None:
        if not isinstance(sys.exc_info()[1], BrokenPipeError):
            super().handleError(record)
            return
        with suppress(OSError, ValueError):  # (a stream without a descriptor)
            discard(self.stream)
        _say("note: standard output was closed; the run goes on, its messages go to its log file only")


HEARTBEAT_S = 30.0  # seconds between a running part's "still at work" lines


@contextmanager
def announced(log: logging.Logger, part: str, what: str, progress: bool = True) -> Iterator[dict]:
    """Log `part: what` on entry and `part: done in T s` on a normal exit; yields a dict whose
    "seconds" holds the wall seconds once the block ends, and whose "progress" is a
    `rbfn.progress.Progress` for the library loops inside to advance. Between, with `progress`,
    `part: still running (T s so far); <where the loop stands, and about how long it has left>`
    every HEARTBEAT_S seconds: on the terminal and in the job's log file alike, so that output
    sent to a file or a batch system's log says it too."""
    log.info("%s: %s", part, what)
    t0 = time.perf_counter()
    stop = threading.Event()
    timing: dict = {"progress": Progress()}

    def beat() -> None:
        while not stop.wait(HEARTBEAT_S):
            where = timing["progress"].line()
            log.info(
                "%s: still running (%.0f s so far)%s", part, time.perf_counter() - t0, f"; {where}" if where else ""
            )

    thread = threading.Thread(target=beat, name=f"{part}-progress", daemon=True) if progress else None
    if thread is not None:
        thread.start()
    try:
        yield timing
    finally:
        stop.set()
        if thread is not None:
            thread.join()
        timing["seconds"] = time.perf_counter() - t0
    log.info("%s: done in %.1f s", part, timing["seconds"])
