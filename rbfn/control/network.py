"""The adaptive controller's RBF network: inputs, a pilot run, and centres chosen by ACO.

Inputs are the desired state x = (q_d, qd_d) (2n,) (the tracking law), or (q_d, qd_d, qdd_d) (3n,)
(the two-phase law: the payload acts through the acceleration), standardised over the
trajectory, so the features h(x_d(t)) are known in advance for every step. Centres and widths come from
`rbfn.select` on data recorded in a pilot run of `smc_obs` on the unloaded robot: the residual
torque the nominal model misses, tau - (M_hat qdd + C_hat qd + G_hat), against x. The `fit`
objective picks centres that fit that residual; `cluster` places them on the states alone
(k-means' objective, searched by ACO); `grid` spaces them evenly in time along one period.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import torch

from ..config import NETWORK_METHODS, ACOConfig, CentersConfig, Objective, WidthRule
from ..fit import design_matrix, ridge_fit
from ..gaussians import gaussian_features
from ..objectives import FitObjective
from ..select import choose_widths, select
from .controllers import Gains, Model, make_controller
from .simulator import Plant, Scenario, simulate
from .trajectory import Reference

__all__ = [
    "ControlNet",
    "PayloadBasis",
    "desired_states",
    "pilot_residuals",
    "payload_residuals",
    "payload_basis",
    "model_payload_torque",
    "control_network",
]
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


def desired_states(ref: Reference, acceleration: bool = False) -> torch.Tensor:
    """Network inputs (T, 2n): desired joints and velocities; with `acceleration` (T, 3n), and the
    desired accelerations."""
    return torch.cat([ref.q_d, ref.qd_d, ref.qdd_d] if acceleration else [ref.q_d, ref.qd_d], -1)


def pilot_residuals(
    plant: Plant,
    scenario: Scenario,
    ref: Reference,
    gains: Gains,
    model: Model,
    *,
    stride: int = 10,
    joint_scale: torch.Tensor | None = None,
    compile: bool = False,
    aot: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(x (N, 2n), residual torque (N, n)) every `stride` steps of an `smc_obs` run without payload;
    the residual is what the nominal model misses, tau - (M_hat qdd + C_hat qd + G_hat).
    `compile`, `aot`: as `simulate`'s."""
    q0, qd0 = ref.q_d[:1].clone(), ref.qd_d[:1].clone()
    ctrl = make_controller("smc_obs", gains, scenario.dt, model=model, joint_scale=joint_scale)
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
    resid = _missed_torque(model, roll, scenario.dt)[:, 0]
    x = desired_states(ref)[: resid.shape[0]]
    return x[::stride], resid[::stride]


def _missed_torque(model: Model, roll: Any, dt: float) -> torch.Tensor:
    """What `model` misses along an ideal-loop rollout (T + 1 rows, B environments): the applied
    torque less M_hat qdd + C_hat qd + G_hat at each step's start, qdd the step's mean
    acceleration; (T, B, n), N m (N)."""
    q, qd, tau = roll.q[:-1], roll.qd[:-1], roll.tau[:-1]
    qdd = (roll.qd[1:] - qd) / dt
    t, b, n = q.shape
    at = model.at(q.reshape(-1, n), qd.reshape(-1, n))
    rows = tau.reshape(-1, n) - at.m_times(qdd.reshape(-1, n)) - at.c_times(qd.reshape(-1, n)) - at.gravity()
    return rows.reshape(t, b, n)


