"""Online IK adaptation in the closed loop: the learned IK corrects itself on a robot whose
kinematics differ from the model it was trained on.

Each control period: x_d -> IK network -> q_d -> smc_obs -> simulator -> q -> p = FK_real(q);
every `update_every` periods the learner adapts the network's output weights on the recent
pairs (p, q). Environments are batched: one per (perturbation size, adapt on/off). The
perturbation is kinematic (link lengths, joint offsets in FK_real); the dynamics stay nominal.
The joint references' velocity and acceleration come from the network's design rows along the
desired path, differentiated in time on the control grid, times the current weights.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import torch

from ..config import GainsConfig, OnlineConfig, PathName
from ..layer import RBFNetwork
from ..lms import make_learner
from ..robots.scara import ScaraParams, fk, ik
from .aot import aot_chunk, chunk_key
from .controllers import make_controller
from .simulator import ScaraPlant, Scenario, make_chunk, stage_disturbances
from .trajectory import paper_trajectory

log = logging.getLogger(__name__)

__all__ = ["RealRobot", "desired_path", "run_online", "perturbation_sizes"]


@dataclass
class RealRobot:
    """Kinematics of the real arm: link lengths scaled by (1 + link_error), joint offsets added.
    Batched: link_error (B, 2), offset (B, 3)."""

    link_error: torch.Tensor
    offset: torch.Tensor
    params: ScaraParams = ScaraParams()

    def fk(self, q: torch.Tensor) -> torch.Tensor:
        """Measured positions (..., B, 3) of joints q (..., B, 3)."""
        p = replace(self.params, l1=self.params.l1 * (1 + self.link_error[:, 0]),
                    l2=self.params.l2 * (1 + self.link_error[:, 1]))
        return fk(q + self.offset, p)


def perturbation_sizes(cfg: OnlineConfig, sizes: list[float], **kw) -> tuple[torch.Tensor, torch.Tensor]:
    """Link errors (S, 2) and joint offsets (S, 3) of each sweep row: the configured perturbation
    scaled so that its link-1 error equals the row's size (a link-1 error)."""
    s = torch.tensor(sizes, **kw)
    ref = cfg.link_error[0]
    scale = s / ref if ref else torch.zeros_like(s)
    link = torch.tensor(cfg.link_error, **kw)[None] * scale[:, None]
    offset = torch.tensor(cfg.offset_error, **kw)[None] * scale[:, None]
    return link, offset


def desired_path(name: str, t: torch.Tensor, params: ScaraParams = ScaraParams()) -> torch.Tensor:
    """Desired end-effector positions (T, 3) in m at times t (T,) s."""
    if name == PathName.paper:
        return fk(paper_trajectory(t)[0], params)
    centre = fk(torch.tensor([[1.0, 1.15, 1.0]], dtype=t.dtype), params)[0]
    w = 2 * math.pi / 5.0                                                  # one loop per 5 s
    if name == PathName.circle:
        off = torch.stack([0.15 * torch.cos(w * t), 0.15 * torch.sin(w * t), 0.1 * torch.sin(w * t)], -1)
    elif name == PathName.figure8:
        off = torch.stack([0.2 * torch.sin(w * t), 0.1 * torch.sin(2 * w * t), 0.1 * torch.cos(w * t)], -1)
    else:
        raise ValueError(f"unknown path {name!r}; choose one of {[str(p) for p in PathName]}")
    return centre + off


