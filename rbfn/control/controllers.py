"""Controllers for n joints: PD, computed torque, sliding mode (`smc`), `smc` with a momentum
observer (`smc_obs`), and the adaptive RBFN on top of either.

All but PD use the controller's nominal model M_hat = 0.9 M, C_hat = 0.8 C, G_hat = 0.85 G of
the unloaded robot (`rbfn.control.models.NominalModel`; the factors are the gains'). With
e = q_d - q, s = de + Lambda e, the reference velocity qr' = qd_d + Lambda e and acceleration
qr'' = qdd_d + Lambda de:

    smc:     tau = M_hat qr'' + C_hat qr' + G_hat + K s + epsilon sgn(s)      (sgn or saturation)
    smc_obs: ... + d_hat, d_hat the generalized-momentum observer's estimate of what the nominal
             model misses (friction, disturbance, payload, model error)
    arbfn:   ... + W^T h(x), h Gaussian features of the desired state x = (q_d, qd_d), with
             dW/dt = Gamma(t) h s^T - leakage W, Gamma(t) = gamma / (1 + t / gamma_decay); with
             the observer on (the default) the observer sees model + network and catches what
             the network has not learnt yet, such as a sudden load. Per control period the
             update is W += alpha h s^T with alpha = Gamma dt: the paper's alpha(0) = 0.5 at
             dt = 1 ms is gamma = 500.
A composite term (the observer's residual as a prediction error driving W) was tried: with a
heavy unknown payload the residual grows with the applied torque itself (it holds
(M - M_hat) qdd), so the network and the observer integrate together and diverged at 20 kg.

The torque gains K, epsilon, pd_kp, pd_kd and gamma act on joint j times `joint_scale[j]` (an
(n,) tensor; None: 1 on every joint), so one set of gains serves joints whose inertias differ
by orders of magnitude. Every controller is called once per control period with the period's
Reference and its state (`SlidingState`: observer and weights, per environment). Running several
controllers as one batch is `rbfn.control.batch`'s business, not the laws'.

Why one module of over 500 lines: every controller and its builder (`make_controller`, one
entry per name of `rbfn.config.BASE_CONTROLLERS`), which share the sliding-mode law, its state and
the nominal model.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import torch

from ..config import ADAPTIVE, BASE_CONTROLLERS, NETWORK_METHODS, GainsConfig as Gains, Robust, network_method
from .loop import Applied
from .models import NominalModel
from .trajectory import Reference

__all__ = [
    "Gains",
    "NominalModel",
    "Reference",
    "Controller",
    "PD",
    "pd_gains",
    "ComputedTorque",
    "SlidingMode",
    "SlidingState",
    "ExactSliding",
    "TwoPhase",
    "TwoPhaseState",
    "InertiaSchedule",
    "observer_factor",
    "Forces",
    "JointRates",
    "make_controller",
]

Model = NominalModel


class SlidingState(NamedTuple):
    """A sliding-mode controller's state, each per environment: the observer's estimate d_hat
    (B, n) of the torque the nominal model misses, its integral (B, n) of (tau_m + beta) dt, the
    initial momentum p0 = M_hat(q0) qd0 (B, n), and the network's weights w (B, M, n) (None
    without a network); for the realistic loop (`rbfn.control.loop`) also the last period's known
    momentum rate beta and the share of the last command that is not the nominal law's. N m (N),
    N m s (N s)."""

    d_hat: torch.Tensor
    integral: torch.Tensor
    p0: torch.Tensor
    w: torch.Tensor | None = None
    beta: torch.Tensor | None = None  # the realistic loop: the last period's dM_hat/dt qd - C_hat qd - G_hat
    share: torch.Tensor | None = None  # the realistic loop: the observer's and network's share of the command


class Forces(NamedTuple):
    """What only the perfect-knowledge controller is told each period: the payload's load
    (`Plant.load`, each (B,)) and the disturbance torque now ((), or (n,)), N m (N)."""

    load: tuple[torch.Tensor, ...]
    dist: torch.Tensor


class JointRates(NamedTuple):
    """Per-joint factors (n,) of the sliding-mode law's integrators (`gains.inertia_scaling`): of
    the observer's gain K_o and of the adaptation rate Gamma. Dimensionless."""

    observer: torch.Tensor
    gamma: torch.Tensor


