"""The robot a network is trained for: its URDF chain, end link and the sampled joint box."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytorch_kinematics as pk
import torch

from ..config import RobotConfig
from . import scara
from .kinematics import joint_limits, load_serial_chain

__all__ = ["Robot", "load_robot", "robot_from_record"]


@dataclass
class Robot:
    """A serial chain (float64) root -> end link and the joint box (n,) sampled for training."""

    chain: pk.SerialChain
    urdf_text: str
    end_link: str
    low: torch.Tensor
    high: torch.Tensor

    @property
    def joint_names(self) -> list[str]:
        return self.chain.get_joint_parameter_names()

    def record(self) -> dict:
        """Plain data for a checkpoint's `robot` entry (URDF text, end link, names, box)."""
        return {"urdf": self.urdf_text, "end_link": self.end_link, "joint_names": self.joint_names,
                "joint_low": self.low.tolist(), "joint_high": self.high.tolist()}


def _check_box(chain: pk.SerialChain, low: torch.Tensor, high: torch.Tensor, where: str) -> None:
    names = chain.get_joint_parameter_names()
    if len(names) != low.shape[0]:
        raise ValueError(f"{where}: robot.joint_low/joint_high give {low.shape[0]} joints, the URDF chain has "
                         f"{len(names)}: {names}")
    u_low, u_high = joint_limits(chain)
    outside = (low < u_low - 1e-12) | (high > u_high + 1e-12)
    if bool(outside.any()):
        j = int(outside.nonzero()[0])
        raise ValueError(f"{where}: joint range of {names[j]} [{low[j]:.4g}, {high[j]:.4g}] leaves the URDF "
                         f"limits [{u_low[j]:.4g}, {u_high[j]:.4g}]")


def load_robot(cfg: RobotConfig, device: str = "cpu") -> Robot:
    """The robot of `cfg` (the packaged SCARA when `cfg.urdf` is empty), its box checked against
    the URDF's joint limits."""
    path = Path(cfg.urdf) if cfg.urdf else scara.URDF_PATH
    if not path.is_file():
        raise FileNotFoundError(f"robot.urdf={cfg.urdf!r}: no such file ({path.resolve()})")
    chain = load_serial_chain(path, cfg.end_link, torch.float64, device)
    low = torch.tensor(cfg.joint_low, dtype=torch.float64)
    high = torch.tensor(cfg.joint_high, dtype=torch.float64)
    _check_box(chain, low, high, str(path))
    return Robot(chain, path.read_text(), cfg.end_link, low, high)


def robot_from_record(record: dict, device: str = "cpu") -> Robot:
    """The Robot of a checkpoint's `robot` entry."""
    chain = load_serial_chain(record["urdf"], record["end_link"], torch.float64, device)
    return Robot(chain, record["urdf"], record["end_link"], torch.tensor(record["joint_low"], dtype=torch.float64),
                 torch.tensor(record["joint_high"], dtype=torch.float64))
