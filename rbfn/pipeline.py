"""Training the IK network, the paper's procedure as one library function.

data -> centres and widths (rbfn.select) -> output weights (ridge or LMS) -> growth of M until the
validation error meets the goal -> optional gradient refinement -> an RBFNetwork. Pure: tensors
in, a result out. Resuming is a separate, optional concern: given a `rbfn.resume.StateFile`, the
run records its progress there and continues from it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple, cast

import torch

from .config import RefineLoss, Solver, Target, TrainConfig
from .data import Dataset, input_scaling
from .fit import (
    ROUND_TOL,
    RidgeFit,
    RoundingRule,
    deployed_design,
    design_matrix,
    ridge_fit,
    rounding_scale,
    rounding_tolerance,
)
from .growth import grow, growth_schedule
from .layer import RBFNetwork, assemble
from .lms import lms_fit
from .objectives import FitObjective
from .progress import Progress
from .refine import Refined, refine, refine_mode
from .resume import Resumable, StateFile, TrainState
from .robots.robot import check_ik_is_function
from .select import Selection, select
from .targets import TargetFeatures
from .widths import check_max_width

if TYPE_CHECKING:
    from .robots.robot import Robot

__all__ = ["TrainResult", "fit_weights", "task_jacobians", "train_ik"]

log = logging.getLogger(__name__)


@dataclass
class TrainResult:
    """The trained network, its final fit, the growth curve (M, E), each colony's best/mean
    objective per iteration (by M), the refinement's validation curve and the time spent;
    `chosen_by`, the method that chose the final network's centres (`rbfn.select.Selection`), and
    `selection_note`, why it is not the configured one ("" where it is)."""

    model: RBFNetwork
    fit: RidgeFit
    curve: list[tuple[int, float]]
    colonies: dict[int, tuple[list[float], list[float]]] = field(default_factory=dict)
    refine_history: list[float] = field(default_factory=list)
    select_seconds: float = 0.0
    train_seconds: float = 0.0
    chosen_by: str = ""
    selection_note: str = ""


def fit_weights(
    cfg: TrainConfig,
    data: Dataset,
    feats: tuple[torch.Tensor, torch.Tensor],
    offset: torch.Tensor,
    scale: torch.Tensor,
    centers: torch.Tensor,
    widths: torch.Tensor,
    *,
    gen: torch.Generator,
    refined: Refined | None = None,
) -> RidgeFit:
    """Output weights (P, n) by ridge least squares (the ridge chosen on validation as the deployed
    float32 module evaluates it) or, with `rbfn.solver=lms`, the paper's normalised LMS. `feats`:
    the training and validation inputs' features (N, d). After mini-batch refinement (`refined`
    with trained weights) those weights are kept instead where their validation loss (the one
    refinement minimised) is lower and they are as stable in float32 as the ridge rule demands;
    the fit's ridge is then NaN. Every fit follows the float32 rule the full refinement optimises
    under (`float32_rule`)."""
    q_tr, q_val = data.train.q, data.val.q
    z_val = (feats[1] - offset) / scale
    a_tr = design_matrix((feats[0] - offset) / scale, centers, widths, cfg.rbfn.tail)
    a_val = design_matrix(z_val, centers, widths, cfg.rbfn.tail)
    a_val32 = deployed_design(feats[1], offset, scale, centers, widths, cfg.rbfn.tail, torch.float32)
    rule = float32_rule(cfg)
    fit = ridge_fit(
        a_tr,
        q_tr,
        a_val,
        q_val,
        a_val_eval=a_val32,
        round_tol=rule.round_tol,
        round_rel=rule.round_rel,
    )
    if cfg.rbfn.solver == Solver.lms:
        fit.weights = lms_fit(a_tr, q_tr, alpha0=cfg.rbfn.lms_alpha0, epochs=cfg.rbfn.lms_epochs, generator=gen)
        fit.val_mse = (a_val @ fit.weights - q_val).square().sum(-1).mean()
    elif refined is not None and refined.weights is not None:
        trained = refined.weights
        assert refined.val_loss is not None  # mini-batch refinement gives it with the weights
        pred = (a_val32 @ trained.to(a_val32.dtype)).to(q_val.dtype)
        mse = (pred - q_val).square().sum(-1).mean()
        rounding = rounding_scale(a_val, trained, torch.float32).amax()
        tol = rounding_tolerance(mse[None], q_val.shape[1], rule.round_tol, rule.round_rel)[0]
        ridge_pred = (a_val32 @ fit.weights.to(a_val32.dtype)).to(q_val.dtype)
        if rounding <= tol and refined.val_loss(pred) < refined.val_loss(ridge_pred):
            fit = RidgeFit(trained, torch.tensor(float("nan"), dtype=q_val.dtype), mse, rounding)
    return fit


def float32_rule(cfg: TrainConfig) -> RoundingRule:
    """The float32 rule of every fit, the full refinement's included: a rounding scale of at most
    ROUND_TOL or `rbfn.round_rel` times the fit's own error (`rbfn.fit.rounding_tolerance`)."""
    return RoundingRule(torch.float32, ROUND_TOL, cfg.rbfn.round_rel)