class Controller:
    """A pure function of tensors, so the whole closed-loop step can be compiled and batched:
    `init_state(q0, qd0)` -> its state (a pytree of tensors; () for PD and computed torque);
    `torque(ref, q, qd, state, h=, alpha=, applied=, forces=)` -> (tau (B, n), state), with ref
    this period's Reference (each (n,) or (B, n)), h the features (M,) or None, alpha the
    adaptation step (0-dim), applied the realistic loop's `Applied` (None in the ideal loop) and
    forces the true payload and disturbance (`Forces`, given only where `needs_forces`; else None).
    """

    features: torch.Tensor | None = None
    needs_forces = False  # True: the simulator passes forces= (the perfect-knowledge ceiling only)

    def __init__(
        self, gains: Gains, dt: float, model: Model | None = None, joint_scale: torch.Tensor | None = None
    ) -> None:
        self.gains, self.dt = gains, dt
        self.model: Any = model  # None only for a controller that needs no model (PD, smc_exact)
        self.scale = joint_scale

    def _scaled(self, gain: float):
        """A torque gain on every joint: gain, or gain * joint_scale (n,)."""
        return gain if self.scale is None else gain * self.scale

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> Any:
        return ()

    def torque(
        self,
        ref: Reference,
        q: torch.Tensor,
        qd: torch.Tensor,
        state: Any,
        *,
        h: torch.Tensor | None = None,
        alpha: torch.Tensor | None = None,
        applied: Applied | None = None,
        forces: Forces | None = None,
    ) -> tuple[torch.Tensor, Any]:
        raise NotImplementedError

    def share(self, state: Any, like: torch.Tensor) -> torch.Tensor:
        """The part of the last command (B, n) that is not the nominal law's (observer, network):
        what the realistic loop subtracts from the applied torque to tell the observer its
        nominal share. Zeros (like `like`) for a controller without either."""
        return torch.zeros_like(like)

    def alphas(self, t: torch.Tensor) -> torch.Tensor:
        """Adaptation step per control period alpha(t) = Gamma(t) dt at times t (s)."""
        return self.gains.gamma * self.dt / (1.0 + t / self.gains.gamma_decay)


def pd_gains(gains: Gains) -> tuple[float, float]:
    """(Kp, Kd) of `pd`, per unit of the joint scale: gains.pd_kp and pd_kd, or where 0 the
    sliding-mode feedback's own, K Lambda and K."""
    return gains.pd_kp or gains.K * gains.Lambda, gains.pd_kd or gains.K


class PD(Controller):
    """tau = Kp e + Kd de (no model); the gains `pd_gains`."""

    def torque(self, ref, q, qd, state, *, h=None, alpha=None, applied=None, forces=None):
        kp, kd = (self._scaled(v) for v in pd_gains(self.gains))
        return kp * (ref.q_d - q) + kd * (ref.qd_d - qd), state


class ComputedTorque(Controller):
    """tau = M_hat (qdd_d + 2 Lambda de + Lambda^2 e) + C_hat qd + G_hat: critically damped at Lambda."""

    def torque(self, ref, q, qd, state, *, h=None, alpha=None, applied=None, forces=None):
        lam, at = self.gains.Lambda, self.model.at(q, qd)
        e, de = ref.q_d - q, ref.qd_d - qd
        v = ref.qdd_d + 2 * lam * de + lam * lam * e
        return at.m_times(v) + at.c_times(qd) + at.gravity(), state


