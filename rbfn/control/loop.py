"""What a real arm adds to the closed loop, as pure tensor functions: the sensing side (encoder
quantisation, position noise, a sensing delay, velocity from filtered finite differences of the
measured positions), the timing (a control period of several integration steps, the torque held
between them) and the actuation side (a delay of whole periods, saturation at the URDF's effort
limits, torque noise). `RealLoop` holds one configuration (`real_loop` builds it from the `loop`
config and a robot); `rbfn.control.simulator.simulate` runs it. Joint values in rad (m for a
prismatic joint), torques in N m (N), each (B, n) unless said.

The controller is told, with its next measurement, the torque actually applied over the last
period (`Applied`): its nominal share (what was applied less the observer's and the network's
shares of that command) and where it was saturated, so the momentum observer integrates the
torque that acted and the adaptation stops where the actuator could not follow (anti-windup:
Astrom and Wittenmark, Computer-Controlled Systems, drive the observer with the applied input).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import torch

from ..config import LoopConfig

__all__ = [
    "RealLoop",
    "crossover_limit",
    "Applied",
    "Sensing",
    "Actuation",
    "real_loop",
    "quantise",
    "filter_gain",
    "filtered_velocity",
    "velocity_lag",
    "saturate",
    "integration_limit",
    "STABLE_STEP",
]


class Applied(NamedTuple):
    """The torque applied over the last control period, as the controller may know it: its
    nominal share `known` (B, n) (the applied torque less the observer's and network's shares of
    the command it came from) and `saturated` (B, n), 1.0 where the actuator clipped it."""

    known: torch.Tensor
    saturated: torch.Tensor


class Sensing(NamedTuple):
    """The sensors' state: the last measured positions, oldest first (sensing_delay + 1, B, n),
    the last position delivered to the controller (B, n) and the filtered velocity (B, n)."""

    history: torch.Tensor
    previous: torch.Tensor
    velocity: torch.Tensor


class Actuation(NamedTuple):
    """The actuators' state: commands waiting to act, oldest first (actuation_delay, B, n), their
    observer and network shares (the same shape), what the controller is told of the last period
    (`Applied`) and the periods each joint spent saturated (B, n)."""

    commands: torch.Tensor
    shares: torch.Tensor
    applied: Applied
    saturated_periods: torch.Tensor


@dataclass(frozen=True)
class RealLoop:
    """One realistic loop for n joints (see the module docstring); None fields are off.

    substeps: integration steps per control period; period: its length, s; resolution (n,): rad
    (m) per encoder count; position_noise: rad (m), standard deviation; velocity_gain: the
    first-order filter's gain per period (None: the exact velocity); torque_limit (n,): N m (N);
    torque_noise (n,): N m (N), standard deviation; seed: the noise streams'; noise_envs: the
    period of the environments' noise (B a multiple of it), so that every controller of a
    comparison meets the same noise in the same case (common random numbers); 0: each its own.
    """

    substeps: int = 1
    period: float = 1e-3
    sensing_delay: int = 0
    actuation_delay: int = 0
    resolution: torch.Tensor | None = None
    position_noise: float = 0.0
    velocity_gain: float | None = None
    torque_limit: torch.Tensor | None = None
    torque_noise: torch.Tensor | None = None
    seed: int = 0
    noise_envs: int = 0  # environments b and b + noise_envs share noise draws (0: each its own)


def crossover_limit(loop: RealLoop, margin: float) -> float:
    """The highest crossover frequency, rad/s, a feedback loop of the sliding surface may have in
    `loop` and keep `margin` degrees of phase margin. Under tau = K s the joint is an integrator from
    torque to s (-90 deg); the loop adds the lag phi(w) = w T (sensing_delay + actuation_delay + 1/2
    for the zero-order hold, + 1/2 for the backward difference where the velocity is estimated) plus
    the velocity filter's phase, and phi grows with w up to the Nyquist frequency pi / T (the filter's
    lag falls by less than the hold's rises). Found by bisection where phi = 90 - margin degrees;
    pi / T where even the Nyquist frequency keeps the margin. T: the control period."""
    t, a = loop.period, loop.velocity_gain
    periods = loop.sensing_delay + loop.actuation_delay + 0.5 + (0.0 if a is None else 0.5)

    def lag(w: float) -> float:
        x = w * t
        filtered = 0.0 if a is None else math.atan2((1 - a) * math.sin(x), 1 - (1 - a) * math.cos(x))
        return x * periods + filtered

    target = math.radians(90.0 - margin)
    lo, hi = 0.0, math.pi / t
    if lag(hi) <= target:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if lag(mid) <= target else (lo, mid)
    return lo


STABLE_STEP = 0.5  # the ideal loop's feedback crossover, times its step dt, at most (integration_limit)


def integration_limit(dt: float) -> float:
    """The highest crossover frequency, rad/s, of a joint's sliding-surface feedback that the
    ideal loop (the controller acting every simulation step dt, s) integrates stably and
    accurately: STABLE_STEP / dt. A joint under tau = K s has its fastest pole near -K s_j / Me_jj;
    RK4 is stable on the real axis up to 2.79 / dt and semi-implicit Euler up to 2 / dt, so
    0.5 / dt keeps a factor 4 for the observer's and the surface's own poles. A coupled joint whose
    apparent inertia is far below its diagonal (two axes aligned at home) crosses it; the shipped
    arms' joints stay below (at most 248 rad/s against 500 at 1 kHz)."""
    return STABLE_STEP / dt


