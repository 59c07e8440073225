"""The adaptive controller's RBF network: inputs, a pilot run, and centres chosen by ACO.

Inputs are the desired state x = (q_d, qd_d) (2n,), standardised over the trajectory, so the
features h(x_d(t)) are known in advance for every step. Centres and widths come from
`rbfn.select` on data recorded in a pilot run of `smc_obs` on the unloaded robot: the residual
torque the nominal model misses, tau - (M_hat qdd + C_hat qd + G_hat), against x. The `fit`
objective picks centres that fit that residual; `cluster` places them on the states alone
(k-means' objective, searched by ACO); `grid` spaces them evenly in time along one period.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import torch

from ..config import CONTROL_CENTER_METHODS, ACOConfig, CentersConfig, Method, Objective, WidthRule
from ..fit import design_matrix, ridge_fit
from ..layer import gaussian_features
from ..objectives import FitObjective
from ..select import choose_widths, select
from .controllers import Gains, Model, make_controller
from .simulator import Plant, Scenario, simulate
from .trajectory import Reference

__all__ = ["ControlNet", "desired_states", "pilot_residuals", "control_network"]
PERIOD = 2 * math.pi  # s: every desired joint repeats with this period


@dataclass
class ControlNet:
    """Standardisation (2n,), centres (M, 2n) and widths (M,) in standardised units, initial weights
    (M, n) (zeros unless warm-started), and the selection time in s."""

    offset: torch.Tensor
    scale: torch.Tensor
    centers: torch.Tensor
    widths: torch.Tensor
    w0: torch.Tensor
    seconds: float

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Gaussian activations (T, M) of desired states x (T, 2n)."""
        z = (x - self.offset.to(x)) / self.scale.to(x)
        return gaussian_features(z, self.centers.to(x), self.widths.to(x))


def desired_states(ref: Reference) -> torch.Tensor:
    """Network inputs (T, 2n): desired joints and velocities."""
    return torch.cat([ref.q_d, ref.qd_d], -1)


def pilot_residuals(
    plant: Plant,
    scenario: Scenario,
    ref: Reference,
    gains: Gains,
    model: Model,
    stride: int = 10,
    joint_scale: torch.Tensor | None = None,
    compile: bool = False,
    aot: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(x (N, 2n), residual torque (N, n)) every `stride` steps of an `smc_obs` run without payload;
    the residual is what the nominal model misses, tau - (M_hat qdd + C_hat qd + G_hat).
    `compile`, `aot`: as `simulate`'s."""
    q0, qd0 = ref.q_d[:1].clone(), ref.qd_d[:1].clone()
    ctrl = make_controller("smc_obs", gains, scenario.dt, model, joint_scale=joint_scale)
    roll = simulate(
        plant,
        ctrl,
        scenario,
        ref,
        q0=q0,
        qd0=qd0,
        payload=torch.zeros(1, dtype=q0.dtype, device=q0.device),
        compile=compile,
        aot=aot,
    )
    q, qd, tau = roll.q[:-1, 0], roll.qd[:-1, 0], roll.tau[:-1, 0]
    qdd = (roll.qd[1:, 0] - qd) / scenario.dt
    at = model.at(q, qd)
    resid = tau - at.m_times(qdd) - at.c_times(qd) - at.gravity()
    x = desired_states(ref)[: q.shape[0]]
    return x[::stride], resid[::stride]


def control_network(
    method: str,
    x: torch.Tensor,
    y: torch.Tensor,
    m: int,
    seed: int,
    sample_dt: float,
    aco: ACOConfig | None = None,
    warm_start: bool = False,
) -> ControlNet:
    """Centres and widths for the controller's network by `method` (CONTROL_CENTER_METHODS) from pilot
    data x (N, 2n), y (N, n) sampled every `sample_dt` s; even samples train, odd ones validate
    (widths, ridge, ACO's fit objective). `warm_start` starts the weights at the ridge fit of y."""
    if method not in CONTROL_CENTER_METHODS:
        raise ValueError(f"unknown centre method {method!r}; choose one of {list(CONTROL_CENTER_METHODS)}")
    offset, scale = x.mean(0), x.std(0).clamp_min(1e-9)
    z = (x - offset) / scale
    objective = FitObjective(z[0::2], y[0::2], z[1::2], y[1::2], tail=False)
    g = torch.Generator().manual_seed(seed)
    if method == "grid":
        t0 = time.perf_counter()
        period_n = min(z.shape[0], max(m, int(round(PERIOD / sample_dt))))
        centers = z[torch.linspace(0, period_n - 1, m + 1)[:-1].round().long()]
        widths = choose_widths(objective, centers, "per_center", None, max_width=4.0)
        seconds = time.perf_counter() - t0
    else:
        aco = aco or ACOConfig()
        if method == "aco_cluster":  # a new value: the caller's config is never mutated
            aco = replace(aco, objective=Objective.cluster)
        cfg = CentersConfig(
            name=method,
            method=Method.aco if method.startswith("aco") else Method(method),
            width_rule=WidthRule.per_center,
            aco=aco,
        )
        sel = select(cfg, objective, m, seed, max_width=4.0, generator=g)
        centers, widths, seconds = sel.centers, sel.widths, sel.seconds
    w0 = torch.zeros(m, y.shape[1], dtype=x.dtype)
    if warm_start:
        a_tr = design_matrix(z[0::2], centers, widths, tail=False)
        a_val = design_matrix(z[1::2], centers, widths, tail=False)
        w0 = ridge_fit(a_tr, y[0::2], a_val, y[1::2]).weights
    return ControlNet(offset, scale, centers, widths, w0, seconds)