class SlidingMode(Controller):
    """`smc`, with optional momentum observer and adaptive RBF network (see the module docstring).

    features: (T, M) Gaussian activations of the desired state at every step (precomputed, the
    inputs being the desired trajectory), or per environment (T, B, M) (a network of its own in
    each, as a colony's candidates); w0: (M, n) initial weights (zeros: learn from scratch), or
    per environment (B, M, n).
    State: a SlidingState. Several of them run as one batch through `rbfn.control.batch`.
    """

    def __init__(
        self,
        gains: Gains,
        dt: float,
        model: Model | None = None,
        *,
        observer: bool = False,
        features: torch.Tensor | None = None,
        w0: torch.Tensor | None = None,
        joint_scale: torch.Tensor | None = None,
        rates: JointRates | None = None,
    ) -> None:
        super().__init__(gains, dt, model, joint_scale)
        self.observer, self.features, self.w0 = observer, features, w0
        self.rates = rates  # None: K_o and Gamma on every joint

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> SlidingState:
        z = torch.zeros_like(q0)
        p0 = self.model.at(q0, qd0).m_times(qd0)
        if self.features is None:
            return SlidingState(z, z.clone(), p0, None, z.clone(), z.clone())
        m, n = self.features.shape[-1], q0.shape[1]
        w0 = z.new_zeros(m, n) if self.w0 is None else self.w0.to(z)
        return SlidingState(z, z.clone(), p0, w0.expand(q0.shape[0], m, n).clone(), z.clone(), z.clone())

    def share(self, state: SlidingState, like: torch.Tensor) -> torch.Tensor:
        assert state.share is not None
        return state.share

    def observer_gain(self) -> float | torch.Tensor:
        """K_o: one gain for every joint, or per joint (n,) (`rates`); a batch's per environment
        (B, 1) or (B, n)."""
        k = self.gains.observer_gain
        return k if self.rates is None else k * self.rates.observer

    def torque(
        self,
        ref: Reference,
        q: torch.Tensor,
        qd: torch.Tensor,
        state: SlidingState,
        *,
        h: torch.Tensor | None = None,
        alpha: torch.Tensor | None = None,
        applied: Applied | None = None,
        forces: Forces | None = None,
    ) -> tuple[torch.Tensor, SlidingState]:
        """tau (B, n) and the next state at joints q, velocities qd (B, n); h: this period's
        features (M,), or per environment (B, M); alpha: its adaptation step (0-dim).

        applied: the realistic loop's account of the last period's torque (`rbfn.control.loop`),
        where the torque that acts is not the command. The observer then integrates the last
        period with the nominal share of the torque actually applied (`applied.known`, known after
        the fact: the command delayed and saturated) rather than with this period's command, so
        it does not wind up against saturation and delay; the adaptation ignores |s_j| below
        `gains.dead_zone` (a noise floor, Peterson and Narendra's dead zone: measurement noise
        alone cannot drift the weights) and joints whose torque was saturated (it cannot learn
        what the actuator did not apply)."""
        g, dt = self.gains, self.dt
        e, de = ref.q_d - q, ref.qd_d - qd
        s = torch.add(de, e, alpha=g.Lambda)  # x + alpha y in one operation: overhead-bound at small B
        at = self.model.at(q, qd)
        robust = torch.sign(s) if g.robust == Robust.sign else (s / g.boundary).clamp(-1.0, 1.0)
        tau = (
            at.m_times(torch.add(ref.qdd_d, de, alpha=g.Lambda))
            + at.c_times(torch.add(ref.qd_d, e, alpha=g.Lambda))
            + at.gravity()
        )
        if self.scale is None:
            tau = torch.add(torch.add(tau, s, alpha=g.K), robust, alpha=g.epsilon)
        else:
            tau = tau + self._scaled(g.K) * s + self._scaled(g.epsilon) * robust
        d_hat, integral, p0, w, beta, share = state
        tau_m = tau  # what the nominal model sees: no network, no observer
        if h is not None:
            tau = tau + torch.einsum("m,bmj->bj" if h.dim() == 1 else "bm,bmj->bj", h, w)
        if self.observer:
            # Generalized momentum of the nominal model p = M_hat qd. With tau_m the torque the
            # nominal model sees (the network's share removed) and beta = dM_hat/dt qd - C_hat qd
            # - G_hat, d_hat = K_o (p0 + int (tau_m + beta - d_hat) dt - p) obeys
            # d(d_hat)/dt = K_o (miss - d_hat): it tracks what the model (nominal + network) misses.
            if applied is not None:  # the last period, as it was applied
                assert beta is not None
                integral = integral + dt * (applied.known + beta)
            d_hat = self.observer_gain() * (integral + p0 - at.m_times(qd))
            tau = tau + d_hat
            if applied is None:
                integral = torch.add(integral, tau_m + at.momentum_rate(), alpha=dt)
            else:
                beta = at.momentum_rate()
        if applied is not None:
            share = tau - tau_m
        if h is None:
            return tau, SlidingState(d_hat, integral, p0, w, beta, share)
        assert w is not None and alpha is not None  # a network has weights and a step
        if applied is not None:  # a 0/1 mask: exact
            s = s * ((s.abs() > g.dead_zone).to(s) * (1.0 - applied.saturated))
        step = alpha * s if self.scale is None else alpha * (self.scale * s)
        if self.rates is not None:
            step = step * self.rates.gamma
        w = w + h[..., None] * step[:, None, :]  # h (M,) or (B, M)
        if g.leakage:
            w = w * (1.0 - g.leakage * dt)
        return tau, SlidingState(d_hat, integral, p0, w, beta, share)


