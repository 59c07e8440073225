"""The loop's schema (group `loop`: `ideal` or `realistic`): how real the closed loop is, its
sensing and actuation (rbfn.control.loop models each)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from .base import _check_sensing, _need, _seed, finite


@dataclass
class LoopConfig:
    """How real the closed loop is (group `loop`: `ideal`, today's exact loop, every value off;
    `realistic`, what a real arm has). Times in control periods of 1 / control_rate s.

    The controller reads the positions measured `sensing_delay` periods ago, quantised by the
    encoders and with Gaussian noise, and velocities from their filtered finite differences; it
    acts every 1 / control_rate s (zero-order hold; the plant integrates at control.dt), and its
    torque acts `actuation_delay` periods later, saturated at the URDF's effort limits, with
    Gaussian noise. The observer and the adaptation are told the torque actually applied.
    """

    name: str = "ideal"  # the preset's label
    control_rate: Optional[float] = None  # Hz; null: the controller acts every control.dt
    sensing_delay: int = 0  # periods between a measurement and its use
    actuation_delay: int = 0  # periods between a command and its torque
    encoder_counts: list[float] = field(default_factory=list)  # per joint (robot.encoder_counts); empty: exact
    position_noise: float = 0.0  # rad (m): standard deviation on the measured positions
    velocity_cutoff: Optional[float] = None  # Hz: first-order filter on position differences; null: exact velocity
    torque_limits: bool = False  # saturate the torques at the URDF's effort limits
    torque_noise: float = 0.0  # N m (N) per unit joint scale: standard deviation on the applied torque
    noise_seed: int = 0  # the sensor and torque noise streams

    @property
    def ideal(self) -> bool:
        """Every part off: the loop is today's exact one, bit for bit."""
        return (
            self.control_rate is None
            and self.sensing_delay == 0
            and self.actuation_delay == 0
            and not self.encoder_counts
            and self.position_noise == 0
            and self.velocity_cutoff is None
            and not self.torque_limits
            and self.torque_noise == 0
        )

    def check(self, dt: float, key: str = "loop") -> None:
        """dt: the integration step (control.dt), s."""
        rate = self.control_rate
        _check_sensing(rate, self.encoder_counts, key)
        if rate is not None:
            sub = 1.0 / (rate * dt)
            _need(
                sub >= 1 - 1e-9 and abs(sub - round(sub)) < 1e-6,
                f"{key}.control_rate",
                rate,
                f"its period must be a whole number of integration steps control.dt={dt} s",
            )
        for k in ("sensing_delay", "actuation_delay"):
            _need(0 <= getattr(self, k) <= 100, f"{key}.{k}", getattr(self, k), "must be in [0, 100] periods")
        for k in ("position_noise", "torque_noise"):
            _need(finite(getattr(self, k)) and getattr(self, k) >= 0, f"{key}.{k}", getattr(self, k), "must be >= 0")
        cut = self.velocity_cutoff
        _need(cut is None or (finite(cut) and cut > 0), f"{key}.velocity_cutoff", cut, "must be > 0 Hz or null")
        _seed(f"{key}.noise_seed", self.noise_seed)
