"""Closed-loop simulator throughput: env-steps per second of `rbfn.control.simulate` (controller
`smc_obs`, float32, RK4 at dt = 1 ms, 10 kg payload throughout), the wall time of one full
10 s scenario at B = 1 (eager, and torch.compile'd in a capped child process), against scipy's
solve_ivp for one environment and MuJoCo's rollout of the same arm where `mujoco` is installed.

    python -m bench.simulator --compiled-scenario cpu   # the child process: prints one JSON line

scipy integrates the same dynamics (sign friction, disturbance, payload window) with a PD law
(Kp = K Lambda, Kd = K, the library's `pd` at the default gains) inside the right-hand side, by
adaptive RK45. MuJoCo's rollout is open loop (its controls are computed beforehand: inverse
dynamics along the reference minus the disturbance), so it does less work per step than the
closed loop; friction is damping + frictionloss there.

URDF arms (`arm_rows`, `arm_mujoco_rows`; the UR5 by default): the same closed loop (`smc_obs`, the
robot's derived joint scale and scenario, 2.5 kg at the end link throughout, float32) through
`rbfn.control.Plant` over the URDF recursion (`rbfn.robots.arm_terms.ArmTerms`, Cholesky solve)
at B environments, against MuJoCo's rollout of the same
URDF (`rbfn.robots.mjcf.arm_model`, open loop: inverse dynamics along the reference plus the
scenario's friction minus its disturbance), both on one thread:

    python -m bench.simulator --arm ur5 --batches 1,1024,8192 --integrator rk4 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from rbfn.config import ControlConfig, RobotConfig
from rbfn.control import Plant, Scenario, control_robot, make_controller, paper_trajectory, simulate
from rbfn.control.controllers import Gains
from rbfn.control.models import NominalModel
from rbfn.robots import scara
from rbfn.robots.scara import ScaraTerms

from .timing import median_seconds, timed

SCARA_MODEL = NominalModel(ScaraTerms())  # the paper's nominal model of the SCARA

__all__ = [
    "DT",
    "PAYLOAD",
    "closed_loop",
    "env_steps_rows",
    "scenario_seconds",
    "compiled_scenario",
    "aot_scenario",
    "scipy_row",
    "numpy_rk4_row",
    "mujoco_rows",
    "has_c_compiler",
    "robot_config",
    "arm_closed_loop",
    "arm_rows",
    "arm_mujoco_rows",
]

DT, PAYLOAD = 1e-3, 10.0


def closed_loop(
    b: int,
    duration: float,
    device: str = "cpu",
    compile: bool = False,
    payload_window: tuple[float, float] | None = None,
    aot: bool = False,
):
    """A no-argument function running B environments for `duration` s (final state only)."""
    on, off = payload_window or (0.0, duration)
    sc = Scenario(duration=duration, dt=DT, payload_on=on, payload_off=off, metrics_after=0.0)
    ref = tuple(r.to(device) for r in paper_trajectory(sc.times(torch.float32, device)))
    ctrl = make_controller("smc_obs", Gains(), DT, model=SCARA_MODEL)
    q0, qd0 = ref[0][0].expand(b, 3).clone(), ref[1][0].expand(b, 3).clone()
    payload = torch.full((b,), PAYLOAD, device=device)
    plant = Plant(scara.ScaraTerms())
    return lambda: simulate(
        plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, record=False, compile=compile, aot=aot
    )


def env_steps_rows(steps_for: dict[int, int], device: str = "cpu", repeats: int = 3) -> list[dict]:
    """Per B: seconds per closed-loop step and env-steps/s (median of `repeats` runs of n steps)."""
    rows = []
    for b, n in steps_for.items():
        t, _ = median_seconds(closed_loop(b, n * DT, device), repeats, device)
        rows.append({"B": b, "steps": n, "device": device, "seconds": t, "step_s": t / n, "env_steps_per_s": b * n / t})
    return rows


def _window(duration: float) -> tuple[float, float]:
    """The paper's payload window, 1-4 s of 10 s, scaled to shorter runs."""
    return 0.1 * duration, 0.4 * duration


