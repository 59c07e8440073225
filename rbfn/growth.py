"""Growth: add hidden nodes until the validation error meets the goal or M reaches its maximum."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar, cast

__all__ = ["growth_schedule", "grow"]

T = TypeVar("T")


def growth_schedule(start: int, factor: float, m_max: int) -> list[int]:
    """M values to try: start, ceil(start * factor), ..., m_max; [m_max] when start is 0 or >= m_max."""
    if start <= 0 or start >= m_max:
        return [m_max]
    ms = [start]
    while ms[-1] < m_max:
        ms.append(min(m_max, max(ms[-1] + 1, math.ceil(ms[-1] * factor))))
    return ms


def grow(
    fit_at: Callable[[int], tuple[T, float]],
    schedule: list[int],
    goal: float,
    on_step: Callable[[int, float], None] | None = None,
) -> tuple[T, list[tuple[int, float]]]:
    """Fit at each M of `schedule` until the error E returned by `fit_at(M)` is <= goal.

    Returns the last fit and the (M, E) curve.
    """
    curve: list[tuple[int, float]] = []
    result = None
    for m in schedule:
        result, err = fit_at(m)
        curve.append((m, err))
        if on_step is not None:
            on_step(m, err)
        if err <= goal:
            break
    return cast(T, result), curve  # a schedule has at least one M
