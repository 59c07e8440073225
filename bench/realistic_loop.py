"""The default (realistic) closed loop's speed: one scenario of `smc_obs` as evaluate.py configures
it for --robot (loop=realistic, the robot's realistic gains, float64, half the rated payload
inside the window), at B environments on --device, eager, torch.compile'd in the process
(`compile`) or compiled ahead of time (`aot`, `control.aot`), against
a plain numpy RK4 loop (the SCARA) and MuJoCo's single-environment rate of the same URDF (arms).

    python -m bench.realistic_loop --robot scara --batches 1 --modes eager,aot --duration 10
    python -m bench.realistic_loop --robot ur5 --batches 1,64 --modes eager --duration 1

Prints one JSON line per row: robot, mode, B, chunk, the first call's seconds (with `aot`: the
package's build on a cold cache, its load on a warm one: run the command twice and read the second
for "counting the build on a second run"), the median run's seconds and env-steps/s, and the
largest difference of q from an eager run (`aot`). One torch thread; the load average is reported.
The numpy row steps the SCARA's ideal loop with PD in the right-hand side (`bench.simulator`),
less work per step than `smc_obs` in the realistic loop: a conservative reference.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import torch

from bench.timing import median_seconds, sync


def setup(robot: str, b: int, duration: float, device: str = "cpu") -> dict:
    """evaluate.py's closed loop for `robot`: the arguments of `simulate` (smc_obs, loop=realistic)."""
    from bench.tuning_time import evaluation_config
    from rbfn.control.controllers import make_controller
    from rbfn.control.loop import real_loop
    from rbfn.control.models import model_scales
    from rbfn.control.robot_setup import control_robot
    from rbfn.control.simulator import Scenario
    from rbfn.control.trajectory import Reference

    cfg = evaluation_config(robot, [])
    c, gains = cfg.control, cfg.gains
    kw: dict = {"dtype": torch.float64, "device": device}
    rob = control_robot(cfg.robot, c)
    on, off = c.payload_on * duration / c.duration, c.payload_off * duration / c.duration
    sc = Scenario(duration, c.dt, str(c.integrator), on, off, 0.0)
    ref = Reference(*rob.trajectory(sc.times(torch.float64))).to(**kw)
    effort = torch.tensor(rob.effort if rob.effort is not None else [float("inf")] * rob.n, device=device)
    loop = real_loop(cfg.loop, sc.dt, rob.prismatic, effort, rob.joint_scale(**kw))
    assert loop is not None, "evaluate.py's default loop is the realistic one"
    factors = rob.gain_factors(gains, loop, dt=sc.dt, **kw)
    model = rob.nominal_model(gains.nominal_payload, model_scales(gains))
    ctrl = make_controller("smc_obs", gains, loop.period, model=model, joint_scale=factors.scale, rates=factors.rates)
    q0, qd0 = ref.q_d[:1].expand(b, rob.n).clone(), ref.qd_d[:1].expand(b, rob.n).clone()
    payload = torch.full((b,), rob.rated_payload / 2, **kw)
    return {
        "plant": rob.plant,
        "controller": ctrl,
        "scenario": sc,
        "ref": ref,
        "q0": q0,
        "qd0": qd0,
        "payload": payload,
        "loop": loop,
    }


def row(robot: str, mode: str, b: int, duration: float, chunk: int, repeats: int, device: str = "cpu") -> dict:
    from rbfn.control.simulator import simulate

    args = setup(robot, b, duration, device)
    kw = {"aot": mode == "aot", "compile": mode == "compile", "chunk": chunk}
    sync(device)
    t0 = time.perf_counter()
    first = simulate(**args, **kw)
    sync(device)
    out: dict = {
        "robot": robot,
        "mode": mode,
        "B": b,
        "device": device,
        "chunk": chunk or "default",
        "duration": duration,
        "first_s": round(time.perf_counter() - t0, 3),
    }
    t, _ = median_seconds(lambda: simulate(**args, **kw), repeats, device, warmup=0)
    steps = args["scenario"].steps
    out.update(run_s=round(t, 4), env_steps_per_s=round(b * steps / t))
    if mode != "eager":
        eager = simulate(**args)
        out["max_abs_dq_vs_eager"] = float((first.q - eager.q).abs().max())
    return out


def mujoco_row(robot: str, duration: float, repeats: int) -> dict | None:
    """MuJoCo's rollout of one environment of the same URDF (open loop, RK4, dt = 1 ms)."""
    from bench.simulator import arm_mujoco_rows

    steps = int(round(duration / 1e-3))
    rows = arm_mujoco_rows({1: steps}, robot=robot, integrator="RK4", threads=1, repeats=repeats)
    return rows[0] if rows else None


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", default="scara")
    p.add_argument("--batches", default="1")
    p.add_argument("--modes", default="eager")
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--chunk", type=int, default=0, help="periods per call (0: 100 eager, the backend's compiled)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--device", default="cpu", help="where the closed loop runs (MuJoCo and numpy on the CPU)")
    a = p.parse_args()
    bad = sorted(set(a.modes.split(",")) - {"eager", "compile", "aot"})
    if bad:
        p.error(f"--modes {a.modes!r}: {', '.join(bad)} unknown; use eager, compile and aot, comma-separated")
    torch.set_num_threads(1)
    info = {"threads": torch.get_num_threads(), "load_average": os.getloadavg(), "torch": torch.__version__}
    if a.device != "cpu":
        info["gpu"] = torch.cuda.get_device_name(torch.device(a.device))
    print(json.dumps(info), flush=True)
    for b in [int(x) for x in a.batches.split(",")]:
        for mode in a.modes.split(","):
            print(json.dumps(row(a.robot, mode, b, a.duration, a.chunk, a.repeats, a.device)), flush=True)
    if a.robot == "scara":
        from bench.simulator import numpy_rk4_row

        print(json.dumps({**numpy_rk4_row(a.duration), "robot": "scara"}), flush=True)
    else:
        r = mujoco_row(a.robot, a.duration, a.repeats)
        print(json.dumps(r if r is not None else {"mujoco": "not installed"}), flush=True)


if __name__ == "__main__":
    main()