def task_jacobians(cfg: TrainConfig, robot: Robot, data: Dataset) -> tuple[torch.Tensor, torch.Tensor]:
    """Task Jacobians (N, r, n) at the training and validation joints, the rotation rows times
    `robot.rotation_scale` (m), as the task loss weighs them."""
    jacs = robot.jacobian(data.train.q), robot.jacobian(data.val.q)
    for j in jacs:
        j[:, 3:] *= cfg.robot.rotation_scale
    return jacs


def _uses_task_loss(cfg: TrainConfig, data: Dataset, features: int, robot: Robot | None) -> bool:
    """Whether mini-batch refinement at M = num_centers (`features` inputs d) takes the task loss
    (its Jacobian sees every joint: check_ik_is_function); refuses it without the robot."""
    r = cfg.centers.refine
    p = cfg.rbfn.num_centers + (features + 1 if cfg.rbfn.tail else 0)
    task = r.enabled and r.minibatch.loss == RefineLoss.task
    if not (task and refine_mode(r, data.train.q.shape[0], p) == "minibatch"):
        return False
    if robot is None:
        raise ValueError(
            "centers.refine.minibatch.loss=task needs the robot (train_ik(..., robot=ROBOT)) for its Jacobian"
        )
    return True


def train_ik(
    cfg: TrainConfig,
    data: Dataset,
    states: StateFile | None = None,
    state: TrainState | None = None,
    robot: Robot | None = None,
    progress: Progress | None = None,
) -> TrainResult:
    """Train the IK network of `cfg` on `data` (targets (N, 3 or 7) -> joints (N, n)).

    With `states` and the `state` it loaded, progress is saved as it goes (every growth step, and
    the running colony's snapshots; `rbfn.resume.Resumable`) and an interrupted run continues where
    it stopped, ending with exactly the result of an uninterrupted one. `robot` (the data's) gives
    the task Jacobians that mini-batch refinement's task loss needs
    (`centers.refine.minibatch.loss=task`). `progress`, where given, follows the colonies'
    iterations and the refinement's steps. An arm with more free joints than its targets' degrees
    of freedom is refused first (check_ik_is_function).
    """
    n_q = data.train.q.shape[1]
    joints = robot.joint_names if robot is not None else [f"joint {i + 1}" for i in range(n_q)]
    check_ik_is_function(str(cfg.robot.target), joints, cfg.robot.locked, cfg.robot.redundancy)
    run = Resumable(states, state, torch.Generator().manual_seed(cfg.seed))
    x = _Inputs.of(cfg, data, robot)
    feats, offset, scale = x.feats, x.offset, x.scale
    objective = FitObjective(
        x.z_train,
        data.train.q,
        x.z_val,
        data.val.q,
        tail=cfg.rbfn.tail,
        eval_dtype=torch.float32,
        round_rel=cfg.rbfn.round_rel,
    )

    def fit_at(m: int) -> tuple[tuple[torch.Tensor, torch.Tensor, RidgeFit], float]:
        def on_state(snapshot: dict) -> None:
            run.colony(snapshot)
            if progress is not None:
                progress.at(f"M = {m}: colony", snapshot["iteration"], snapshot["iterations"], "iterations")

        sel = select(
            cfg.centers,
            objective,
            m,
            seed=cfg.seed,
            max_width=cfg.rbfn.max_width,
            progress=cfg.progress,
            generator=run.gen,
            resume=run.begin(m),
            on_state=on_state,
        )
        fit = fit_weights(cfg, data, feats, offset, scale, sel.centers, sel.widths, gen=run.gen)
        err = 0.5 * float(fit.val_mse)
        run.finish(_step_record(m, err, sel), _fit_record(sel.centers, sel.widths, fit))
        log.info("M = %4d: validation E = %.3e (selection %.1f s)", m, err, sel.seconds)
        return (sel.centers, sel.widths, fit), err

    schedule = run.remaining(
        growth_schedule(cfg.rbfn.growth.start, cfg.rbfn.growth.factor, cfg.rbfn.num_centers), cfg.rbfn.growth.goal
    )
    curve = run.curve()
    if schedule:
        (centers, widths, fit), more = grow(fit_at, schedule, cfg.rbfn.growth.goal)
        curve += more
    else:  # growth had finished before the interruption
        centers, widths, fit = _restored_fit(run.state.last_fit, cfg.device)
    history: list[float] = []
    if cfg.centers.refine.enabled:  # centres, widths and input scales (rbfn.refine)
        ref = _refine(cfg, data, x, centers, widths, fit, progress)
        scale = scale * ref.input_scale
        centers, widths, history = ref.centers, ref.widths, ref.history
        fit = fit_weights(cfg, data, feats, offset, scale, centers, widths, gen=run.gen, refined=ref)
    model = assemble(centers, widths, fit.weights, offset, scale, cfg.rbfn.tail, inputs=x.features)
    model.set_domain(data.train.x, data.train.q)
    done = run.state.done
    return TrainResult(
        model,
        fit,
        curve,
        colonies={d["num_centers"]: (d.get("aco_best", []), d.get("aco_mean", [])) for d in done},
        refine_history=history,
        select_seconds=sum(d["select_seconds"] for d in done),
        train_seconds=run.elapsed(),
        chosen_by=done[-1].get("chosen_by", str(cfg.centers.method)),  # (a last.pt from before it was kept)
        selection_note=done[-1].get("selection_note", ""),
    )


