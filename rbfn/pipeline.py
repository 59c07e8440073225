"""Training the IK network, the paper's procedure as one library function.

data -> centres and widths (rbfn.select) -> output weights (ridge or LMS) -> growth of M until the
validation error meets the goal -> optional gradient refinement -> an RBFNetwork. Pure: tensors
in, a result out. Resuming is a separate, optional concern: given a `rbfn.resume.StateFile`, the
run records its progress there and continues from it.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import torch

from .config import Solver, Target, TrainConfig
from .data import Dataset, input_scaling
from .fit import RidgeFit, deployed_design, design_matrix, ridge_fit
from .growth import grow, growth_schedule
from .layer import RBFNetwork, assemble
from .lms import lms_fit
from .objectives import FitObjective
from .refine import refine
from .resume import StateFile, TrainState
from .select import select
from .targets import TargetFeatures

__all__ = ["TrainResult", "fit_weights", "train_ik"]

log = logging.getLogger(__name__)


@dataclass
class TrainResult:
    """The trained network, its final fit, the growth curve (M, E), each colony's best/mean
    objective per iteration (by M), the refinement's validation curve and the time spent."""

    model: RBFNetwork
    fit: RidgeFit
    curve: list[tuple[int, float]]
    colonies: dict[int, tuple[list[float], list[float]]] = field(default_factory=dict)
    refine_history: list[float] = field(default_factory=list)
    select_seconds: float = 0.0
    train_seconds: float = 0.0


def fit_weights(cfg: TrainConfig, data: Dataset, feats: tuple[torch.Tensor, torch.Tensor], offset: torch.Tensor,
                scale: torch.Tensor, centers: torch.Tensor, widths: torch.Tensor, gen: torch.Generator) -> RidgeFit:
    """Output weights (P, n) by ridge least squares (the ridge chosen on validation as the deployed
    float32 module evaluates it) or, with `rbfn.solver=lms`, the paper's normalised LMS. `feats`:
    the training and validation inputs' features (N, d)."""
    q_tr, q_val = data.train.q, data.val.q
    a_tr = design_matrix((feats[0] - offset) / scale, centers, widths, cfg.rbfn.tail)
    a_val = design_matrix((feats[1] - offset) / scale, centers, widths, cfg.rbfn.tail)
    a_val32 = deployed_design(feats[1], offset, scale, centers, widths, cfg.rbfn.tail, torch.float32)
    fit = ridge_fit(a_tr, q_tr, a_val, q_val, a_val_eval=a_val32, round_rel=cfg.rbfn.round_rel)
    if cfg.rbfn.solver == Solver.lms:
        fit.weights = lms_fit(a_tr, q_tr, alpha0=cfg.rbfn.lms_alpha0, epochs=cfg.rbfn.lms_epochs, generator=gen)
        fit.val_mse = (a_val @ fit.weights - q_val).square().sum(-1).mean()
    return fit


def train_ik(cfg: TrainConfig, data: Dataset, states: StateFile | None = None,
             state: TrainState | None = None) -> TrainResult:
    """Train the IK network of `cfg` on `data` (positions (N, 3) m -> joints (N, n)).

    With `states` and the `state` it loaded, progress is saved as it goes (every growth step, and
    the running colony's snapshots) and an interrupted run continues where it stopped, ending with
    exactly the result of an uninterrupted one.
    """
    t_start = time.perf_counter()
    state = state or TrainState(config={})
    elapsed_before = state.elapsed
    dev = cfg.device

    def save(force: bool = True) -> None:
        if states is not None:
            state.elapsed = elapsed_before + time.perf_counter() - t_start
            states.save(state, force=force)

    features = TargetFeatures(cfg.robot.target == Target.pose, cfg.robot.rotation_scale, device=data.train.x.device)
    feats = (features(data.train.x), features(data.val.x))
    offset, scale = input_scaling(feats[0], cfg.rbfn.input_scaling)
    z_tr, z_val = (feats[0] - offset) / scale, (feats[1] - offset) / scale
    objective = FitObjective(z_tr, data.train.q, z_val, data.val.q, tail=cfg.rbfn.tail, eval_dtype=torch.float32,
                             round_rel=cfg.rbfn.round_rel)
    gen = torch.Generator().manual_seed(cfg.seed)
    if state.gen_after is not None:
        gen.set_state(state.gen_after)

    def fit_at(m: int):
        resume = None
        if state.current is not None and state.current["num_centers"] == m:
            gen.set_state(state.current["gen_start"])
            resume = state.current["colony"]
        else:
            state.current = {"num_centers": m, "gen_start": gen.get_state(), "colony": None}

        def on_state(colony_state: dict) -> None:
            state.current["colony"] = colony_state
            save(force=False)

        sel = select(cfg.centers, objective, m, cfg.seed, cfg.rbfn.max_width, cfg.progress, gen, resume, on_state)
        fit = fit_weights(cfg, data, feats, offset, scale, sel.centers, sel.widths, gen)
        err = 0.5 * float(fit.val_mse)
        state.done.append({"num_centers": m, "val_E": err, "select_seconds": sel.seconds,
                           "aco_best": list(sel.aco_best), "aco_mean": list(sel.aco_mean)})
        state.last_fit = {"centers": sel.centers.cpu(), "widths": sel.widths.cpu(), "weights": fit.weights.cpu(),
                          "ridge": float(fit.ridge), "val_mse": float(fit.val_mse)}
        state.gen_after, state.current = gen.get_state(), None
        save()
        log.info("M = %4d: validation E = %.3e (selection %.1f s)", m, err, sel.seconds)
        return (sel.centers, sel.widths, fit), err

    schedule = growth_schedule(cfg.rbfn.growth.start, cfg.rbfn.growth.factor, cfg.rbfn.num_centers)
    curve = [(d["num_centers"], d["val_E"]) for d in state.done]
    if curve and (curve[-1][1] <= cfg.rbfn.growth.goal or curve[-1][0] == schedule[-1]):
        schedule = []                                   # growth had finished before the interruption
    else:
        schedule = [m for m in schedule if m not in {c[0] for c in curve}]
    if schedule:
        (centers, widths, fit), more = grow(fit_at, schedule, cfg.rbfn.growth.goal)
        curve += more
    else:
        lf = state.last_fit
        centers, widths = lf["centers"].to(dev), lf["widths"].to(dev)
        fit = RidgeFit(lf["weights"].to(dev), torch.tensor(lf["ridge"]), torch.tensor(lf["val_mse"]))

    history: list[float] = []
    if cfg.centers.refine.enabled:       # centres, widths and input scales (rbfn.refine)
        r = cfg.centers.refine
        ref = refine(z_tr, data.train.q, z_val, data.val.q, centers, widths, fit.weights,
                     max(float(fit.ridge), r.min_ridge), r, cfg.rbfn.tail, cfg.rbfn.max_width, cfg.seed)
        scale = scale * ref.input_scale
        centers, widths, history = ref.centers, ref.widths, ref.history
        fit = fit_weights(cfg, data, feats, offset, scale, centers, widths, gen)
    model = assemble(centers, widths, fit.weights, offset, scale, cfg.rbfn.tail, inputs=features)
    model.set_domain(data.train.x, data.train.q)
    return TrainResult(model, fit, curve,
                       colonies={d["num_centers"]: (d.get("aco_best", []), d.get("aco_mean", [])) for d in state.done},
                       refine_history=history,
                       select_seconds=sum(d["select_seconds"] for d in state.done),
                       train_seconds=elapsed_before + time.perf_counter() - t_start)