def scenario_seconds(device: str = "cpu", repeats: int = 3, duration: float = 10.0) -> float:
    """Median wall seconds of one eager scenario (B = 1, payload 1-4 s of 10) after a short warm-up."""
    closed_loop(1, 0.05, device)()
    return median_seconds(
        closed_loop(1, duration, device, payload_window=_window(duration)), repeats, device, warmup=0
    )[0]


def has_c_compiler() -> bool:
    """torch.compile's CPU backend needs a C++ compiler."""
    return any(shutil.which(c) for c in ("c++", "g++", "clang++"))


def compiled_scenario(device: str, threads: int, cap_s: float, duration: float = 10.0) -> dict:
    """The compiled scenario timed in a child process killed after `cap_s`: compile seconds
    (first call minus a compiled run) and the median of two compiled runs, or why not."""
    if device == "cpu" and not has_c_compiler():
        return {"status": "no C++ compiler"}
    cmd = [
        sys.executable,
        "-m",
        "bench.simulator",
        "--compiled-scenario",
        device,
        "--threads",
        str(threads),
        "--duration",
        str(duration),
    ]
    t = time.perf_counter()
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=cap_s)
    except subprocess.TimeoutExpired:
        return {"status": f"not done within the {cap_s:.0f} s cap", "wall_s": time.perf_counter() - t}
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode or not lines:
        return {"status": f"failed (exit {out.returncode}): {out.stderr.strip()[-300:]}"}
    return {"status": "ok", **json.loads(lines[-1])}


def _compiled_child(device: str, threads: int, duration: float, aot: bool = False) -> None:
    torch.set_num_threads(threads)
    run = closed_loop(1, duration, device, compile=not aot, aot=aot, payload_window=_window(duration))
    first = timed(run, device)
    t, ts = median_seconds(run, 2, device, warmup=0)
    print(json.dumps({"first_call_s": first, "seconds": t, "runs": ts, "compile_s": first - t}))


def aot_scenario(device: str, threads: int, cap_s: float, duration: float = 10.0) -> dict:
    """The scenario with `aot` (rbfn.control.aot) in two child processes sharing a fresh cache:
    the first builds the package (build_s: its first call minus a run), the second loads it
    (cached_first_call_s: load and one run in a new process); seconds: the median cached run."""
    if device == "cpu" and not has_c_compiler():
        return {"status": "no C++ compiler"}
    import os
    import tempfile

    out: dict = {"status": "ok"}
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "ACO_RBFN_CACHE": cache}
        cmd = [
            sys.executable,
            "-m",
            "bench.simulator",
            "--aot-scenario",
            device,
            "--threads",
            str(threads),
            "--duration",
            str(duration),
        ]
        for run in ("build", "cached"):
            try:
                res = subprocess.run(cmd, capture_output=True, text=True, timeout=cap_s, env=env)
            except subprocess.TimeoutExpired:
                return {"status": f"{run}: not done within the {cap_s:.0f} s cap"}
            lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
            if res.returncode or not lines:
                return {"status": f"{run} failed (exit {res.returncode}): {res.stderr.strip()[-300:]}"}
            r = json.loads(lines[-1])
            if run == "build":
                out["build_s"] = r["compile_s"]
            else:
                out.update(cached_first_call_s=r["first_call_s"], seconds=r["seconds"], runs=r["runs"])
    return out


def numpy_rk4_row(duration: float = 10.0) -> dict:
    """One environment stepped by a plain numpy RK4 loop at dt = 1 ms (the same plant, PD in the
    right-hand side, torque held per step as in `simulate`): wall seconds."""
    params = scara.ScaraParams()
    plant = Plant(scara.ScaraTerms(params))
    rhs = _pd_rhs(params, plant, Gains(), *_window(duration))
    s0 = np.array([1.0, 1.2, 1.0, 0.3, 0.0, 0.7])
    n, h = int(round(duration / DT)), DT

    def run():
        s, t = s0.copy(), 0.0
        for _ in range(n):
            k1 = rhs(t, s)
            k2 = rhs(t + h / 2, s + h / 2 * k1)
            k3 = rhs(t + h / 2, s + h / 2 * k2)
            k4 = rhs(t + h, s + h * k3)
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t += h

    t, _ = median_seconds(run, 1, warmup=0)
    return {
        "method": "numpy RK4 loop (PD in the RHS)",
        "B": 1,
        "duration": duration,
        "seconds": t,
        "env_steps_per_s": n / t,
    }