class ExactSliding(Controller):
    """`smc_exact`, the perfect-knowledge ceiling: the sliding-mode feedback with every force known
    exactly, the plant's own M, C qd, G with the payload, friction and the disturbance:

        tau = M (qdd_d + Lambda de) + C qd + G + F(qd) + tau_d(t) + K s + epsilon sgn(s),

    so that M ds/dt = -K s - epsilon sgn(s) with exact state: what is left of its error is what
    sensing, timing and actuation allow. M and the rest come from the plant's forward dynamics
    (n + 1 evaluations of `Plant.accel` and one solve), at the state the controller measures."""

    needs_forces = True

    def __init__(self, gains: Gains, dt: float, plant: Any, joint_scale: torch.Tensor | None = None) -> None:
        super().__init__(gains, dt, None, joint_scale)
        self.plant = plant

    def torque(self, ref, q, qd, state, *, h=None, alpha=None, applied=None, forces=None):
        assert forces is not None  # the simulator passes them to a controller that needs_forces
        g, n = self.gains, q.shape[-1]
        e, de = ref.q_d - q, ref.qd_d - qd
        s = de + g.Lambda * e
        robust = torch.sign(s) if g.robust == Robust.sign else (s / g.boundary).clamp(-1.0, 1.0)
        zero = torch.zeros_like(q)
        a0 = self.plant.accel(q, qd, zero, forces.load)  # -M^-1 (C qd + G + F)
        eye = torch.eye(n, dtype=q.dtype, device=q.device)
        m_inv = torch.stack([self.plant.accel(q, qd, eye[j].expand_as(q), forces.load) - a0 for j in range(n)], -1)
        feedforward = torch.linalg.solve(m_inv, ref.qdd_d + g.Lambda * de - a0)  # M (qr'' ) + C qd + G + F
        tau = feedforward + forces.dist + self._scaled(g.K) * s + self._scaled(g.epsilon) * robust
        return tau, state