def quantise(q: torch.Tensor, resolution: torch.Tensor) -> torch.Tensor:
    """q rounded to the nearest encoder count: resolution (n,) rad (m) per count."""
    return torch.round(q / resolution) * resolution


def filter_gain(cutoff: float, period: float) -> float:
    """The gain a = 1 - exp(-2 pi f_c T) of a first-order low-pass of cutoff f_c (Hz) sampled every
    T s: y_k = y_{k-1} + a (x_k - y_{k-1}), the exact discretisation of 1 / (1 + s / (2 pi f_c))."""
    return 1.0 - math.exp(-2.0 * math.pi * cutoff * period)


def filtered_velocity(
    velocity: torch.Tensor, y: torch.Tensor, previous: torch.Tensor, period: float, gain: float
) -> torch.Tensor:
    """The next filtered velocity: the finite difference (y - previous) / period of measured
    positions through the first-order filter of `gain` (`filter_gain`)."""
    return velocity + gain * ((y - previous) / period - velocity)


def velocity_lag(loop: RealLoop | None) -> float:
    """How far, s, the velocity the controller measures in `loop` lags the joint's, at frequencies
    well below the filter's cutoff: half a period for the backward difference and (1 - a) / a
    periods for the first-order filter of gain a (`filtered_velocity`); 0 in the ideal loop or
    where the velocity is exact. A reference velocity qd_d compares with the measured one as
    qd_d - lag qdd_d (to first order in the lag)."""
    if loop is None or loop.velocity_gain is None:
        return 0.0
    a = loop.velocity_gain
    return loop.period * (0.5 + (1.0 - a) / a)


def saturate(tau: torch.Tensor, limit: torch.Tensor) -> torch.Tensor:
    """tau clipped to [-limit, limit] per joint (limit (n,), inf where unlimited)."""
    return torch.maximum(torch.minimum(tau, limit), -limit)


def real_loop(
    cfg: LoopConfig,
    dt: float,
    prismatic: list[bool],
    effort: torch.Tensor,
    joint_scale: torch.Tensor | None = None,
) -> RealLoop | None:
    """The loop `cfg` for a robot whose joints are `prismatic` (n,) with effort limits `effort`
    (n,) N m (N), integrated every dt s; None for the ideal loop. joint_scale (n,): the factor of
    the torque noise per joint (None: 1). ValueError names the key whose length is wrong."""
    if cfg.ideal:
        return None
    n = len(prismatic)
    rate = cfg.control_rate
    substeps = 1 if rate is None else round(1.0 / (rate * dt))
    period = substeps * dt
    resolution = None
    if cfg.encoder_counts:
        if len(cfg.encoder_counts) != n:
            raise ValueError(
                f"loop.encoder_counts={list(cfg.encoder_counts)} needs one value per joint of the chain ({n})"
            )
        per = [1.0 / c if p else 2 * math.pi / c for c, p in zip(cfg.encoder_counts, prismatic)]
        resolution = torch.tensor(per, dtype=torch.float64)
    scale = torch.ones(n, dtype=torch.float64) if joint_scale is None else joint_scale.double().cpu()
    return RealLoop(
        substeps=substeps,
        period=period,
        sensing_delay=cfg.sensing_delay,
        actuation_delay=cfg.actuation_delay,
        resolution=resolution,
        position_noise=cfg.position_noise,
        velocity_gain=None if cfg.velocity_cutoff is None else filter_gain(cfg.velocity_cutoff, period),
        torque_limit=effort.double().cpu() if cfg.torque_limits else None,
        torque_noise=cfg.torque_noise * scale if cfg.torque_noise else None,
        seed=cfg.noise_seed,
    )
