"""Controllers for n joints: PD, computed torque, sliding mode (`smc`), `smc` with a momentum
observer (`smc_obs`), and the adaptive RBFN on top of either.

All but PD use the controller's nominal model M_hat = 0.9 M, C_hat = 0.8 C, G_hat = 0.85 G of
the unloaded robot (`rbfn.control.models`: the SCARA's closed form or any URDF arm). With
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
by orders of magnitude. Every controller is called once per control period with the step's
reference and the state; its own state (observer, weights) is a tensor per environment.
"""
from __future__ import annotations

from typing import cast

import torch

from ..config import BASE_CONTROLLERS, CONTROL_CENTER_METHODS, GainsConfig as Gains, Robust
from .models import ArmModel, NominalModel

__all__ = ["Gains", "NominalModel", "ArmModel", "Controller", "PD", "ComputedTorque", "SlidingMode",
           "Stacked", "make_controller"]

Model = NominalModel | ArmModel


class Controller:
    """A pure function of tensors, so the whole closed-loop step can be compiled and batched:
    `init_state(q0, qd0)` -> state tuple; `torque(ref, q, qd, state)` -> (tau (B, n), state),
    where ref = (q_d, qd_d, qdd_d (n,), h (M,) or None, alpha (0-dim): the adaptation step).
    """

    features: torch.Tensor | None = None

    def __init__(self, gains: Gains, dt: float, model: Model | None = None,
                 joint_scale: torch.Tensor | None = None) -> None:
        self.gains, self.dt, self.model = gains, dt, model or NominalModel()
        self.scale = joint_scale

    def _scaled(self, gain: float):
        """A torque gain on every joint: gain, or gain * joint_scale (n,)."""
        return gain if self.scale is None else gain * self.scale

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> tuple:
        return ()

    def alphas(self, t: torch.Tensor) -> torch.Tensor:
        """Adaptation step per control period alpha(t) = Gamma(t) dt at times t (s)."""
        return self.gains.gamma * self.dt / (1.0 + t / self.gains.gamma_decay)


class PD(Controller):
    """tau = Kp e + Kd de (no model)."""

    def torque(self, ref, q, qd, state):
        g = self.gains
        kp, kd = self._scaled(g.pd_kp or g.K * g.Lambda), self._scaled(g.pd_kd or g.K)
        return kp * (ref[0] - q) + kd * (ref[1] - qd), state


class ComputedTorque(Controller):
    """tau = M_hat (qdd_d + 2 Lambda de + Lambda^2 e) + C_hat qd + G_hat: critically damped at Lambda."""

    def torque(self, ref, q, qd, state):
        lam, at = self.gains.Lambda, self.model.at(q, qd)
        e, de = ref[0] - q, ref[1] - qd
        v = ref[2] + 2 * lam * de + lam * lam * e
        return at.m_times(v) + at.c_times(qd) + at.gravity(), state


