"""Training data: seeded joint samples in the robot's box, FK targets, train/val/test splits."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from .robots.kinematics import joint_limits

if TYPE_CHECKING:
    from .robots.robot import Robot

__all__ = [
    "Split",
    "Dataset",
    "sample_joints",
    "make_split",
    "make_dataset",
    "evaluation_split",
    "full_limits",
    "full_range_split",
    "stream",
    "input_scaling",
    "check_finite",
]

# Random streams: a seed s draws training, validation and test sets from streams s * 1000 + 0, 1, 2
# and evaluation sets from s * 1000 + 777. Two streams of any seeds coincide only if they have the
# same offset, so an evaluation set never repeats a training, validation or test set.
STREAMS_PER_SEED = 1000
TRAIN_VAL_TEST = (0, 1, 2)
EVALUATION = 777
FULL_RANGE = (3, 778)  # the test and evaluation sets over the whole joint range (`full_range_split`)


def stream(seed: int, offset: int) -> int:
    """The generator seed of stream `offset` (< 1000) of `seed`."""
    return seed * STREAMS_PER_SEED + offset


@dataclass
class Split:
    """The network's inputs x (N, 3) in m, or (N, 7) m and unit quaternion, and with a redundant
    joint its value (N, 8) (`Robot.inputs`), and free joints q (N, n)."""

    x: torch.Tensor
    q: torch.Tensor

    def to(self, **kw) -> Split:
        return Split(self.x.to(**kw), self.q.to(**kw))


@dataclass
class Dataset:
    train: Split
    val: Split
    test: Split


def sample_joints(low: torch.Tensor, high: torch.Tensor, n: int, generator: torch.Generator) -> torch.Tensor:
    """n joint vectors (n, J) uniform in the box [low, high] (float64)."""
    u = torch.rand(n, low.shape[0], dtype=torch.float64, generator=generator)
    return low + u * (high - low)


def make_split(
    robot: Robot, n: int, seed: int, low: torch.Tensor | None = None, high: torch.Tensor | None = None
) -> Split:
    """n (target, joints) pairs from joints sampled in the robot's box (or in [low, high] (n,))
    with `seed` (float64, on the chain's device)."""
    g = torch.Generator().manual_seed(seed)
    lo, hi = (robot.low, robot.high) if low is None or high is None else (low, high)
    q = sample_joints(lo, hi, n, g).to(robot.chain.device)
    return Split(robot.inputs(q).to(torch.float64), q)


def full_limits(robot: Robot) -> tuple[torch.Tensor, torch.Tensor]:
    """(low, high) (n,) float64 of the free joints (CPU): their URDF limits, a joint without limits
    over [-pi, pi] (one turn reaches every pose)."""
    low, high = (t[robot.free].cpu() for t in joint_limits(robot.chain))
    return low.nan_to_num(neginf=-torch.pi), high.nan_to_num(posinf=torch.pi)


def full_range_split(robot: Robot, n: int, seed: int, evaluation: bool = False) -> Split:
    """n pairs from joints uniform over the free joints' whole URDF range (`full_limits`), held
    joints as held: every pose the arm reaches, on every branch. The test set's stream of `seed`
    (the evaluation set's with `evaluation`), which no training set draws."""
    return make_split(robot, n, stream(seed, FULL_RANGE[evaluation]), *full_limits(robot))


def make_dataset(robot: Robot, sizes: tuple[int, int, int], seed: int) -> Dataset:
    """Train/val/test splits of (target, joints) pairs, each from its own seeded stream."""
    return Dataset(*(make_split(robot, n, stream(seed, k)) for k, n in zip(TRAIN_VAL_TEST, sizes)))


def evaluation_split(robot: Robot, n: int, seed: int) -> Split:
    """A fresh evaluation set for `seed`, from a stream no training run of any seed draws."""
    return make_split(robot, n, stream(seed, EVALUATION))


def input_scaling(x: torch.Tensor, mode: str) -> tuple[torch.Tensor, torch.Tensor]:
    """(offset, scale) (d,) for inputs x (N, d): "metres" centres only, "standard" also divides by std."""
    if mode == "metres":
        return x.mean(0), torch.ones_like(x[0])
    if mode == "standard":
        return x.mean(0), x.std(0).clamp_min(1e-12)
    raise ValueError(f"unknown input scaling {mode!r}; allowed: ['metres', 'standard']")


def check_finite(name: str, t: torch.Tensor) -> None:
    """Raise ValueError if tensor `t` holds NaN or inf, naming it and the first bad row."""
    bad = ~torch.isfinite(t)
    if bool(bad.any()):
        row = int(bad.reshape(t.shape[0], -1).any(-1).nonzero()[0])
        raise ValueError(f"{name} contains non-finite values (first at row {row}: {t[row].tolist()})")