def run_online(net: RBFNetwork, cfg: OnlineConfig, gains: GainsConfig, sizes: list[float],
               device: str = "cpu") -> dict:
    """Run adapted and frozen networks for every perturbation size in `sizes` (link-1 errors; see
    `perturbation_sizes`) and the nominal analytic IK.

    Returns, on the control grid: t (T,), err_adapt / err_frozen / err_analytic (T, S) task-space
    errors in mm, q_adapt (T, S, 3), dw (U, S) weight-change norms at the update times t_update
    (U,), final weights (S, P, 3), the rows' link errors (S, 2) and offsets (S, 3), and the number
    of rejected (non-finite) pairs.
    """
    kw = {"dtype": torch.float64, "device": device}
    sc = Scenario(cfg.duration, cfg.dt, "rk4", 0.0, cfg.duration, 0.0)
    sc.validate()
    n = sc.steps
    t = sc.times(**kw)
    x_d = desired_path(cfg.path, t).to(**kw)
    net = net.to(**kw)
    link, offset = perturbation_sizes(cfg, sizes, **kw)
    n_s = len(sizes)
    # Environments: [adapted (S), frozen (S)].
    real = RealRobot(torch.cat([link, link]), torch.cat([offset, offset]))
    b = 2 * n_s
    a_path = net.design(x_d)                                          # (T, P)
    da = torch.gradient(a_path, spacing=cfg.dt, dim=0)[0]
    dda = torch.gradient(da, spacing=cfg.dt, dim=0)[0]
    w0 = net.output_weights().to(**kw)
    learner = make_learner(cfg.learner, w0.expand(b, *w0.shape), cfg.alpha0, cfg.decay, cfg.forgetting)
    frozen = torch.cat([torch.zeros(n_s, dtype=torch.bool, device=device), torch.ones(n_s, dtype=torch.bool, device=device)])
    plant = ScaraPlant()
    ctrl = make_controller("smc_obs", gains, cfg.dt)
    q = torch.einsum("p,bpj->bj", a_path[0], learner.w)
    qd = torch.einsum("p,bpj->bj", da[0], learner.w)
    state = ctrl.init_state(q, qd)
    dist = stage_disturbances(plant, n, cfg.dt, **kw)
    co = plant.coefficients(torch.zeros(cfg.update_every, b, **kw))     # no payload
    alpha = torch.zeros(cfg.update_every, **kw)
    run = make_chunk(plant, ctrl, cfg.dt, "rk4", cfg.update_every)
    qs = torch.empty(n + 1, b, 3, **kw)
    dw = []
    k = 0
    with torch.inference_mode():          # no autograd bookkeeping: a fifth of a small batch's step
        while k < n:
            m = min(cfg.update_every, n - k)
            sl = slice(k, k + m)
            refs = [torch.einsum("np,bpj->nbj", r[sl], learner.w) for r in (a_path, da, dda)]
            args = (q, qd, state, *refs, None, alpha[:m], dist[sl], tuple(c[:m] for c in co))
            if cfg.aot and k == 0 and m == cfg.update_every:        # compiled ahead of time, cached on disk
                run = aot_chunk(run, chunk_key(plant, ctrl, cfg.dt, "rk4", m, args), args, log.info)
            fn = run if m == cfg.update_every else make_chunk(plant, ctrl, cfg.dt, "rk4", m)
            q, qd, state, rq, _, _ = fn(*args)
            qs[sl] = rq
            k += m
            if not bool(torch.isfinite(q).all()):
                raise RuntimeError(f"online run diverged by step {k} (t = {k * cfg.dt:.3f} s): q = {q.tolist()}")
            # Pairs (p, q) of this segment; the frozen environments learn nothing.
            p = real.fk(rq)                                                     # (m, B, 3)
            a = net.design(p).transpose(0, 1)                             # (B, m, P)
            y = rq.transpose(0, 1)
            keep = learner.w.clone()
            learner.update(a, y, k * cfg.dt)
            learner.w = torch.where(frozen[:, None, None], keep, learner.w)
            dw.append((learner.w - w0).flatten(1).norm(dim=-1)[:n_s])
    qs[n] = q
    err = (real.fk(qs) - x_d[:, None, :]).norm(dim=-1) * 1000.0            # (T, B) mm
    # Nominal analytic IK on the real robot: the same joints for every size (kinematic perturbation).
    q_an = ik(x_d, ScaraParams())
    real_s = RealRobot(link, offset)
    err_an = (real_s.fk(q_an[:, None, :].expand(-1, n_s, 3)) - x_d[:, None, :]).norm(dim=-1) * 1000.0
    return {"t": t, "err_adapt": err[:, :n_s], "err_frozen": err[:, n_s:], "err_analytic": err_an,
            "q_adapt": qs[:, :n_s], "dw": torch.stack(dw), "t_update": torch.arange(1, len(dw) + 1, **kw)
            * cfg.update_every * cfg.dt, "weights": learner.w[:n_s], "link_error": link, "offset_error": offset,
            "rejected": learner.rejected}