class SlidingMode(Controller):
    """`smc`, with optional momentum observer and adaptive RBF network (see the module docstring).

    features: (T, M) Gaussian activations of the desired state at every step (precomputed, the
    inputs being the desired trajectory); w0: (M, n) initial weights (zeros: learn from scratch).
    State: (d_hat, observer integral, p0, W (B, M, n)).
    """

    def __init__(self, gains: Gains, dt: float, model: Model | None = None,
                 observer: bool = False, features: torch.Tensor | None = None,
                 w0: torch.Tensor | None = None, joint_scale: torch.Tensor | None = None) -> None:
        super().__init__(gains, dt, model, joint_scale)
        self.observer, self.features, self.w0 = observer, features, w0
        # per-environment masks of a `batched` one (set by init_state)
        self._observed: torch.Tensor | None = None
        self._own: torch.Tensor | None = None
        self.members: list[tuple[SlidingMode, int]] = []
        self.member_columns: list[int] = []  # a batched one's feature columns per member

    @classmethod
    def batched(cls, parts: list[SlidingMode], sizes: list[int]) -> SlidingMode:
        """Sliding-mode controllers that share gains, time step, model and joint scale as one
        controller of sum(sizes) environments (part i drives the i-th block of sizes[i]): one model
        evaluation per period for all of them. Its features are the parts' side by side (T, sum M_i);
        an environment adds d_hat only if its part has the observer, and W^T h over its own
        part's feature columns only (its W is zero elsewhere and stays so)."""
        first = parts[0]
        feats = [p.features for p in parts if p.features is not None]
        out = cls(first.gains, first.dt, first.model, any(p.observer for p in parts),
                  torch.cat(feats, -1) if feats else None, None, first.scale)
        out.members = list(zip(parts, sizes))
        # Public, so a compiled chunk's cache key (which leaves features out) sees the column split.
        out.member_columns = [0 if p.features is None else p.features.shape[1] for p in parts]
        return out

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> tuple:
        z = torch.zeros_like(q0)
        p0 = self.model.at(q0, qd0).m_times(qd0)
        if self.members:
            self._set_masks(q0)
        if self.features is None:
            return z, z.clone(), p0
        m, n = self.features.shape[1], q0.shape[1]
        if not self.members:
            w0 = z.new_zeros(m, n) if self.w0 is None else self.w0.to(z)
            return z, z.clone(), p0, w0.expand(q0.shape[0], m, n).clone()
        w = z.new_zeros(q0.shape[0], m, n)                    # each block's own columns hold its w0
        for part, rows, cols in self._blocks():
            if part.w0 is not None:
                w[rows, cols] = part.w0.to(z)
        return z, z.clone(), p0, w

    def _blocks(self):
        """(part, its environments' rows, its feature columns) of a batched controller."""
        r = c = 0
        for (part, size), k in zip(self.members, self.member_columns):
            yield part, slice(r, r + size), slice(c, c + k)
            r, c = r + size, c + k

    def _set_masks(self, like: torch.Tensor) -> None:
        """A batched controller's (B, 1) observer mask (None: every part has it) and (B, M) mask of
        each environment's own feature columns (None: one part's features span them all)."""
        b = like.shape[0]
        self._observed = self._own = None
        if not all(p.observer for p, _ in self.members):
            self._observed = torch.zeros(b, 1)
        if self.features is not None:
            self._own = torch.zeros(b, self.features.shape[1])
        for part, rows, cols in self._blocks():
            if self._observed is not None:
                self._observed[rows] = float(part.observer)
            if self._own is not None:
                self._own[rows, cols] = 1.0
        self._observed, self._own = (None if x is None else x.to(like) for x in (self._observed, self._own))

    def torque(self, ref, q, qd, state):
        g, dt = self.gains, self.dt
        q_d, v_d, a_d, h, alpha = ref
        e, de = q_d - q, v_d - qd
        s = torch.add(de, e, alpha=g.Lambda)        # x + alpha y in one operation: overhead-bound at small B
        at = self.model.at(q, qd)
        robust = torch.sign(s) if g.robust == Robust.sign else (s / g.boundary).clamp(-1.0, 1.0)
        tau = (at.m_times(torch.add(a_d, de, alpha=g.Lambda)) + at.c_times(torch.add(v_d, e, alpha=g.Lambda))
               + at.gravity())
        if self.scale is None:
            tau = torch.add(torch.add(tau, s, alpha=g.K), robust, alpha=g.epsilon)
        else:
            tau = tau + self._scaled(g.K) * s + self._scaled(g.epsilon) * robust
        d_hat, integral, p0 = state[:3]
        tau_m = tau                       # what the nominal model sees: no network, no observer
        if h is not None:
            w = state[3]
            if self._own is None:
                tau = tau + torch.einsum("m,bmj->bj", h, w)
            else:
                h = h * self._own                 # (B, M): each environment's own columns
                tau = tau + torch.einsum("bm,bmj->bj", h, w)
        if self.observer:
            # Generalized momentum of the nominal model p = M_hat qd. With tau_m the torque the
            # nominal model sees (the network's share removed) and beta = dM_hat/dt qd - C_hat qd
            # - G_hat, d_hat = K_o (p0 + int (tau_m + beta - d_hat) dt - p) obeys
            # d(d_hat)/dt = K_o (miss - d_hat): it tracks what the model (nominal + network) misses.
            d_hat = g.observer_gain * (integral + p0 - at.m_times(qd))
            tau = tau + (d_hat if self._observed is None else d_hat * self._observed)
            integral = torch.add(integral, tau_m + at.momentum_rate(), alpha=dt)
        if h is None:
            return tau, (d_hat, integral, p0)
        step = alpha * s if self.scale is None else alpha * (self.scale * s)
        w = w + h[..., None] * step[:, None, :]          # h (M,) or, batched, (B, M)
        if g.leakage:
            w = w * (1.0 - g.leakage * dt)
        return tau, (d_hat, integral, p0, w)