class InertiaSchedule(NamedTuple):
    """The nominal model's inertia diagonal at home as a function of the payload it carries,
    M_jj(m) = base_j + per_kg_j m (exact for a point mass; `ControlRobot.inertia_schedule`), and
    the heaviest payload the design allows, `high` = 1.25 x robot.rated_payload: base (n,) kg m^2
    (kg), per_kg (n,) m^2 (1), high kg."""

    base: torch.Tensor
    per_kg: torch.Tensor
    high: float


def observer_factor(gains: Gains, scale: torch.Tensor, inertia: torch.Tensor) -> torch.Tensor:
    """The observer gain's per-joint factor min(1, K s_j / (K_o M_jj)) for the joint scale s (n,)
    and inertia diagonal M_jj (n,) or per environment (B, n): the observer no faster than the
    feedback's bandwidth K s_j / M_jj at that inertia. Dimensionless, the shape of `inertia`."""
    return (gains.K * scale / (gains.observer_gain * inertia)).clamp(max=1.0)


class TwoPhaseState(NamedTuple):
    """`TwoPhase`'s state, per environment: the sliding-mode law's (`SlidingState`, its w unused)
    on the model carrying the estimate; the estimator's momentum observer, on the nominal model:
    its integral (B, n), initial momentum (B, n), last momentum rate (B, n) and estimate d_e (B, n)
    of what the nominal model misses less the command's share; the payload estimate m_hat (B,)
    kg; and, in a batch of such laws (`rbfn.control.batch.TwoPhaseBatch`), each environment's
    settings (`TwoPhase.settings`: rate (B,), growth cap (B, 1), feedforward (B, n)), carried
    unchanged, so that a compiled package takes them as inputs (None: the controller's own).
    N m (N), N m s (N s)."""

    law: SlidingState
    e_integral: torch.Tensor
    e_p0: torch.Tensor
    e_beta: torch.Tensor
    d_e: torch.Tensor
    m_hat: torch.Tensor
    settings: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None


