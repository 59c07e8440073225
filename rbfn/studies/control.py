"""evaluate.py's `control` part: run the comparison, then its table, figures and TensorBoard summary and curves."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import torch
from torch.utils.tensorboard import SummaryWriter

from ..config import ControlConfig, GainsConfig, LoopConfig, NetworkConfig, RobotConfig, network_method, plain
from ..control.comparison import PICK_AND_PLACE, ControlComparison, PickedAndPlaced, compare_controllers
from ..control.controllers import pd_gains
from ..control.robot_setup import ControlRobot, control_robot
from ..progress import Progress
from .beside import Beside, can_fork
from .plots import pick_and_place_figure, robot_label, tracking_figure
from .rundir import write_figure, write_summary

__all__ = ["check_control", "evaluate_control", "control_table", "held_out"]

log = logging.getLogger(__name__)


def check_control(cfg: ControlConfig, robot: RobotConfig | None = None, urdf_text: str | None = None) -> ControlRobot:
    """Load and check the control part's robot (URDF, joints, payload link, joint scale): call it
    before any work; raises ValueError naming the bad key. `urdf_text`: the URDF's text (a
    checkpoint's), loaded instead of robot.urdf or the preset's file."""
    return control_robot(robot or RobotConfig(), cfg, urdf_text=urdf_text)


def evaluate_control(
    cfg: ControlConfig,
    gains: GainsConfig,
    *,
    device: str,
    writer,
    out_dir: Path,
    robot: RobotConfig | None = None,
    parallel: bool = True,
    loop: LoopConfig | None = None,
    urdf_text: str | None = None,
    progress: Progress | None = None,
) -> dict:
    """metrics.json's `control` (controller -> case -> metric -> per joint) and `control_info`;
    `parallel`: half the figures drawn in a forked process where the machine allows; `urdf_text`
    as check_control takes it."""
    robot = robot or RobotConfig()
    setup = check_control(cfg, robot, urdf_text)
    source = urdf_text if urdf_text is not None else Path(robot.urdf) if robot.urdf else robot.name
    label = robot_label(robot.name, source)
    res = compare_controllers(cfg, gains, device, setup=setup, loop=loop, progress=progress)
    net = res.network
    metrics = {name: run.metrics for name, run in res.runs.items()}
    limits, undefined = torque_limits(setup, loop, metrics)
    gain_record: dict[str, Any] = {
        k: (str(v) if not isinstance(v, (int, float)) else v) for k, v in vars(gains).items()
    }
    gain_record["joint_scale"] = res.joint_scale or [1.0] * setup.n  # the torque gains' factor per joint
    info: dict[str, Any] = {
        "loop": plain(loop) if loop is not None else {"name": "ideal"},
        "network": {"law": str(net.law), "objective": str(net.objective)} if net is not None else None,
        "gains": gain_record,
        "select_seconds": {n: r.select_seconds for n, r in res.runs.items() if r.select_seconds is not None},
        "sim_seconds": {n: r.sim_seconds for n, r in res.runs.items()},
        "torque_limits": limits,
    }
    bases = {n: r.basis for n, r in res.runs.items() if r.basis is not None}
    if bases:  # the two-phase law's phase 1: its payloads and each network's fit at them
        info["phase_one"] = {
            "payloads": res.phase_one_payloads,
            "seconds": res.phase_one_seconds,  # its calibration runs (each network's selection: select_seconds)
            "fit_error": {n: b.fit_error.tolist() for n, b in bases.items()},
            "joint_error": {n: b.joint_error.tolist() for n, b in bases.items()},
        }
        # the two-phase law's settings, as the closed loop chose them on the tuning's scenarios: the
        # joints each network feeds its predicted torque forward on (control.network.feedforward),
        # the payload estimate's step per control period and the feedback's most growth (each a
        # factor of its gain: control.network.estimate_rate_factors, feedback_growth_factors)
        chosen = {n: r.settings for n, r in res.runs.items() if r.settings is not None}
        info["feedforward"] = {
            "mode": str(net.feedforward) if net is not None else None,
            "joints": {n: st.feedforward.tolist() for n, st in chosen.items()},
            # per joint, the RMS with the network's torque over without it on the tuning's scenarios
            "ratio": {n: st.feedforward_ratio.tolist() for n, st in chosen.items() if st.feedforward_ratio is not None},
            "seconds": res.choice_seconds,  # the whole choice, every setting
        }
        info["estimate_rate"] = {
            "factors": list(net.estimate_rate_factors) if net is not None else None,
            "chosen": {n: st.estimate_rate for n, st in chosen.items()},
        }
        info["feedback_growth"] = {
            "factors": list(net.feedback_growth_factors) if net is not None else None,
            "chosen": {n: st.feedback_growth for n, st in chosen.items()},
        }
    picked = res.pick_and_place
    if picked is not None:  # metrics.json's case pick_and_place: what was carried when
        info["pick_and_place"] = {
            "duration": picked.scenario.duration,
            "carries": [{"pick": on, "place": off, "kg": kg} for on, off, kg in picked.masses()],
            "sim_seconds": picked.seconds,
        }
    tuned = {n: r.tuned for n, r in res.runs.items() if r.tuned is not None}
    if tuned:  # the closed-loop tuning: the cost each network reached on the tuning's scenarios
        info["tuning"] = {
            n: {
                "cost": t.cost,
                "held_out": held_out(metrics, n),
                "episodes": t.episodes,
                "seconds": t.seconds,
                "curve": t.curve,
                "confirmation": None if t.confirmation is None else list(t.confirmation),
                "kept_twin": t.kept_twin,
            }
            for n, t in tuned.items()
        }
        info["tuning_scenarios"] = res.tune_scenarios.listed() if res.tune_scenarios is not None else None
        info["tuning_seconds"] = res.tuning_seconds  # every search with its confirmation, and the set-up
        for n, t in tuned.items():
            for it, v in enumerate(t.curve):
                writer.add_scalar(f"control/tuning/{n}/cost", v, it + 1)
    write_summary(writer, "control/summary", control_table(metrics, setup.units, setup.joint_names))
    tracking_curves(writer, res)
    # The second half of the figures is drawn in a forked process beside this one where it can be
    # (rbfn.studies.beside), with a TensorBoard writer of its own.
    names = list(metrics)
    half = len(names) // 2
    fork = parallel and half > 0 and can_fork(device)
    with Beside(_figures, res, names[half:], label, cfg, gains, out_dir, None if fork else writer, fork=fork) as other:
        _figures(res, names[:half], label, cfg, gains, out_dir, writer)
        if picked is not None:
            _pick_and_place_figure(picked, names, setup, label, writer, out_dir)
        other.result()
    log.info("%s", control_table(metrics, setup.units, setup.joint_names))
    out = {"control": metrics, "control_info": info}
    return {**out, "undefined": undefined} if undefined else out


def tracking_curves(writer, res: ControlComparison, every: float = 0.05) -> None:
    """TensorBoard's curves of the closed loop: per controller and payload case the largest
    tracking error over the joints, max_j |q_d,j - q_j| (rad, or m for a prismatic joint), its
    maximum over each `every` s of the run (so that no peak is lost between points; step: the
    window's end, ms), tags control/tracking_error/<controller>/<case>."""
    for name, run in res.runs.items():
        roll = run.rollout
        k = max(1, round(every / float(roll.t[1] - roll.t[0])))
        err = (res.q_des[:, None, :] - roll.q).abs().amax(-1)  # (T, cases), row 0 at t = 0
        windows = (err.shape[0] - 1) // k  # rows 1..k end at t = every, k+1..2k at 2 every, ...
        peaks = err[1 : 1 + windows * k].reshape(windows, k, -1).amax(1)  # (windows, cases)
        peaks[0] = torch.maximum(peaks[0], err[0])  # the start with the first window
        steps = (roll.t[k : 1 + windows * k : k] * 1000).round().long().tolist()
        for i, payload in enumerate(res.payloads):
            tag = f"control/tracking_error/{name}/{payload:g}kg"
            for step, v in zip(steps, peaks[:, i].cpu().tolist()):
                writer.add_scalar(tag, v, step)


def torque_limits(setup: ControlRobot, loop: LoopConfig | None, metrics: dict) -> tuple[list, dict[str, str]]:
    """(control_info's `torque_limits`: per joint the effort limit the realistic loop saturated
    the torque at, N m (N), or None where it had none; metrics.json's `undefined` entries naming
    why). A joint without a limit (the URDF gives none, or the loop applies none:
    `loop.torque_limits=false`) never saturates, so its `saturated` entries in `metrics` are set to
    None (undefined: not 0 %) in place."""
    limited = loop is not None and not loop.ideal and loop.torque_limits
    effort = setup.effort or [math.inf] * setup.n
    limits = [e if limited and math.isfinite(e) else None for e in effort]
    why = [
        "the realistic loop applies no torque limit (loop.torque_limits=false)"
        if not limited
        else f"{setup.joint_names[j]} has no effort limit in the URDF (none given, or 0)"
        for j in range(setup.n)
    ]
    undefined: dict[str, str] = {}
    if loop is None or loop.ideal:
        return limits, undefined  # the ideal loop records no saturation
    for j, e in enumerate(limits):
        if e is None:
            undefined[f"control_info.torque_limits[{j}]"] = why[j]
    for name, cases in metrics.items():
        for case, m in cases.items():
            if "saturated" in m:
                for j, e in enumerate(limits):
                    if e is None:
                        m["saturated"][j] = None
                        undefined[f"control.{name}.{case}.saturated[{j}]"] = why[j]
    return limits, undefined


def held_out(metrics: dict, name: str) -> float | None:
    """The evaluation's counterpart of the tuning cost: the mean over the payload cases (not the
    pick-and-place run) of sum_j rms_j / rms_j(smc) of controller `name` (None without smc)."""
    if "smc" not in metrics:
        return None
    ratios = [
        sum(r / max(s, 1e-12) for r, s in zip(m["rms_err"], metrics["smc"][case]["rms_err"]))
        for case, m in metrics[name].items()
        if case != PICK_AND_PLACE
    ]
    return sum(ratios) / len(ratios)


def _figures(
    res: ControlComparison,
    names: list[str],
    label: str,
    cfg: ControlConfig,
    gains: GainsConfig,
    out_dir: Path,
    writer=None,
) -> None:
    """control_<name>.png for each of `names`, titled with the robot's `label` (robot_label), also
    to `writer` (None: a writer of its own)."""
    own = writer is None
    writer = SummaryWriter(log_dir=str(out_dir), filename_suffix=".figures") if own else writer
    try:
        for name in names:
            _figure(res, name, label, cfg, gains, writer, out_dir)
    finally:
        if own:
            writer.close()


def _figure(
    res: ControlComparison, name: str, label: str, cfg: ControlConfig, gains: GainsConfig, writer, out_dir: Path
) -> None:
    """control_<name>.png: every payload case, the joints by their URDF names, the controller's own
    gains in the title."""
    assert res.robot is not None  # compare_controllers records it
    roll = res.runs[name].rollout
    fig = tracking_figure(
        roll.t.cpu().numpy(),
        roll.q.cpu().numpy(),
        res.q_des.cpu().numpy(),
        roll.tau.cpu().numpy(),
        robot=label,
        detail=f"{name}, {controller_gains(name, gains, res.network)}",
        window=(cfg.payload_on, cfg.payload_off),
        units=res.robot.units,
        limits=None if res.robot.lower is None or res.robot.upper is None else (res.robot.lower, res.robot.upper),
        cases=[f"{m:g} kg" for m in res.payloads],
        joint_names=res.robot.joint_names,
    )
    write_figure(fig, out_dir / f"control_{name}.png", 110, writer, f"figures/control_{name}")


def controller_gains(name: str, gains: GainsConfig, network: NetworkConfig | None = None) -> str:
    """The gains controller `name` runs with, as a figure's title gives them (per unit of the
    joint scale s_j): pd its Kp and Kd, ctc its Lambda, the sliding-mode family K and Lambda (and
    the observer's and the network's law where they have them). `network`: control.network as it
    ran (`ControlComparison.network`)."""
    if name == "pd":
        kp, kd = pd_gains(gains)
        return f"Kp = {kp:g}, Kd = {kd:g}"
    if name == "ctc":
        return f"Lambda = {gains.Lambda:g} 1/s (critically damped)"
    text = f"K = {gains.K:g}, Lambda = {gains.Lambda:g} 1/s"
    if name == "smc_obs":
        text += f", observer {gains.observer_gain:g} 1/s"
    if network_method(name) and network is not None and network.law is not None:
        text += f", {network.law} law"
    return text


def _pick_and_place_figure(
    picked: PickedAndPlaced, names: list[str], setup: ControlRobot, label: str, writer, out_dir: Path
) -> None:
    """control_pick_and_place.png: every controller's tracking error and the mass carried."""
    roll = picked.rollout
    err = (picked.q_des[:, None, :] - roll.q).cpu().numpy()  # (T, controllers, n)
    fig = pick_and_place_figure(
        roll.t.cpu().numpy(),
        err,
        names,
        picked.carried.cpu().numpy(),
        robot=label,
        units=[u for u, _ in setup.units],
        joint_names=setup.joint_names,
    )
    write_figure(fig, out_dir / "control_pick_and_place.png", 110, writer, "figures/control_pick_and_place")


def control_table(
    metrics: dict, units: list[tuple[str, str]] | None = None, joint_names: list[str] | None = None
) -> str:
    """RMS error per joint (t > 0.5 s), max error of the last joint in the payload window, peak
    torques; in the realistic loop the largest share of time a joint with a torque limit spent
    saturated ("no limit" where no joint has one: `saturated` None, `torque_limits`), where
    `smc_exact` ran the smallest share of the smc -> smc_exact gap closed over the joints, and the
    largest share of time a joint spent beyond its URDF position limit. `joint_names` name the
    joints without a limit below the table."""
    units = units or [("rad", "N m"), ("rad", "N m"), ("m", "N")]
    n = len(units)
    pos = ", ".join(f"e{j + 1}" for j in range(n)) + " [" + ", ".join(u for u, _ in units) + "]"
    tq = "peak |tau| [" + ", ".join(u for _, u in units) + "]"
    last = f"max e{n} window [{units[-1][0]}]"
    first: dict = next(iter(next(iter(metrics.values())).values()), {}) if metrics else {}
    extra = ("   sat max" if "saturated" in first else "") + ("  gap min" if "gap_closure" in first else "")
    extra += "  beyond limit" if "limit_breach" in first else ""
    wide = max([6] + [len(case) for cases in metrics.values() for case in cases])
    lines = [f"{'controller':14s} {'case':>{wide}s}  {'RMS ' + pos:>{10 * n}s}  {last:>17s}  {tq:>{9 * n}s}{extra}"]
    for name, cases in metrics.items():
        for case, m in cases.items():
            rms = " ".join(f"{v:9.2e}" for v in m["rms_err"])
            peak = " ".join(f"{v:8.1f}" for v in m["peak_tau"])
            row = f"{name:14s} {case:>{wide}s}  {rms:>{10 * n}s}  {m['max_err_payload'][-1]:17.3e}  {peak:>{9 * n}s}"
            if "saturated" in m:
                sat = [v for v in m["saturated"] if v is not None]
                row += f"  {100 * max(sat):7.2f}%" if sat else "  no limit"
            if "gap_closure" in m:
                row += f"  {min(m['gap_closure']):7.2f}"
            if "limit_breach" in m:
                row += f"  {100 * max(m['limit_breach']):12.2f}%"
            lines.append(row)
    unlimited = [j for j, v in enumerate(first.get("saturated", [])) if v is None]
    if unlimited:
        names = [joint_names[j] if joint_names else f"joint {j + 1}" for j in unlimited]
        lines.append(f"sat max: over the joints with a torque limit; no limit on {names} (never counted as saturated)")
    return "\nClosed loop\n" + "\n".join(lines)