class Stacked(Controller):
    """Several controllers as one batch, so that one simulation runs them all: controller i drives
    the i-th block of `sizes[i]` environments. Consecutive sliding-mode controllers that share
    gains, time step, model and joint scale run as one (`SlidingMode.batched`: the model is
    evaluated once for all their environments). Its features are the parts' side by side
    (T, sum M_i), its adaptation steps one column per unit (T, K), its state the units' states."""

    def __init__(self, controllers: list[Controller], sizes: list[int]) -> None:
        if len(controllers) != len(sizes) or not controllers:
            raise ValueError(f"need one batch size per controller, got {len(sizes)} for {len(controllers)}")
        self.parts, self.sizes = list(controllers), list(sizes)
        runs: list[list[tuple[Controller, int]]] = []
        for c, size in zip(self.parts, self.sizes):
            if runs and _batchable(runs[-1][-1][0], c):
                runs[-1].append((c, size))
            else:
                runs.append([(c, size)])
        self.units = [r[0][0] if len(r) == 1
                      else SlidingMode.batched([cast(SlidingMode, c) for c, _ in r], [s for _, s in r])
                      for r in runs]
        self.unit_sizes = [sum(s for _, s in r) for r in runs]
        feats = [c.features for c in self.units if c.features is not None]
        self.features = torch.cat(feats, -1) if feats else None
        self.columns: list[slice | None] = []
        start = 0
        for c in self.units:
            m = 0 if c.features is None else c.features.shape[-1]
            self.columns.append(slice(start, start + m) if m else None)
            start += m

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> tuple:
        return tuple(c.init_state(q, qd) for c, q, qd in
                     zip(self.units, q0.split(self.unit_sizes), qd0.split(self.unit_sizes)))

    def alphas(self, t: torch.Tensor) -> torch.Tensor:
        return torch.stack([c.alphas(t) for c in self.units], -1)

    def torque(self, ref, q, qd, state):
        q_d, v_d, a_d, h, alpha = ref
        taus, states = [], []
        for i, (c, qi, qdi) in enumerate(zip(self.units, q.split(self.unit_sizes), qd.split(self.unit_sizes))):
            cols = self.columns[i]
            tau, st = c.torque((q_d, v_d, a_d, None if cols is None else h[cols], alpha[i]), qi, qdi, state[i])
            taus.append(tau)
            states.append(st)
        return torch.cat(taus), tuple(states)


def _batchable(a: Controller, b: Controller) -> bool:
    """Whether sliding-mode controllers a and b can run as one: equal gains, time step, joint
    scale and model (the same object, or the SCARA's with the same coefficients)."""
    if type(a) is not SlidingMode or type(b) is not SlidingMode or a.gains != b.gains or a.dt != b.dt:
        return False
    same_scale = a.scale is b.scale or (a.scale is not None and b.scale is not None and torch.equal(a.scale, b.scale))
    same_model = a.model is b.model or (type(a.model) is type(b.model) is NominalModel
                                        and vars(a.model) == vars(b.model))
    return same_scale and same_model


def make_controller(name: str, gains: Gains, dt: float, model: Model | None = None,
                    features: torch.Tensor | None = None, w0: torch.Tensor | None = None,
                    observer: bool = True, joint_scale: torch.Tensor | None = None) -> Controller:
    """Controller by name: pd, ctc, smc, smc_obs, or arbfn* (needs `features`). `model`: the
    nominal model (default: the SCARA's); `joint_scale` (n,): per-joint factor of the torque gains."""
    if name == "pd":
        return PD(gains, dt, model, joint_scale)
    if name == "ctc":
        return ComputedTorque(gains, dt, model, joint_scale)
    if name == "smc":
        return SlidingMode(gains, dt, model, joint_scale=joint_scale)
    if name == "smc_obs":
        return SlidingMode(gains, dt, model, observer=True, joint_scale=joint_scale)
    if name.startswith("arbfn"):
        if features is None:
            raise ValueError(f"controller {name!r} needs RBF features (T, M)")
        return SlidingMode(gains, dt, model, observer=observer, features=features, w0=w0, joint_scale=joint_scale)
    raise ValueError(f"unknown controller {name!r}; choose one of {list(BASE_CONTROLLERS)} or "
                     f"arbfn_<{'|'.join(CONTROL_CENTER_METHODS)}>")