class TwoPhase(Controller):
    """`arbfn_<method>` under `control.network.law=two_phase`: the paper's two phases.

    Phase 1 (offline, `rbfn.control.network.payload_basis`) fits the torque the nominal model
    misses, recorded at payloads from 0 to 1.25x the rated one, as W^T h(x) with W = W0 + m V
    for a payload of m kg, h the network's Gaussians of the desired state x = (q_d, qd_d, qdd_d).
    The features this law is given are that network's outputs along the reference (T, 3n):
    [h^T W0, h^T V, h^T V - Y], the unloaded robot's residual, the payload's torque per kg and
    what of it the nominal model carrying the payload leaves (Y: the model's own torque per kg,
    `rbfn.control.network.model_payload_torque`; the model's factors scale the payload too).

    Phase 2 (online) adapts only the network's coordinate m along V, the payload estimate m_hat,
    by normalised LMS on a prediction error: a second momentum observer, on the nominal model and
    `gains.estimator_gain` fast (it acts only through m_hat), estimates d_e ~ r - share, r the
    torque the nominal model misses and share the command's part that is not the nominal law's,
    so the error is

        err = d_e + share - h^T W0 - m_hat h^T V,  m_hat += mu (phi^T D err) / (phi^T D phi + eps)

    with phi = h^T V, D = diag(1 / s_j^2) (joints in comparable units), mu = `gains.estimate_rate`,
    m_hat kept within [0, schedule.high]. The sliding-mode law then runs on the nominal model
    carrying m_hat, its feedback gain grown by g_j = M_jj(m_hat) / M_jj(design) (at most
    `gains.feedback_growth`) and the observer's gain following (`observer_factor` at g_j K and
    M_jj(m_hat), instead of held at the rated payload's), plus what the network says that model
    misses:

        tau = M_hat(m_hat) qr'' + C_hat(m_hat) qr' + G_hat(m_hat) + g K s + eps sat(s)
              + h^T W0 + m_hat (h^T V - Y) + d_hat.

    The controller is not told the payload: the rating bounds m_hat, as it bounds the design.
    `feedforward` (n,), 1 or 0 per joint (None: every joint 1), keeps or drops the network's terms
    h^T W0 + m_hat (h^T V - Y) in tau on that joint (`control.network.feedforward`); the estimate
    uses the network on every joint either way.

    `velocity_lag` (s, `rbfn.control.loop.velocity_lag`; `control.network.lag_compensation`): the
    law compares the measured velocity with the reference's as the loop would measure it,
    de = qd_d - velocity_lag qdd_d - qd. Compared with qd_d itself, a filtered velocity shows a
    tracking error of about velocity_lag qdd_d where there is none, and the feedback answers it
    with a torque (K + M Lambda) velocity_lag qdd_d that acts like extra inertia (the SCARA, 50 Hz
    filter: about 0.2 M qdd, twice what the nominal model's 0.9 M misses); the observer then has
    to take back the network's correct prediction of the missing inertia, and the prediction hurt
    the tracking."""

    features: torch.Tensor

    def __init__(
        self,
        gains: Gains,
        dt: float,
        model: Model,
        features: torch.Tensor,
        schedule: InertiaSchedule,
        joint_scale: torch.Tensor | None = None,
        feedforward: torch.Tensor | None = None,
        velocity_lag: float = 0.0,
    ) -> None:
        super().__init__(gains, dt, model, joint_scale)
        self.features, self.schedule, self.feedforward = features, schedule, feedforward
        self.velocity_lag = velocity_lag

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> TwoPhaseState:
        z = torch.zeros_like(q0)
        m = torch.full(q0.shape[:1], float(self.model.payload), dtype=q0.dtype, device=q0.device)
        p0 = self.model.at(q0, qd0, payload=m).m_times(qd0)
        law = SlidingState(z, z.clone(), p0, None, z.clone(), z.clone())
        return TwoPhaseState(law, z.clone(), self.model.at(q0, qd0).m_times(qd0), z.clone(), z.clone(), m)

    def share(self, state: TwoPhaseState, like: torch.Tensor) -> torch.Tensor:
        assert state.law.share is not None
        return state.law.share

    def settings(self) -> tuple[float, float, torch.Tensor | None]:
        """(the estimate's step `gains.estimate_rate`, the feedback's most growth
        `gains.feedback_growth`, the feedforward joints (n,) or None: every joint); a batch of
        such controllers (`rbfn.control.batch.TwoPhaseBatch`) carries them per environment in
        its state (`TwoPhaseState.settings`)."""
        return self.gains.estimate_rate, self.gains.feedback_growth, self.feedforward

    def _inertia(self, m: torch.Tensor | float, like: torch.Tensor) -> torch.Tensor:
        """M_jj(m) = base_j + per_kg_j m at payloads m (B, 1) or one payload: (B, n) or (n,)."""
        return self.schedule.base.to(like) + self.schedule.per_kg.to(like) * m

    def torque(
        self,
        ref: Reference,
        q: torch.Tensor,
        qd: torch.Tensor,
        state: TwoPhaseState,
        *,
        h: torch.Tensor | None = None,
        alpha: torch.Tensor | None = None,
        applied: Applied | None = None,
        forces: Forces | None = None,
    ) -> tuple[torch.Tensor, TwoPhaseState]:
        """tau (B, n) and the next state; h: this period's [h^T W0, h^T V, h^T V - Y] (3n,) or
        per environment (B, 3n); alpha unused (the estimate's step is `gains.estimate_rate`)."""
        assert h is not None  # the network's outputs along the reference
        g, dt, n = self.gains, self.dt, q.shape[-1]
        law, e_integral, e_p0, e_beta, d_e, m, _ = state
        rate, cap, feedforward = self.settings() if state.settings is None else state.settings
        resid0, phi, beyond = h[..., :n], h[..., n : 2 * n], h[..., 2 * n :]
        e, de = ref.q_d - q, ref.qd_d - qd
        if self.velocity_lag:
            de = de - self.velocity_lag * ref.qdd_d  # the reference's velocity as the loop measures it
        s = de + g.Lambda * e
        at = self.model.at(q, qd, payload=m)  # the model carrying the estimate
        robust = torch.sign(s) if g.robust == Robust.sign else (s / g.boundary).clamp(-1.0, 1.0)
        tau_m = at.m_times(ref.qdd_d + g.Lambda * de) + at.c_times(ref.qd_d + g.Lambda * e) + at.gravity()
        # Each joint's feedback grows by how much heavier it is than the model's design, so that it
        # keeps its bandwidth whatever it carries; capped where the estimate is wrong (it overshoots
        # a payload's arrival and lags its removal) and where the diagonal understates the coupled
        # joints' dynamics: uncapped, the feedback saturated.
        inertia = self._inertia(m[:, None], q)  # M_jj(m_hat) (B, n)
        growth = (inertia / self._inertia(float(self.model.payload), q)).clamp(max=cap)
        tau_m = tau_m + self._scaled(g.K) * growth * s + self._scaled(g.epsilon) * robust
        # The law's observer on the model carrying the estimate: its gain min(1, K s_j / (K_o M_jj))
        # with the feedback's gain and the inertia grown alike (the unloaded joint's rate).
        integral, beta = law.integral, law.beta
        if applied is not None:
            assert beta is not None
            integral = integral + dt * (applied.known + beta)
        unit = torch.ones_like(q[0]) if self.scale is None else self.scale.to(q)
        factor = observer_factor(self.gains, unit * growth, inertia)
        d_hat = g.observer_gain * factor * (integral + law.p0 - at.m_times(qd))
        predicted = resid0 + m[:, None] * beyond
        if feedforward is not None:
            predicted = predicted * feedforward.to(q)
        tau = tau_m + predicted + d_hat
        beta = at.momentum_rate()
        if applied is None:  # the ideal loop: this period's nominal share acts as commanded
            integral = integral + dt * (tau_m + beta)
        share = tau - tau_m
        # The estimator: its own observer on the nominal model, what that model misses less the share.
        at0 = self.model.at(q, qd)
        known = tau_m if applied is None else applied.known
        if applied is not None:
            e_integral = e_integral + dt * (known + e_beta - d_e)
        d_e = g.estimator_gain * (e_integral + e_p0 - at0.m_times(qd))
        e_beta = at0.momentum_rate()
        if applied is None:
            e_integral = e_integral + dt * (known + e_beta - d_e)
        weight = torch.ones_like(q[0]) if self.scale is None else 1.0 / self.scale.to(q) ** 2
        err = d_e + share - resid0 - m[:, None] * phi
        num = (phi * weight * err).sum(-1)
        den = (phi * phi * weight).sum(-1) + 1e-3 * weight.sum()
        m = (m + rate * num / den).clamp(0.0, self.schedule.high)
        law = SlidingState(d_hat, integral, law.p0, None, beta, share)
        return tau, TwoPhaseState(law, e_integral, e_p0, e_beta, d_e, m, state.settings)


