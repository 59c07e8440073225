"""The IK network's outputs: training's checkpoint, exports, metrics.json and TensorBoard curves,
and evaluate.py's accuracy on a fresh test set with its workspace error map."""

from __future__ import annotations

import logging
import math
from pathlib import Path

from ..charts import ChartedIK, charts_from_checkpoint
from ..checkpoint import CHARTS_KIND, model_from_checkpoint, save_checkpoint
from ..config import SELECTORS, EvalConfig, Target, TrainConfig, plain
from ..data import Dataset, Split, evaluation_split, full_range_split
from ..export import deployed, export_all
from ..metrics import error_summary, ik_metrics_both
from ..pipeline import TrainResult
from ..robots.robot import Robot, robot_from_record
from ..solver import CHARTED_ERROR_DAMPING, CHARTED_ITERATIONS, DEFAULT_ITERATIONS, IKSolver
from .plots import pose_error_figure, robot_label, workspace_error_map
from .rundir import write_figure, write_json, write_summary

__all__ = [
    "training_metrics",
    "write_training",
    "evaluate_ik",
    "ik_table",
    "charted_metrics",
    "charted_line",
]

ALL_POSES = 500  # whole-range poses `charted_metrics` asks IKSolver.solve_all for every solution of

log = logging.getLogger(__name__)


def _polished(model, robot: Robot, x, iterations: int):
    """IKSolver.solve's (joints, converged) for the network inputs x (B, 3, 7 or 8): a redundant
    joint's value (the 8th column) is handed over as `redundancy`."""
    targets, value = robot.split_inputs(x)
    return IKSolver(model, robot).solve(targets, iterations, redundancy=value)


def polished_metrics(model, robot: Robot, x, iterations: int = DEFAULT_ITERATIONS, prefix: str = "test_") -> dict:
    """Accuracy after the network's answer is polished by `iterations` damped-least-squares steps:
    `polished_success_rate` (share within 0.1 mm and 0.1 deg) and the error summary."""
    q, ok = _polished(model, robot, x, iterations)
    pos, rot = robot.errors(q, x)
    out = {
        "polished_success_rate": float(ok.double().mean()),
        "polish_iterations": iterations,
        **{f"polished_{k}": v for k, v in error_summary(pos, rot).items()},
    }
    return {f"{prefix}{k}": v for k, v in out.items()}


def full_range_metrics(model, robot: Robot, split: Split, iterations: int = DEFAULT_ITERATIONS) -> dict:
    """The IK over the whole joint range (`rbfn.data.full_range_split`: every reachable pose, on
    every branch), beside the trained box's figures: `test_full_range_polished_success_rate` (the
    network's answer polished by `iterations` steps, within 0.1 mm and 0.1 deg),
    `test_full_range_in_workspace` (the share the deployed network's workspace flag marks inside,
    base turns included) and `test_full_range_success_in_workspace` (the success rate among those:
    what the flag promises; null where it marks none)."""
    converged = _polished(model, robot, split.x, iterations)[1]
    _, inside = deployed(model, robot)(split.x)  # the exporters' float32 copy, as deployed
    flagged = int(inside.sum())
    return {
        "test_full_range_polished_success_rate": float(converged.double().mean()),
        "test_full_range_in_workspace": flagged / split.x.shape[0],
        "test_full_range_success_in_workspace": float(converged[inside].double().mean()) if flagged else None,
    }


def _ridge(ridge) -> float | None:
    """The fit's relative ridge, None where refinement's trained weights were kept (NaN)."""
    r = float(ridge)
    return None if math.isnan(r) else r


def _weights_from(cfg: TrainConfig, ridge) -> str:
    """How the output weights were found: `lms`, `ridge` (least squares) or `trained` (mini-batch refinement)."""
    if cfg.rbfn.solver == "lms":
        return "lms"
    return "trained" if math.isnan(float(ridge)) else "ridge"


def training_metrics(cfg: TrainConfig, result: TrainResult, robot: Robot, data: Dataset) -> dict:
    """metrics.json of a training run: test accuracy in float64 and float32, raw and polished, E
    against M, times; `selector` the configured preset (`centers.name`), `centers_chosen_by` the
    method that actually chose the final network's centres (`kmeans` where the `aco` colony skipped
    itself or searched widths only) and `selection_note` why it differs (null where it does not)."""
    acc, _, _ = ik_metrics_both(result.model, robot, data.test.x, data.test.q)
    acc.update(polished_metrics(result.model, robot, data.test.x))
    acc.update(full_range_metrics(result.model, robot, full_range_split(robot, data.test.x.shape[0], cfg.seed)))
    return {
        "num_centers": result.model.num_centers,
        "selector": cfg.centers.name,
        "centers_chosen_by": result.chosen_by or str(cfg.centers.method),
        "selection_note": result.selection_note or None,
        "target": str(robot.target),
        **acc,
        "val_E": 0.5 * float(result.fit.val_mse),
        "ridge": _ridge(result.fit.ridge),
        "output_weights": _weights_from(cfg, result.fit.ridge),
        "growth": [{"num_centers": m, "val_E": e} for m, e in result.curve],
        "select_seconds": result.select_seconds,
        "train_seconds": result.train_seconds,
    }