def _pd_rhs(p: scara.ScaraParams, plant: Plant, gains: Gains, on: float, off: float):
    """Right-hand side of the closed loop (state (6,): q, qd) in numpy, PD inside."""
    kp, kd = gains.K * gains.Lambda, gains.K

    def rhs(t: float, s: np.ndarray) -> np.ndarray:
        q, qd = s[:3], s[3:]
        st, ct = math.sin, math.cos
        q_d = np.array(
            [1 + 0.1 * (st(t) + st(2 * t)), 1 + 0.1 * (ct(2 * t) + ct(3 * t)), 1 + 0.1 * (st(3 * t) + st(4 * t))]
        )
        v_d = np.array(
            [
                0.1 * (ct(t) + 2 * ct(2 * t)),
                -0.1 * (2 * st(2 * t) + 3 * st(3 * t)),
                0.1 * (3 * ct(3 * t) + 4 * ct(4 * t)),
            ]
        )
        tau = kp * (q_d - q) + kd * (v_d - qd)
        p1, p2, p3, m3 = scara.inertia_params(PAYLOAD if on <= t < off else 0.0, p)
        c2, h = math.cos(q[1]), p2 * math.sin(q[1])
        r = tau - plant.viscous * qd - plant.coulomb * np.sign(qd) - plant.dist * math.sin(plant.dist_freq * t)
        r[0] += h * (qd[1] * qd[0] + (qd[0] + qd[1]) * qd[1])
        r[1] -= h * qd[0] * qd[0]
        r[2] += m3 * p.g
        m11, m12 = p1 + 2 * p2 * c2, p3 + p2 * c2
        det = m11 * p3 - m12 * m12
        qdd = np.array([(p3 * r[0] - m12 * r[1]) / det, (m11 * r[1] - m12 * r[0]) / det, r[2] / m3])
        return np.concatenate([qd, qdd])

    return rhs


def scipy_row(duration: float = 10.0, repeats: int = 1) -> dict:
    """One environment by scipy's solve_ivp (RK45, rtol 1e-6, atol 1e-8): wall seconds, RHS calls."""
    from scipy.integrate import solve_ivp

    params = scara.ScaraParams()
    plant = Plant(scara.ScaraTerms(params))
    rhs = _pd_rhs(params, plant, Gains(), *_window(duration))
    s0 = np.array([1.0, 1.2, 1.0, 0.3, 0.0, 0.7])  # the reference at t = 0
    sol = {}

    def run():
        sol["r"] = solve_ivp(rhs, (0.0, duration), s0, method="RK45", rtol=1e-6, atol=1e-8)

    t, _ = median_seconds(run, repeats, warmup=0)
    return {
        "method": "scipy solve_ivp (RK45, PD in the RHS)",
        "B": 1,
        "duration": duration,
        "seconds": t,
        "env_steps_per_s": duration / DT / t,
        "nfev": int(sol["r"].nfev),
        "ok": bool(sol["r"].success),
    }


def _timed_rollout(
    model, datas: list, q0: torch.Tensor, qd0: torch.Tensor, tau: torch.Tensor, b: int, repeats: int
) -> tuple[float, list[float]]:
    """(median, runs) seconds of MuJoCo's rollout of B copies of `model` from (q0, qd0), the open-loop
    torques tau (n, joints) shared by every copy; more than one MjData: rollout's threads."""
    import mujoco
    from mujoco import rollout

    d = datas[0]
    d.qpos[:], d.qvel[:] = q0.numpy(), qd0.numpy()
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, d, state0, spec)
    init = np.tile(state0, (b, 1))
    ctrl = np.ascontiguousarray(tau.numpy()[None])  # (1, n, joints), tiled over B
    out = np.empty((b, tau.shape[0], state0.shape[0]))
    return median_seconds(
        lambda: rollout.rollout(model, datas if len(datas) > 1 else d, init, ctrl, state=out), repeats
    )