def make_controller(
    name: str,
    gains: Gains,
    dt: float,
    *,
    model: Model | None = None,
    features: torch.Tensor | None = None,
    w0: torch.Tensor | None = None,
    observer: bool = True,
    joint_scale: torch.Tensor | None = None,
    plant: Any = None,
    rates: JointRates | None = None,
    law: str = "tracking",
    schedule: InertiaSchedule | None = None,
    feedforward: torch.Tensor | None = None,
    velocity_lag: float = 0.0,
) -> Controller:
    """Controller by name: pd, ctc, smc, smc_obs, smc_exact (needs the `plant`), or arbfn* (needs
    `features`). `model`: the nominal model (`rbfn.control.models.NominalModel`; all but pd and
    smc_exact need it); `joint_scale` (n,): per-joint
    factor of the torque gains; `rates`: per-joint factors of the sliding-mode law's observer gain
    and adaptation rate (None: 1). `law`: the adaptive network's (`control.network.law`):
    `tracking`, features h (T, M) and dW/dt = Gamma h s^T from `w0`; `two_phase` (`TwoPhase`),
    features [h^T W0, h^T V, h^T V - Y] (T, 3n), the inertia `schedule` and the joints it feeds
    the network's torque forward on (`feedforward` (n,), None: every joint) and the loop's
    `velocity_lag` it compensates (s, `TwoPhase`)."""
    spec = _Spec(
        name, gains, dt, model, features, w0, observer, joint_scale, plant, rates, law, schedule, feedforward,
        velocity_lag,
    )  # fmt: skip
    build = _BUILDERS.get(name) or (_adaptive if name == ADAPTIVE.rstrip("_") or network_method(name) else None)
    if build is None:
        raise ValueError(
            f"unknown controller {name!r}; choose one of {list(BASE_CONTROLLERS)} or "
            f"{ADAPTIVE}<{'|'.join(NETWORK_METHODS)}>"
        )
    if model is None and name not in ("pd", "smc_exact"):
        raise ValueError(f"controller {name!r} needs the nominal model (model=rbfn.control.models.NominalModel)")
    return build(spec)