def write_training(out_dir: Path, cfg: TrainConfig, robot: Robot, result: TrainResult, metrics: dict, writer) -> None:
    """checkpoint.pt, ik.onnx / ik.pt2 (unless `export=false`), metrics.json and TensorBoard events."""
    save_checkpoint(out_dir / "checkpoint.pt", result.model, robot.record(), plain(cfg), metrics)
    if cfg.export:
        export_all(result.model, out_dir, robot=robot)  # deploy without this package
    write_json(out_dir / "metrics.json", metrics)
    for m, (best, mean) in result.colonies.items():
        for it, (b, a) in enumerate(zip(best, mean)):
            writer.add_scalar(f"aco/M{m}/best_objective", b, it)
            writer.add_scalar(f"aco/M{m}/mean_objective", a, it)
    for m, e in result.curve:
        writer.add_scalar("growth/val_E", e, m)
    for i, e in enumerate(result.refine_history):
        writer.add_scalar("refine/val_mse", e, i)
    scalars = {k: v for k, v in metrics.items() if isinstance(v, (int, float)) and k != "num_centers"}
    # One HParams session per job, in the job's own run (run_name="."). Every job writes the same
    # experiment summary (same hparams, metrics and selector domain), so whichever one TensorBoard
    # reads describes the whole sweep.
    writer.add_hparams(
        {"centers": cfg.centers.name, "num_centers": result.model.num_centers, "seed": cfg.seed},
        {f"hparam/{k}": v for k, v in scalars.items()},
        hparam_domain_discrete={"centers": list(SELECTORS)},
        run_name=".",
    )


def charted_metrics(model: ChartedIK, robot: Robot, box: Split, full: Split) -> dict:
    """A charted network's figures (robot.workspace=full) on the trained box's test poses `box`
    (`test_` keys) and on poses over the whole joint range `full` (`test_full_range_` keys): the
    best-ranked chart's raw position and rotation error medians (`pos_err_mm_median`,
    `rot_err_deg_median`), the polished success within 0.1 mm / 0.1 deg (`polished_success_rate`,
    `IKSolver.solve`: the charts in turn, `polish_iterations` steps an answer), the share of whole-range
    poses the exported flag marks inside (`test_full_range_in_workspace`: the graph's own polish,
    `rbfn.graph_polish`, converged) and the solver's success among them
    (`test_full_range_success_in_workspace`), and the distinct solutions `IKSolver.solve_all` finds
    a pose (`test_full_range_solutions_mean`, on the first `ALL_POSES` whole-range poses)."""
    solver = IKSolver(model, robot, error_damping=CHARTED_ERROR_DAMPING)
    out: dict = {"workspace": "full", "charts": model.num_charts, "polish_iterations": CHARTED_ITERATIONS}
    for prefix, split in (("test_", box), ("test_full_range_", full)):
        targets, value = robot.split_inputs(split.x)
        raw, _ = solver.network(split.x)
        pos, rot = robot.errors(raw, targets)
        out[prefix + "pos_err_mm_median"] = float(pos.median())
        if rot is not None:
            out[prefix + "rot_err_deg_median"] = float(rot.median())
        _, ok = solver.solve(targets, redundancy=value)
        out[prefix + "polished_success_rate"] = float(ok.double().mean())
        if prefix == "test_full_range_":
            inside = deployed(model, robot)(split.x)[1]  # the exporters' float32 flag (converged), as deployed
            out[prefix + "in_workspace"] = float(inside.double().mean())
            out[prefix + "success_in_workspace"] = float(ok[inside].double().mean()) if bool(inside.any()) else None
            k = min(ALL_POSES, split.x.shape[0])
            _, found = solver.solve_all(targets[:k], redundancy=None if value is None else value[:k])
            out[prefix + "solutions_mean"] = float(found.sum(1).double().mean())
    return out


def charted_line(m: dict) -> str:
    """One log line of `charted_metrics`' figures."""
    return (
        f"{m['charts']} charts: polished ({m['polish_iterations']} steps) "
        f"{100 * m['test_polished_success_rate']:.2f} % of the box's poses, "
        f"{100 * m['test_full_range_polished_success_rate']:.2f} % over the whole joint range "
        f"(raw median {m['test_full_range_pos_err_mm_median']:.3g} mm), "
        f"{m['test_full_range_solutions_mean']:.2f} distinct solutions a pose"
    )


