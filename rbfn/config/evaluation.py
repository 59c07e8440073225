"""evaluate.py's schema, `EvalConfig`: the IK accuracy part's settings and the parts it holds."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from .base import _need, _seed, check_types, validate_device
from .control import ControlConfig, GainsConfig
from .loop import LoopConfig
from .online import OnlineConfig
from .robot import RobotConfig


@dataclass
class EvalConfig:
    checkpoint: Optional[str] = None  # null: the newest checkpoint.pt under outputs_dir
    outputs_dir: str = "outputs"
    ik: bool = True  # the IK accuracy part (needs a checkpoint)
    n_test: int = 10000
    seed: Optional[int] = None  # null: the checkpoint's training seed; the test stream is derived
    device: str = "cpu"
    num_threads: int = 0  # torch threads; 0: torch's default, or one per process while the parts
    # run side by side
    parallel: bool = True  # checkpoint parts, half the control figures in forked processes
    # (fork, CPU, >= 2 cores)
    progress: bool = True  # each part's "still running" line every 30 s (terminal and log), with where it stands
    robot: RobotConfig = field(default_factory=RobotConfig)  # the control part's robot (IK: the checkpoint's)
    gains: GainsConfig = field(default_factory=GainsConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    online: OnlineConfig = field(default_factory=OnlineConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)

    def check(self) -> None:
        """Every value's type and every value of every enabled part (whether the parts fit in
        memory: `rbfn.memory.check_evaluate`)."""
        check_types(self)
        _need(self.n_test > 0, "n_test", self.n_test, "must be > 0")
        if self.seed is not None:
            _seed("seed", self.seed)
        validate_device(self.device, self.num_threads)
        self.robot.check()
        if self.control.enabled:
            self.control.check(realistic=not self.loop.ideal)
            self.gains.check()
            growths = [self.gains.feedback_growth * f for f in self.control.network.feedback_growth_factors]
            _need(
                min(growths) >= 1,
                "control.network.feedback_growth_factors",
                list(self.control.network.feedback_growth_factors),
                f"each times gains.feedback_growth={self.gains.feedback_growth:g} must be >= 1 "
                "(a growth below 1 would shrink the feedback)",
            )
            self.loop.check(self.control.dt)
        if self.online.enabled:
            self.online.check()


def validate_evaluate(cfg: EvalConfig) -> None:
    """Raise ValueError naming the first bad value of an evaluation config (`EvalConfig.check`)."""
    cfg.check()