class _Spec(NamedTuple):
    """`make_controller`'s arguments, as each builder takes them."""

    name: str
    gains: Gains
    dt: float
    model: Any
    features: torch.Tensor | None
    w0: torch.Tensor | None
    observer: bool
    joint_scale: torch.Tensor | None
    plant: Any
    rates: JointRates | None
    law: str
    schedule: InertiaSchedule | None
    feedforward: torch.Tensor | None
    velocity_lag: float


def _exact(s: _Spec) -> Controller:
    if s.plant is None:
        raise ValueError("controller 'smc_exact' needs the plant (it knows every force exactly)")
    return ExactSliding(s.gains, s.dt, s.plant, s.joint_scale)


def _adaptive(s: _Spec) -> Controller:
    """arbfn and arbfn_<method>: the adaptive network under its law (`control.network.law`)."""
    if s.features is None:
        raise ValueError(f"controller {s.name!r} needs RBF features (T, M)")
    if s.law == "two_phase":
        if s.schedule is None:
            raise ValueError(f"controller {s.name!r} under law 'two_phase' needs the inertia schedule")
        return TwoPhase(
            s.gains, s.dt, s.model, s.features, s.schedule, joint_scale=s.joint_scale, feedforward=s.feedforward,
            velocity_lag=s.velocity_lag,
        )  # fmt: skip
    if s.law != "tracking":
        raise ValueError(f"unknown adaptive law {s.law!r}; choose 'two_phase' or 'tracking'")
    return SlidingMode(
        s.gains,
        s.dt,
        s.model,
        observer=s.observer,
        features=s.features,
        w0=s.w0,
        joint_scale=s.joint_scale,
        rates=s.rates,
    )


# Each controller of rbfn.config.BASE_CONTROLLERS (its names, and docs/control.md's table), built
# from make_controller's arguments; the adaptive network is `_adaptive`.
_BUILDERS: dict[str, Callable[[_Spec], Controller]] = {
    "pd": lambda s: PD(s.gains, s.dt, s.model, s.joint_scale),
    "ctc": lambda s: ComputedTorque(s.gains, s.dt, s.model, s.joint_scale),
    "smc": lambda s: SlidingMode(s.gains, s.dt, s.model, joint_scale=s.joint_scale, rates=s.rates),
    "smc_obs": lambda s: SlidingMode(s.gains, s.dt, s.model, observer=True, joint_scale=s.joint_scale, rates=s.rates),
    "smc_exact": _exact,
}
assert set(_BUILDERS) == set(BASE_CONTROLLERS), "each rbfn.config.BASE_CONTROLLERS name needs its builder here"
