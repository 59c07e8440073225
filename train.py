"""Train the IK network: data -> centres and widths -> weights -> growth -> refinement -> checkpoint.

    python train.py                       # ACO centres and widths, refined, M = 80
    python train.py centers=kmeans rbfn.num_centers=40 seed=1
    python train.py -m centers=aco,kmeans rbfn.num_centers=10,40,160

Writes checkpoint.pt, metrics.json and TensorBoard events into the Hydra run directory.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from torch.utils.tensorboard import SummaryWriter

from rbfn.checkpoint import atomic_write_bytes, save_checkpoint
from rbfn.config import SELECTORS, TrainConfig, register_configs, validate_train
from rbfn.export import export_all
from rbfn.data import check_finite, input_scaling, make_dataset
from rbfn.fit import RidgeFit, deployed_design, design_matrix, lms_weights, ridge_fit
from rbfn.growth import grow, growth_schedule
from rbfn.layer import assemble
from rbfn.metrics import ik_metrics
from rbfn.objectives import FitObjective
from rbfn.refine import refine
from rbfn.resume import StateFile
from rbfn.robots import joint_limits, load_serial_chain
from rbfn.robots import scara
from rbfn.select import select

register_configs()


def load_robot(cfg: TrainConfig, device: str):
    """The serial chain (float64) and the sampled joint box (low, high), checked against the URDF."""
    urdf = Path(cfg.robot.urdf) if cfg.robot.urdf else scara.URDF_PATH
    chain = load_serial_chain(urdf, cfg.robot.end_link, torch.float64, device)
    low = torch.tensor(cfg.robot.joint_low, dtype=torch.float64)
    high = torch.tensor(cfg.robot.joint_high, dtype=torch.float64)
    names = chain.get_joint_parameter_names()
    if len(names) != low.shape[0]:
        raise ValueError(f"robot.joint_low/high give {low.shape[0]} joints, the URDF chain to "
                         f"{cfg.robot.end_link!r} has {len(names)}: {names}")
    u_low, u_high = joint_limits(chain)
    outside = (low < u_low - 1e-12) | (high > u_high + 1e-12)
    if bool(outside.any()):
        j = int(outside.nonzero()[0])
        raise ValueError(f"joint range of {names[j]} [{low[j]:.4g}, {high[j]:.4g}] leaves the URDF limits "
                         f"[{u_low[j]:.4g}, {u_high[j]:.4g}]")
    return chain, urdf.read_text(), low.to(device), high.to(device)


def run(cfg: TrainConfig, out_dir: Path) -> dict:
    """Train one IK network with `cfg`; write outputs into `out_dir`; return the metrics."""
    validate_train(cfg)
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    torch.manual_seed(cfg.seed)
    dev = cfg.device
    t_start = time.perf_counter()
    writer = SummaryWriter(log_dir=str(out_dir))

    # 1. Data: seeded joint samples within the branch, FK positions from the URDF.
    chain, urdf_text, low, high = load_robot(cfg, dev)
    data = make_dataset(chain, low.cpu(), high.cpu(), (cfg.data.n_train, cfg.data.n_val, cfg.data.n_test), cfg.seed)
    for name, split in (("train", data.train), ("val", data.val), ("test", data.test)):
        check_finite(f"{name} positions", split.x)
        check_finite(f"{name} joints", split.q)
    offset, scale = input_scaling(data.train.x, cfg.rbfn.input_scaling)
    z_tr, z_val = (data.train.x - offset) / scale, (data.val.x - offset) / scale
    objective = FitObjective(z_tr, data.train.q, z_val, data.val.q, tail=cfg.rbfn.tail,
                             eval_dtype=torch.float32)
    gen = torch.Generator().manual_seed(cfg.seed)

    # A run directory holding last.pt from an interrupted run continues it (same config).
    states = StateFile(out_dir)
    state = states.load(asdict(cfg))
    if state.finished is not None:
        print(f"{out_dir} holds a finished run; nothing to do (delete last.pt to train again)")
        return state.finished
    if state.done or state.current:
        print(f"resuming from {states.path}: {len(state.done)} growth step(s) done")
    if state.gen_after is not None:
        gen.set_state(state.gen_after)

    # 2-4. Centres and widths, then output weights; grow M until E <= goal.
    select_seconds = sum(d["select_seconds"] for d in state.done)

    def fit_at(m: int):
        nonlocal select_seconds
        resume = None
        if state.current is not None and state.current["num_centers"] == m:
            gen.set_state(state.current["gen_start"])
            resume = state.current["colony"]
        else:
            state.current = {"num_centers": m, "gen_start": gen.get_state(), "colony": None}

        def on_state(colony_state: dict) -> None:
            state.current["colony"] = colony_state
            states.save(state, force=False)

        sel = select(cfg.centers, objective, m, cfg.seed, cfg.rbfn.max_width, cfg.progress, gen,
                     resume, on_state)
        select_seconds += sel.seconds
        for it, (b, mean) in enumerate(zip(sel.aco_best, sel.aco_mean)):
            writer.add_scalar(f"aco/M{m}/best_objective", b, it)
            writer.add_scalar(f"aco/M{m}/mean_objective", mean, it)
        fit = fit_weights(cfg, data, offset, scale, sel.centers, sel.widths, gen)
        err = 0.5 * float(fit.val_mse)
        state.done.append({"num_centers": m, "val_E": err, "select_seconds": sel.seconds})
        state.last_fit = {"centers": sel.centers.cpu(), "widths": sel.widths.cpu(),
                          "weights": fit.weights.cpu(), "ridge": float(fit.ridge), "val_mse": float(fit.val_mse)}
        state.gen_after, state.current = gen.get_state(), None
        states.save(state)
        return (sel.centers, sel.widths, fit), err

    def log_growth(m: int, err: float) -> None:
        writer.add_scalar("growth/val_E", err, m)
        print(f"M = {m:4d}: validation E = {err:.3e}")

    schedule = growth_schedule(cfg.rbfn.growth.start, cfg.rbfn.growth.factor, cfg.rbfn.num_centers)
    curve = [(d["num_centers"], d["val_E"]) for d in state.done]
    if curve and (curve[-1][1] <= cfg.rbfn.growth.goal or curve[-1][0] == schedule[-1]):
        schedule = []                                   # growth had finished before the interruption
    else:
        schedule = [m for m in schedule if m not in {c[0] for c in curve}]
    if schedule:
        (centers, widths, fit), more = grow(fit_at, schedule, cfg.rbfn.growth.goal, log_growth)
        curve += more
    else:
        lf = state.last_fit
        centers, widths = lf["centers"].to(dev), lf["widths"].to(dev)
        fit = RidgeFit(lf["weights"].to(dev), torch.tensor(lf["ridge"]), torch.tensor(lf["val_mse"]))

    # 5. Optional refinement of centres, widths and input scales (weights solved inside the loss).
    if cfg.centers.refine.enabled:
        r = cfg.centers.refine
        ref = refine(z_tr, data.train.q, z_val, data.val.q, centers, widths,
                     max(float(fit.ridge), r.min_ridge), r.steps,
                     r.lr, cfg.rbfn.tail, r.learn_input_scale, cfg.rbfn.max_width)
        scale = scale * ref.input_scale
        centers, widths = ref.centers, ref.widths
        fit = fit_weights(cfg, data, offset, scale, centers, widths, gen)
        for i, e in enumerate(ref.history):
            writer.add_scalar("refine/val_mse", e, i)
    model = assemble(centers, widths, fit.weights, offset, scale, cfg.rbfn.tail)
    model.set_domain(data.train.x, data.train.q)
    train_seconds = time.perf_counter() - t_start

    # 6. Test metrics in float64 and float32, checkpoint, metrics.json, TensorBoard hparams.
    m64 = ik_metrics(model, chain, data.test.x, data.test.q, torch.float64)
    m32 = ik_metrics(model, chain, data.test.x, data.test.q, torch.float32)
    model.double()
    metrics = {"num_centers": model.num_centers, "selector": cfg.centers.name,
               **{f"test_{k}": v for k, v in m64.items()},
               **{f"test_{k}_float32": v for k, v in m32.items() if k.startswith(("pos", "joint_rmse"))},
               "val_E": 0.5 * float(fit.val_mse), "ridge": float(fit.ridge),
               "growth": [{"num_centers": m, "val_E": e} for m, e in curve],
               "select_seconds": select_seconds, "train_seconds": train_seconds}
    robot = {"urdf": urdf_text, "end_link": cfg.robot.end_link,
             "joint_names": chain.get_joint_parameter_names(),
             "joint_low": list(cfg.robot.joint_low), "joint_high": list(cfg.robot.joint_high)}
    save_checkpoint(out_dir / "checkpoint.pt", model, robot, asdict(cfg), metrics)
    if cfg.export:
        export_all(model, out_dir)                      # ik.onnx, ik.pt2: deploy without this package
    state.finished = metrics
    states.save(state)
    text = json.dumps(metrics, indent=2).encode()
    atomic_write_bytes(out_dir / "metrics.json", lambda f: f.write(text))
    scalars = {k: v for k, v in metrics.items() if isinstance(v, (int, float)) and k != "num_centers"}
    # One HParams session per job, in the job's own run (run_name="."). Every job writes the same
    # experiment summary (same hparams, metrics and selector domain), so whichever one TensorBoard
    # reads describes the whole sweep.
    writer.add_hparams({"centers": cfg.centers.name, "num_centers": model.num_centers, "seed": cfg.seed},
                       {f"hparam/{k}": v for k, v in scalars.items()},
                       hparam_domain_discrete={"centers": list(SELECTORS)}, run_name=".")
    writer.close()
    print(f"M = {model.num_centers}, test position error median {m64['pos_err_mm_median']:.3f} mm, "
          f"p95 {m64['pos_err_mm_p95']:.3f} mm, max {m64['pos_err_mm_max']:.3f} mm "
          f"(float32 median {m32['pos_err_mm_median']:.3f} mm); selection {select_seconds:.1f} s, "
          f"total {train_seconds:.1f} s -> {out_dir}")
    return metrics


def fit_weights(cfg: TrainConfig, data, offset, scale, centers, widths, gen):
    """Output weights by ridge least squares or LMS.

    The ridge is the one whose fit is best on validation when evaluated exactly as the deployed
    float32 module computes it, so the network stays accurate in float32.
    """
    q_tr, q_val = data.train.q, data.val.q
    a_tr = design_matrix((data.train.x - offset) / scale, centers, widths, cfg.rbfn.tail)
    a_val = design_matrix((data.val.x - offset) / scale, centers, widths, cfg.rbfn.tail)
    a_val32 = deployed_design(data.val.x, offset, scale, centers, widths, cfg.rbfn.tail, torch.float32)
    fit = ridge_fit(a_tr, q_tr, a_val, q_val, a_val_eval=a_val32)
    if cfg.rbfn.solver == "lms":
        fit.weights = lms_weights(a_tr, q_tr, cfg.rbfn.lms_alpha0, cfg.rbfn.lms_epochs, gen)
        fit.val_mse = (a_val @ fit.weights - q_val).square().sum(-1).mean()
    return fit


@hydra.main(version_base="1.3", config_path="conf", config_name="train")
def main(dcfg: DictConfig) -> float:
    cfg: TrainConfig = OmegaConf.to_object(dcfg)
    metrics = run(cfg, Path(HydraConfig.get().runtime.output_dir))
    return metrics["val_E"]  # the validation objective, for sweepers


if __name__ == "__main__":
    main()
