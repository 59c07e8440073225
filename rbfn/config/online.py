"""The online part's schema (evaluate.py's `online`): the IK network corrected by LMS while the
robot follows a task-space path."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from .base import Choice, _check_aot, _need, finite


class PathName(Choice):
    paper = "paper"
    circle = "circle"
    figure8 = "figure8"
    sinusoid = "sinusoid"


class Learner(Choice):
    nlms = "nlms"
    rls = "rls"


@dataclass
class OnlineConfig:
    """Online IK adaptation in the closed loop (evaluate.py's `online` part; needs a checkpoint),
    on the robot the checkpoint was trained for.

    The "real" robot differs from the model by `link_error` (relative errors of links 1, 2, ...:
    link k runs from joint k to joint k+1, or to the end link for the last joint) and
    `offset_error` (offsets added to joints 1, 2, ... in chain order, rad or m); missing entries
    are 0. `sizes` are link-1 errors to sweep: each row scales the whole configured perturbation
    so that its link-1 error equals the size; the configured perturbation itself
    (size = link_error[0]) is the one the headline metrics report.
    """

    enabled: bool = True
    duration: float = 20.0  # s
    dt: float = 1e-3  # s
    path: Optional[PathName] = None  # null: paper (SCARA), sinusoid (URDF arms)
    amplitude: float = 0.25  # sinusoid path: per joint amplitude / half the trained box range
    link_error: list[float] = field(default_factory=lambda: [0.03, -0.02])  # relative, links 1, 2, ...
    offset_error: list[float] = field(default_factory=lambda: [0.02, 0.0, 0.0])  # joints 1, 2, ... (rad or m)
    sizes: list[float] = field(default_factory=lambda: [0.0, 0.01, 0.03, 0.05])  # link-1 errors
    learner: Learner = Learner.nlms
    alpha0: float = 0.5  # NLMS step alpha(0)
    decay: float = 0.0  # s; alpha(t) = alpha0 / (1 + t / decay); 0: constant
    forgetting: float = 0.9995  # RLS forgetting factor
    update_every: int = 10  # control periods per update (the pairs of one mini-batch)
    aot: str = "auto"  # the closed-loop chunk compiled ahead of time, cached on disk: as control.aot
    save_checkpoint: bool = True  # write checkpoint_online.pt (the configured perturbation's network)

    def check(self, key: str = "online") -> None:
        _check_aot(self.aot, f"{key}.aot")
        _need(finite(self.dt) and self.dt > 0, f"{key}.dt", self.dt, "must be a positive number of seconds")
        _need(
            finite(self.duration) and self.duration >= 4.0,
            f"{key}.duration",
            self.duration,
            "must be >= 4 s (the metrics use the first and last 2 s)",
        )
        _need(
            len(self.link_error) > 0 and all(finite(v) and v > -1 for v in self.link_error),
            f"{key}.link_error",
            list(self.link_error),
            "relative errors > -1 of links 1, 2, ... (at least link 1)",
        )
        _need(
            all(finite(v) for v in self.offset_error),
            f"{key}.offset_error",
            list(self.offset_error),
            "finite joint offsets (rad or m) of joints 1, 2, ...",
        )
        _need(
            finite(self.amplitude) and 0 < self.amplitude <= 0.5,
            f"{key}.amplitude",
            self.amplitude,
            "must be in (0, 0.5] (the sinusoid path's two terms then stay inside the trained box)",
        )
        _need(
            len(self.sizes) > 0 and all(finite(s) for s in self.sizes),
            f"{key}.sizes",
            list(self.sizes),
            "a non-empty list of link-1 errors",
        )
        ref = self.link_error[0]
        _need(
            ref != 0 or all(s == 0 for s in self.sizes),
            f"{key}.sizes",
            list(self.sizes),
            f"sizes scale the configured perturbation by its link-1 error, and {key}.link_error[0] is 0",
        )
        _need(
            any(math.isclose(s, ref, rel_tol=1e-9, abs_tol=1e-12) for s in self.sizes),
            f"{key}.sizes",
            list(self.sizes),
            f"must include {key}.link_error[0]={ref}, the configured perturbation",
        )
        _need(0 <= self.alpha0 < 2, f"{key}.alpha0", self.alpha0, "must be in [0, 2)")
        _need(finite(self.decay) and self.decay >= 0, f"{key}.decay", self.decay, "must be >= 0")
        _need(0 < self.forgetting <= 1, f"{key}.forgetting", self.forgetting, "must be in (0, 1]")
        _need(self.update_every >= 1, f"{key}.update_every", self.update_every, "must be >= 1")