def mujoco_rows(steps_for: dict[int, int], threads: int = 1, repeats: int = 3, integrator: str = "RK4") -> list[dict]:
    """MuJoCo's rollout (dt = 1 ms, open loop) of B copies of the arm; [] if not installed."""
    try:
        import mujoco
        from mujoco import rollout  # noqa: F401  (imported here only to return [] without it)
    except ImportError:
        return []
    from rbfn.robots.scara.mjcf import scara_mjcf

    model = mujoco.MjModel.from_xml_string(scara_mjcf(payload=PAYLOAD, dt=DT, integrator=integrator))
    datas = [mujoco.MjData(model) for _ in range(max(threads, 1))]
    plant = Plant(scara.ScaraTerms())
    rows = []
    for b, n in steps_for.items():
        t_grid = torch.arange(n, dtype=torch.float64) * DT
        q, qd, qdd = paper_trajectory(t_grid)
        tau = (
            torch.einsum("bij,bj->bi", scara.mass_matrix(q, PAYLOAD), qdd)
            + torch.einsum("bij,bj->bi", scara.coriolis(q, qd, PAYLOAD), qd)
            + scara.gravity(q, PAYLOAD)
            + plant.friction_torque(qd)
            - plant.disturbance(t_grid)[:, None]
        )
        t, _ = _timed_rollout(model, datas, q[0], qd[0], tau, b, repeats)
        rows.append(
            {
                "B": b,
                "steps": n,
                "device": "cpu",
                "seconds": t,
                "env_steps_per_s": b * n / t,
                "mujoco": mujoco.__version__,
            }
        )
    return rows


# ----------------------------------------------------------------------------- URDF arms
ARM_PAYLOAD = 2.5  # kg at the end link, the UR5's half rated payload


def robot_config(name: str) -> RobotConfig:
    """The packaged robot preset conf/robot/<name>.yaml as a RobotConfig (no Hydra needed)."""
    from omegaconf import OmegaConf

    path = Path(__file__).resolve().parents[1] / "conf" / "robot" / f"{name}.yaml"
    raw = OmegaConf.load(path)
    raw.pop("defaults", None)
    return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(RobotConfig), raw))


def arm_closed_loop(
    b: int,
    steps: int,
    robot: str = "ur5",
    integrator: str = "rk4",
    device: str = "cpu",
    dtype: torch.dtype = torch.float32,
    compile: bool = False,
):
    """A no-argument function running B environments of the arm's closed loop (`smc_obs`) for
    `steps` periods (final state only)."""
    setup = control_robot(robot_config(robot), ControlConfig())
    kw = {"dtype": dtype, "device": device}
    sc = Scenario(
        duration=steps * DT, dt=DT, integrator=integrator, payload_on=0.0, payload_off=steps * DT, metrics_after=0.0
    )
    ref = tuple(r.to(**kw) for r in setup.trajectory(sc.times()))
    ctrl = make_controller("smc_obs", Gains(), DT, model=setup.model, joint_scale=setup.joint_scale(**kw))
    q0, qd0 = ref[0][:1].expand(b, setup.n).clone(), ref[1][:1].expand(b, setup.n).clone()
    payload = torch.full((b,), ARM_PAYLOAD, **kw)
    return lambda: simulate(setup.plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, record=False, compile=compile)


def arm_rows(
    steps_for: dict[int, int],
    robot: str = "ur5",
    integrator: str = "rk4",
    device: str = "cpu",
    repeats: int = 5,
    compile: bool = False,
) -> list[dict]:
    """Per B: env-steps/s of the arm's closed loop (median of `repeats` runs of n steps, each run
    after a warm-up)."""
    rows = []
    for b, n in steps_for.items():
        t, ts = median_seconds(arm_closed_loop(b, n, robot, integrator, device, compile=compile), repeats, device)
        rows.append(
            {
                "robot": robot,
                "integrator": integrator,
                "B": b,
                "steps": n,
                "device": device,
                "compiled": compile,
                "seconds": t,
                "step_ms": 1e3 * t / n,
                "env_steps_per_s": b * n / t,
                "runs_env_steps_per_s": [b * n / x for x in ts],
            }
        )
    return rows


