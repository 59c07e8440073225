"""Ant colony optimization, knowing nothing of robots or networks: it minimizes what it is given.

`AntSystem` chooses a subset of discrete candidates (the paper's colony); `ACOR` searches a
continuous box (Socha & Dorigo's ACO_R). Both evaluate all ants of an iteration in one batched
objective call and keep the best-so-far solution.
"""

from .acor import ACOR
from .ant_system import AntSystem
from .result import ACOResult

__all__ = ["ACOR", "AntSystem", "ACOResult"]
