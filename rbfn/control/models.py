"""The controllers' nominal model: M_hat = m M, C_hat = c C, G_hat = g G of the robot carrying a
fixed payload (0: the unloaded robot), the factors `ModelScales` (the paper's 0.9, 0.8 and 0.85:
`gains.model_inertia`, `model_coriolis`, `model_gravity`), over any backend of
`rbfn.robots.backend.Dynamics`.

`model.at(q, qd)` (or `model.at(q, qd, payload=m)`, carrying m kg per environment instead) gives
what a controller asks of its model at one control period (B, n): `m_times(v)` = M_hat(q) v,
`c_times(y)` = C_hat(q, qd) y, `gravity()` = G_hat(q) and `momentum_rate()` = dM_hat/dt qd -
C_hat qd - G_hat (the momentum observer's known part).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import torch

from ..config import GainsConfig
from ..robots.backend import Dynamics

__all__ = ["ModelScales", "PAPER", "NominalModel", "model_scales"]


class ModelScales(NamedTuple):
    """The nominal model's factors of M, C and G (dimensionless)."""

    m: float = 0.9
    c: float = 0.8
    g: float = 0.85


PAPER = ModelScales()
"""The paper's factors, 0.9, 0.8 and 0.85 (the gains' defaults)."""


def model_scales(gains: GainsConfig) -> ModelScales:
    """The nominal model's factors that `gains` sets."""
    return ModelScales(gains.model_inertia, gains.model_coriolis, gains.model_gravity)


class NominalModel:
    """Scaled M, C and G of `dynamics` carrying `payload` kg (0: unloaded)."""

    def __init__(self, dynamics: Dynamics, scales: ModelScales = PAPER, payload: float = 0.0) -> None:
        self.dynamics, self.scales, self.payload = dynamics, ModelScales(*scales), payload
        self.scaled = dynamics.scaled(*self.scales)
        self.load = self.scaled.load(payload)  # computed once
        self.n = dynamics.n

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, NominalModel)
            and other.dynamics is self.dynamics
            and other.scales == self.scales
            and other.payload == self.payload
        )

    __hash__ = None  # type: ignore[assignment]

    def at(self, q: torch.Tensor, qd: torch.Tensor, payload: torch.Tensor | None = None) -> ModelAt:
        """The model at joints q and velocities qd (B, n), carrying its own payload, or `payload`
        kg per environment (B,) in its stead (an estimate: `rbfn.control.controllers.TwoPhase`)."""
        load = self.load if payload is None else self.scaled.load(payload)
        return ModelAt(self.scaled.at(q, load=load), qd)


class ModelAt:
    """The model at one state (q, qd); the velocity terms it shares are computed once."""

    def __init__(self, terms: Any, qd: torch.Tensor) -> None:
        self.terms, self.qd = terms, qd
        self._mo: Any = None
        self._shared = False

    def _motion(self) -> Any:
        if not self._shared:
            self._mo, self._shared = self.terms.motion(self.qd), True
        return self._mo

    def m_times(self, v: torch.Tensor) -> torch.Tensor:
        return self.terms.mass_times(v)

    def c_times(self, y: torch.Tensor) -> torch.Tensor:
        return self.terms.coriolis_times(self.qd, y, self._motion())

    def gravity(self) -> torch.Tensor:
        return self.terms.gravity()

    def momentum_rate(self) -> torch.Tensor:
        return self.terms.momentum_rate(self.qd, self._motion())