def _step_record(m: int, err: float, sel: Selection) -> dict:
    """A finished growth step as `rbfn.resume.TrainState.done` keeps it."""
    return {
        "num_centers": m,
        "val_E": err,
        "select_seconds": sel.seconds,
        "aco_best": list(sel.aco_best),
        "aco_mean": list(sel.aco_mean),
        "chosen_by": sel.chosen_by,
        "selection_note": sel.note,
    }


def _fit_record(centers: torch.Tensor, widths: torch.Tensor, fit: RidgeFit) -> dict:
    """The last growth step's network as `rbfn.resume.TrainState.last_fit` keeps it (on the CPU)."""
    return {
        "centers": centers.cpu(),
        "widths": widths.cpu(),
        "weights": fit.weights.cpu(),
        "ridge": float(fit.ridge),
        "val_mse": float(fit.val_mse),
    }


def _restored_fit(last_fit: dict | None, device: str) -> tuple[torch.Tensor, torch.Tensor, RidgeFit]:
    """`_fit_record`'s centres, widths and fit back on `device` (the floats saved, exactly)."""
    assert last_fit is not None  # saved with the finished growth
    return (
        last_fit["centers"].to(device),
        last_fit["widths"].to(device),
        RidgeFit(
            last_fit["weights"].to(device),
            torch.tensor(last_fit["ridge"], dtype=torch.float64),
            torch.tensor(last_fit["val_mse"], dtype=torch.float64),
        ),
    )


class _Inputs(NamedTuple):
    """The network's inputs: the target features, the training and validation features (N, d),
    their offset and scale (d,), the scaled features z (N, d), and the task Jacobians where the
    mini-batch refinement's task loss needs them (else None)."""

    features: TargetFeatures
    feats: tuple[torch.Tensor, torch.Tensor]
    offset: torch.Tensor
    scale: torch.Tensor
    z_train: torch.Tensor
    z_val: torch.Tensor
    jacobians: tuple[torch.Tensor, torch.Tensor] | None

    @classmethod
    def of(cls, cfg: TrainConfig, data: Dataset, robot: Robot | None) -> _Inputs:
        features = TargetFeatures(
            cfg.robot.target == Target.pose,
            cfg.robot.rotation_scale,
            device=data.train.x.device,
            redundancy=bool(cfg.robot.redundancy),
        )
        feats = (features(data.train.x), features(data.val.x))
        offset, scale = input_scaling(feats[0], cfg.rbfn.input_scaling)
        z_tr, z_val = (feats[0] - offset) / scale, (feats[1] - offset) / scale
        check_max_width(z_tr, cfg.rbfn.max_width, cfg.rbfn.num_centers)
        # _uses_task_loss refuses robot=None where the task loss is asked for
        task = _uses_task_loss(cfg, data, z_tr.shape[1], robot)
        jacobians = task_jacobians(cfg, cast("Robot", robot), data) if task else None
        return cls(features, feats, offset, scale, z_tr, z_val, jacobians)


def _refine(
    cfg: TrainConfig,
    data: Dataset,
    x: _Inputs,
    centers: torch.Tensor,
    widths: torch.Tensor,
    fit: RidgeFit,
    progress: Progress | None,
) -> Refined:
    """The grown network's centres, widths and input scales refined by gradient (`rbfn.refine`)."""
    r = cfg.centers.refine
    return refine(
        x.z_train,
        data.train.q,
        x.z_val,
        data.val.q,
        centers,
        widths,
        fit.weights,
        ridge=max(float(fit.ridge), r.min_ridge),
        cfg=r,
        tail=cfg.rbfn.tail,
        max_width=cfg.rbfn.max_width,
        seed=cfg.seed,
        jacobians=x.jacobians,
        rule=float32_rule(cfg),
        progress=progress,
    )
