"""What a colony returns: the best-so-far solution and its per-iteration history."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch


@dataclass
class ACOResult:
    """best: the best solution found; best_value its objective; history per iteration."""

    best: torch.Tensor
    best_value: float
    iterations: int
    best_history: list[float] = field(default_factory=list)  # best-so-far after each iteration
    mean_history: list[float] = field(default_factory=list)  # mean objective of that iteration's ants
    converged: bool = False
