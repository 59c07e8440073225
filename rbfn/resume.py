"""Resumable training: what a preempted run needs to continue, kept in RUN_DIR/last.pt.

The state holds the growth steps already completed (their (M, E) and the last step's fitted
centres, widths and weights), the step in progress (its M, the generator's state when it
started, and the colony's latest snapshot), the generator's state between steps, and, once
the run finished, its metrics. Written sealed and atomically, at most every `every` seconds
while a colony runs and at once at each step's end. A directory holding another configuration's
state, or another command's metrics.json (evaluate.py's), is refused before anything is written.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from .checkpoint import TRAIN_STATE_KIND, load_sealed, save_sealed

__all__ = ["TrainState", "StateFile", "Resumable", "DifferentRun", "comparable"]


class DifferentRun(ValueError):
    """The run directory holds another configuration's run, or another command's results (refused;
    the directory is left as it was)."""


KIND = TRAIN_STATE_KIND
FORMAT_VERSION = 1
# Keys that may differ between the interrupted run and its resumption.
_FREE_KEYS = ("progress", "num_threads", "device")


@dataclass
class TrainState:
    config: dict
    # done: {"num_centers", "val_E", "select_seconds", "aco_best", "aco_mean", "chosen_by",
    # "selection_note"} per growth step
    done: list[dict] = field(default_factory=list)
    last_fit: dict | None = None  # {"centers", "widths", "weights", "ridge", "val_mse"}
    gen_after: Any = None  # generator state after the last completed step
    current: dict | None = None  # {"num_centers", "gen_start", "colony"}
    finished: dict | None = None  # final metrics
    elapsed: float = 0.0  # s spent training, over every process so far


def _foreign_metrics(run_dir: Path) -> bool:
    """Whether `run_dir` holds a metrics.json that no training run wrote (evaluate.py's, say)."""
    path = run_dir / "metrics.json"
    if not path.exists():
        return False
    try:
        return "train_seconds" not in json.loads(path.read_text())
    except (OSError, ValueError, TypeError):
        return True


def comparable(cfg: dict) -> dict:
    """`cfg` without the keys that may differ between an interrupted run and its resumption."""
    return {k: v for k, v in cfg.items() if k not in _FREE_KEYS}


class StateFile:
    """Reads and writes the TrainState of one run directory."""

    def __init__(self, run_dir: Path, every: float = 2.0) -> None:
        self.path = Path(run_dir) / "last.pt"
        self.every = every
        self._last_write = 0.0

    def load(self, config: dict) -> TrainState:
        """The saved state if there is one for this config, else a fresh state."""
        if not self.path.exists():
            if _foreign_metrics(self.path.parent):
                raise DifferentRun(
                    f"{self.path.parent / 'metrics.json'} is not a training run's (evaluate.py's, "
                    "say), and training would write over it; give train.py another hydra.run.dir"
                )
            return TrainState(config=config)
        # Re-running training reads the same file again, so the remedy for a bad one is deleting it.
        restart = f"Delete {self.path} to start the run over (its completed steps are lost)."
        raw = load_sealed(self.path, what="training state", advice=restart)
        if not isinstance(raw, dict) or raw.get("kind") != KIND or raw.get("format_version") != FORMAT_VERSION:
            kind, version = (raw.get("kind"), raw.get("format_version")) if isinstance(raw, dict) else (None, None)
            raise ValueError(
                f"{self.path} is not a training state this aco-rbfn can resume "
                f"(kind {kind!r}, format {version}). {restart}"
            )
        if not isinstance(raw.get("state"), dict) or not isinstance(raw["state"].get("config"), dict):
            raise ValueError(f"{self.path} holds no training state with a config. {restart}")
        if comparable(raw["state"]["config"]) != comparable(config):
            raise DifferentRun(
                f"{self.path} belongs to a run with a different configuration; resume it "
                "with the same overrides, use another hydra.run.dir, or delete last.pt"
            )
        return TrainState(**raw["state"])

    def save(self, state: TrainState, force: bool = True) -> None:
        """Write `state` now (force) or if `every` seconds passed since the last write."""
        now = time.monotonic()
        if force or now - self._last_write >= self.every:
            save_sealed(self.path, {"kind": KIND, "format_version": FORMAT_VERSION, "state": asdict(state)})
            self._last_write = now


class Resumable:
    """One training run's bookkeeping, as `rbfn.pipeline.train_ik` uses it: the growth steps done,
    the step in progress and the generator's state between steps, recorded in `state` and saved
    to `states` as they change (None: kept in memory only). The run's generator `gen` is put back
    where the interrupted run left it."""

    def __init__(self, states: StateFile | None, state: TrainState | None, gen: torch.Generator) -> None:
        self.states, self.state, self.gen = states, state or TrainState(config={}), gen
        self._start, self._before = time.perf_counter(), self.state.elapsed
        if self.state.gen_after is not None:
            gen.set_state(self.state.gen_after)

    def elapsed(self) -> float:
        """Seconds spent training, over every process so far."""
        return self._before + time.perf_counter() - self._start

    def save(self, force: bool = True) -> None:
        if self.states is not None:
            self.state.elapsed = self.elapsed()
            self.states.save(self.state, force=force)

    def begin(self, m: int) -> dict | None:
        """Start (or continue) the growth step at M = m: the colony's snapshot to resume from (None:
        from the start), the generator set to where the step started."""
        current = self.state.current
        if current is not None and current["num_centers"] == m:
            self.gen.set_state(current["gen_start"])
            return current["colony"]
        self.state.current = {"num_centers": m, "gen_start": self.gen.get_state(), "colony": None}
        return None

    def colony(self, snapshot: dict) -> None:
        """The running colony's latest snapshot (saved at most every `StateFile.every` seconds)."""
        assert self.state.current is not None  # set by `begin`
        self.state.current["colony"] = snapshot
        self.save(force=False)

    def finish(self, step: dict, last_fit: dict) -> None:
        """The step at hand is done: its record (`TrainState.done`) and its fit (`last_fit`)."""
        self.state.done.append(step)
        self.state.last_fit = last_fit
        self.state.gen_after, self.state.current = self.gen.get_state(), None
        self.save()

    def curve(self) -> list[tuple[int, float]]:
        """The growth curve (M, E) of the steps done."""
        return [(d["num_centers"], d["val_E"]) for d in self.state.done]

    def remaining(self, schedule: list[int], goal: float) -> list[int]:
        """The steps of `schedule` still to run: none where growth had finished (the goal met or the
        last M reached) before the interruption."""
        curve = self.curve()
        if curve and (curve[-1][1] <= goal or curve[-1][0] == schedule[-1]):
            return []
        return [m for m in schedule if m not in {c[0] for c in curve}]