def payload_residuals(
    plant: Plant,
    scenario: Scenario,
    ref: Reference,
    gains: Gains,
    model: Model,
    payloads: list[float],
    *,
    stride: int = 10,
    joint_scale: torch.Tensor | None = None,
    compile: bool = False,
    aot: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Phase 1's data: (x (N, 3n), residual torque (N, C, n)) every `stride` steps of calibration
    runs of the ideal loop, one per payload of `payloads` (C,) kg, each carried for the whole run,
    without the scenario's disturbance; the residual is what the nominal model misses,
    tau - (M_hat qdd + C_hat qd + G_hat), N m (N). The runs are `smc_exact`'s: a calibration knows
    the mass it attached, and its tracking keeps the state within ~1e-4 of the reference that x
    describes (`smc_obs` at the heavier payloads strays far enough to put 10-36 % errors into the
    residual as a function of x). `joint_scale`: the
    controllers' (`make_controller`); `compile`, `aot`: as `simulate`'s."""
    c = len(payloads)
    kw: dict[str, Any] = {"dtype": ref.q_d.dtype, "device": ref.q_d.device}
    q0, qd0 = ref.q_d[:1].expand(c, -1).clone(), ref.qd_d[:1].expand(c, -1).clone()
    quiet = plant.varied(torch.zeros(c, q0.shape[1], **kw), torch.zeros(c, **kw), torch.zeros(c, **kw))
    held = replace(scenario, payload_on=0.0, payload_off=scenario.duration)
    ctrl = make_controller("smc_exact", gains, scenario.dt, model=model, joint_scale=joint_scale, plant=quiet)
    roll = simulate(
        quiet, ctrl, held, ref, q0=q0, qd0=qd0, payload=torch.tensor(payloads, **kw), compile=compile, aot=aot
    )
    resid = _missed_torque(model, roll, scenario.dt)  # (T, C, n)
    x = desired_states(ref, acceleration=True)[: resid.shape[0]]
    return x[::stride], resid[::stride]


class PayloadBasis(NamedTuple):
    """Phase 1's fit on a network's Gaussians h (M,): the torque the nominal model misses carrying
    m kg is h^T (w0 + m per_kg); w0 (M, n) N m (N), per_kg (M, n) N m (N) per kg; `fit_error`:
    the relative RMS error of that fit on the held-out rows, per condition (C,); `joint_error`:
    the same over every condition, per joint (n,)."""

    w0: torch.Tensor
    per_kg: torch.Tensor
    fit_error: torch.Tensor
    joint_error: torch.Tensor

    def outputs(self, h: torch.Tensor, model_per_kg: torch.Tensor) -> torch.Tensor:
        """What `TwoPhase` is given along the reference (T, 3n), for features h (T, M) and the
        torque per kg that the nominal model carrying a payload adds there (`model_payload_torque`,
        (T, n)): [h^T w0, h^T per_kg, h^T per_kg - model_per_kg], the last what the network's
        payload direction adds beyond the model's own (its scaled inertia and gravity)."""
        phi = h @ self.per_kg.to(h)
        return torch.cat([h @ self.w0.to(h), phi, phi - model_per_kg.to(h)], -1)


def model_payload_torque(model: Model, ref: Reference) -> torch.Tensor:
    """The torque per kg (T, n) that `model` carrying a payload adds along the reference, M_hat
    qdd_d + C_hat qd_d + G_hat at 1 kg less at 0 kg (exact: a point mass enters affinely), N m (N)
    per kg."""
    q, qd, qdd = ref.q_d, ref.qd_d, ref.qdd_d

    def torque(kg: float) -> torch.Tensor:
        at = model.at(q, qd, payload=torch.full(q.shape[:1], kg, dtype=q.dtype, device=q.device))
        return at.m_times(qdd) + at.c_times(qd) + at.gravity()

    return torque(1.0) - torque(0.0)


def payload_basis(net: ControlNet, x: torch.Tensor, y: torch.Tensor, payloads: list[float]) -> PayloadBasis:
    """W0 and V of W = W0 + m V for `net`'s Gaussians from phase 1's data x (N, d), residuals y
    (N, C, n) at `payloads` (C,) kg: a ridge fit per condition (even rows train, odd ones choose
    the ridge), then the least-squares line through the C weights in m (the residual of a point
    mass is affine in m, so the weights are too)."""
    n, c = y.shape[-1], y.shape[1]
    h = net.features(x)
    flat = y.reshape(y.shape[0], c * n)
    w = ridge_fit(h[0::2], flat[0::2], h[1::2], flat[1::2]).weights.reshape(-1, c, n)  # (M, C, n)
    m = torch.tensor(payloads, dtype=w.dtype)
    dm = m - m.mean()
    # (no payload to rate, robot.rated_payload 0: every condition at 0 kg, V = 0)
    per_kg = torch.einsum("c,mcj->mj", dm, w - w.mean(1, keepdim=True)) / dm.square().sum().clamp_min(1e-12)
    w0 = w.mean(1) - m.mean() * per_kg
    pred = torch.einsum("nm,mcj->ncj", h[1::2], w0[:, None] + m[None, :, None] * per_kg[:, None])
    miss, held = (pred - y[1::2]).square(), y[1::2].square()
    err = miss.sum((0, 2)).sqrt() / held.sum((0, 2)).sqrt().clamp_min(1e-12)
    joint = miss.sum((0, 1)).sqrt() / held.sum((0, 1)).sqrt().clamp_min(1e-12)
    return PayloadBasis(w0, per_kg, err, joint)


def control_network(
    method: str,
    x: torch.Tensor,
    y: torch.Tensor,
    m: int,
    *,
    seed: int,
    sample_dt: float,
    aco: ACOConfig | None = None,
    warm_start: bool = False,
) -> ControlNet:
    """Centres and widths for the controller's network by `method` (rbfn.config.NETWORK_METHODS) from pilot
    data x (N, 2n), y (N, n) sampled every `sample_dt` s; even samples train, odd ones validate
    (widths, ridge, ACO's fit objective). `warm_start` starts the weights at the ridge fit of y."""
    entry = NETWORK_METHODS.get(method)
    if entry is None:
        raise ValueError(f"unknown centre method {method!r} for a fit; choose one of {list(NETWORK_METHODS)}")
    offset, scale = x.mean(0), x.std(0).clamp_min(1e-9)
    z = (x - offset) / scale
    objective = FitObjective(z[0::2], y[0::2], z[1::2], y[1::2], tail=False)
    g = torch.Generator().manual_seed(seed)
    if entry.selector is None:  # its own (grid): evenly along one period of the reference
        t0 = time.perf_counter()
        period_n = min(z.shape[0], max(m, int(round(PERIOD / sample_dt))))
        centers = z[torch.linspace(0, period_n - 1, m + 1)[:-1].round().long()]
        widths = choose_widths(objective, centers, "per_center", None, max_width=4.0)
        seconds = time.perf_counter() - t0
    else:
        aco = aco or ACOConfig()
        if entry.cluster:  # a new value: the caller's config is never mutated
            aco = replace(aco, objective=Objective.cluster)
        cfg = CentersConfig(name=method, method=entry.selector, width_rule=WidthRule.per_center, aco=aco)
        sel = select(cfg, objective, m, seed=seed, max_width=4.0, generator=g)
        centers, widths, seconds = sel.centers, sel.widths, sel.seconds
    w0 = torch.zeros(m, y.shape[1], dtype=x.dtype)
    if warm_start:
        a_tr = design_matrix(z[0::2], centers, widths, tail=False)
        a_val = design_matrix(z[1::2], centers, widths, tail=False)
        w0 = ridge_fit(a_tr, y[0::2], a_val, y[1::2]).weights
    return ControlNet(offset, scale, centers, widths, w0, seconds)