def evaluate_ik(ckpt: dict, path: Path, cfg: EvalConfig, out_dir: Path, writer) -> dict:
    """Accuracy of checkpoint dict `ckpt` (read from `path`) on a fresh evaluation set, float64
    and float32; writes workspace_error_map.png and a TensorBoard text summary. A charted network
    (robot.workspace=full): `charted_metrics` on fresh box and whole-range poses."""
    robot = robot_from_record(ckpt["robot"], cfg.device)
    seed = int(ckpt["config"]["seed"]) if cfg.seed is None else cfg.seed
    if ckpt["kind"] == CHARTS_KIND:
        charted = charts_from_checkpoint(ckpt).to(cfg.device)
        full = full_range_split(robot, cfg.n_test, seed, evaluation=True)
        res: dict = {"checkpoint": str(path), "test_seed": seed}
        res.update(charted_metrics(charted, robot, evaluation_split(robot, cfg.n_test, seed), full))
        write_summary(writer, "ik/summary", res)
        log.info("IK on fresh poses (%d, evaluation stream of seed %d): %s", cfg.n_test, seed, charted_line(res))
        return res
    model = model_from_checkpoint(ckpt).to(cfg.device)
    test = evaluation_split(robot, cfg.n_test, seed)
    acc, err_mm, inside = ik_metrics_both(model, robot, test.x, test.q)
    acc.update(polished_metrics(model, robot, test.x))
    acc.update(full_range_metrics(model, robot, full_range_split(robot, cfg.n_test, seed, evaluation=True)))
    out: dict = {"checkpoint": str(path), "num_centers": model.num_centers, "test_seed": seed, **acc}
    fig = _error_figure(
        robot, test.q.cpu().numpy(), test.x.cpu().numpy(), err_mm.cpu().numpy(), inside.cpu().numpy(), model.num_centers
    )
    write_figure(fig, out_dir / "workspace_error_map.png", 120, writer, "figures/workspace_error_map")
    write_summary(writer, "ik/summary", out)
    log.info(
        "%s", ik_table(f"IK accuracy on a fresh test set ({cfg.n_test} samples, evaluation stream of seed {seed})", out)
    )
    return out


def _error_figure(robot: Robot, q, x, err_mm, inside, num_centers: int):
    """workspace_error_map.png's figure: the x-y map of position targets x (N, 3), or for pose
    targets the error against the joints q (N, n) in the box; err_mm (N,), inside (N,)."""
    label = robot_label(robot.name, robot.urdf_text)
    if robot.target == Target.pose:
        low, high = robot.low.cpu().numpy(), robot.high.cpu().numpy()
        return pose_error_figure(q, low, high, err_mm, inside, robot=label, num_centers=num_centers)
    return workspace_error_map(x, err_mm, inside, robot=label, num_centers=num_centers)


def ik_table(title: str, m: dict) -> str:
    rows = [
        ("joint RMSE", "test_joint_rmse", 1.0, ""),
        ("position error median", "test_pos_err_mm_median", 1, "mm"),
        ("position error p95", "test_pos_err_mm_p95", 1, "mm"),
        ("position error max", "test_pos_err_mm_max", 1, "mm"),
        ("rotation error median", "test_rot_err_deg_median", 1, "deg"),
        ("rotation error p95", "test_rot_err_deg_p95", 1, "deg"),
        ("flagged in workspace", "test_in_workspace", 100, "%"),
    ]
    lines = [f"\n{title}", f"{'':24s} {'float64':>12s} {'float32':>12s}"]
    for name, key, mul, unit in rows:
        if key in m:
            lines.append(f"{name:24s} {m[key] * mul:12.4g} {m[key + '_float32'] * mul:12.4g} {unit}")
    lines.append(
        f"polished ({m['test_polish_iterations']} steps): "
        f"{100 * m['test_polished_success_rate']:.2f} % within "
        f"0.1 mm / 0.1 deg, median position error {m['test_polished_pos_err_mm_median']:.3g} mm"
    )
    if "test_full_range_polished_success_rate" in m:
        inside = m["test_full_range_success_in_workspace"]
        lines.append(
            f"over the whole joint range: {100 * m['test_full_range_polished_success_rate']:.2f} % polished, "
            f"{100 * m['test_full_range_in_workspace']:.1f} % flagged in workspace"
            + ("" if inside is None else f", of which {100 * inside:.2f} % polished")
        )
    return "\n".join(lines)