def arm_mujoco_rows(
    steps_for: dict[int, int], robot: str = "ur5", integrator: str = "RK4", threads: int = 1, repeats: int = 5
) -> list[dict]:
    """MuJoCo's rollout (dt = 1 ms, open loop) of B copies of the same arm, [] without mujoco."""
    try:
        import mujoco
        from mujoco import rollout  # noqa: F401  (imported here only to return [] without it)
    except ImportError:
        return []
    from rbfn.robots.mjcf import arm_model

    cfg = robot_config(robot)
    setup = control_robot(cfg, ControlConfig())
    plant = setup.plant
    model = arm_model(
        Path(cfg.urdf) if cfg.urdf else cfg.name,
        payload=ARM_PAYLOAD,
        payload_link=plant.dynamics.arm.end_link,
        viscous=plant.viscous,
        coulomb=plant.coulomb,
        dt=DT,
        integrator=integrator,
        gravity=cfg.gravity,
    )
    datas = [mujoco.MjData(model) for _ in range(max(threads, 1))]
    rows = []
    for b, n in steps_for.items():
        t_grid = torch.arange(n, dtype=torch.float64) * DT
        q, qd, qdd = setup.trajectory(t_grid)
        tau = (
            plant.dynamics.arm.inverse_dynamics(q, qd, qdd, ARM_PAYLOAD)
            + plant.friction_torque(qd)
            - plant.disturbance(t_grid)
        )
        t, ts = _timed_rollout(model, datas, q[0], qd[0], tau, b, repeats)
        rows.append(
            {
                "robot": robot,
                "integrator": integrator,
                "B": b,
                "steps": n,
                "device": "cpu",
                "seconds": t,
                "env_steps_per_s": b * n / t,
                "runs_env_steps_per_s": [b * n / x for x in ts],
                "mujoco": mujoco.__version__,
            }
        )
    return rows


def _arm_main(a) -> None:
    torch.set_num_threads(a.threads)
    batches = [int(x) for x in a.batches.split(",")]
    steps_for = {b: max(5, min(1000, a.env_steps // b)) for b in batches}
    ours = arm_rows(steps_for, a.arm, a.integrator, a.device, a.repeats, a.compile)
    theirs = arm_mujoco_rows(steps_for, a.arm, {"rk4": "RK4", "euler": "Euler"}[a.integrator], a.threads, a.repeats)
    mj = {r["B"]: r for r in theirs}
    print(
        f"{a.arm} closed loop (smc_obs, {a.integrator}, float32, {a.threads} thread(s), {a.device}"
        f"{', compiled' if a.compile else ''}): env-steps/s, median of {a.repeats}"
    )
    print(f"{'B':>6s} {'steps':>6s} {'ours':>12s} {'MuJoCo':>12s} {'ratio':>7s}")
    for r in ours:
        m = mj.get(r["B"])
        mr = (
            f"{m['env_steps_per_s']:12.0f} {r['env_steps_per_s'] / m['env_steps_per_s']:7.2f}"
            if m
            else f"{'-':>12s} {'-':>7s}"
        )
        print(f"{r['B']:6d} {r['steps']:6d} {r['env_steps_per_s']:12.0f} {mr}")
    if a.json:
        Path(a.json).write_text(json.dumps({"ours": ours, "mujoco": theirs}, indent=1))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description="closed-loop simulator benchmarks (the suite runs them through "
        "python -m bench; this entry point: URDF arms, and the compiled "
        "scenario's child process)"
    )
    ap.add_argument("--compiled-scenario", metavar="DEVICE", help="child process of compiled_scenario")
    ap.add_argument("--aot-scenario", metavar="DEVICE", help="child process of aot_scenario")
    ap.add_argument("--arm", metavar="ROBOT", help="a URDF arm's closed loop against MuJoCo (ur5, panda, scara)")
    ap.add_argument("--batches", default="1,1024,8192", help="comma-separated B")
    ap.add_argument("--env-steps", type=int, default=80_000, help="about B x steps per timed run")
    ap.add_argument("--integrator", default="rk4", choices=["rk4", "euler"])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--compile", action="store_true", help="torch.compile the step (minutes to compile)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--json", help="also write the rows to this file")
    a = ap.parse_args()
    if a.arm:
        _arm_main(a)
    elif a.compiled_scenario:
        _compiled_child(a.compiled_scenario, a.threads, a.duration)
    elif a.aot_scenario:
        _compiled_child(a.aot_scenario, a.threads, a.duration, aot=True)
    else:
        ap.error("give --arm ROBOT, --compiled-scenario DEVICE or --aot-scenario DEVICE")
