"""The realistic loop's cost against the ideal loop's: env-steps per second (integration steps x
environments / s) of `rbfn.control.simulate` on the SCARA's closed form, controller `smc_obs` at
the realistic gains, 1 s at dt = 1 ms, a 10 kg payload from 0.2 to 0.8 s, float64; the ideal loop
(controller every step, exact state) against `loop=realistic` (500 Hz with one period of delay,
encoders, noise, filtered velocity, torque limits), medians of `--repeats` runs, taken turn by turn:

    python -m bench.loop_throughput [--batch 8192] [--threads 1] [--repeats 3] [--device cpu]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from rbfn.config import ControlConfig, GainsConfig, LoopConfig, RobotConfig
from rbfn.control import Plant, Scenario, make_controller, paper_trajectory, simulate
from rbfn.control.loop import real_loop
from rbfn.control.models import NominalModel
from rbfn.control.robot_setup import control_robot
from rbfn.robots.scara import ScaraTerms

SCARA_MODEL = NominalModel(ScaraTerms())  # the paper's nominal model of the SCARA

# conf/loop/realistic.yaml with the SCARA's conf/robot values, and conf/gains/robot/scara_realistic.yaml
REALISTIC = LoopConfig(
    name="realistic",
    control_rate=500.0,
    actuation_delay=1,
    encoder_counts=[10485760, 10485760, 11377800],
    position_noise=1e-5,
    velocity_cutoff=50.0,
    torque_limits=True,
)
GAINS = GainsConfig(observer_gain=25.0, gamma=200.0, dead_zone=0.012, inertia_scaling=True, phase_margin=30.0)


def measure(batch: int, repeats: int, device: str) -> dict[str, float]:
    """Median env-steps/s of each loop."""
    sc = Scenario(duration=1.0, dt=1e-3, payload_on=0.2, payload_off=0.8)
    kw = {"dtype": torch.float64, "device": device}
    ref = paper_trajectory(sc.times()).to(**kw)
    q0, qd0 = ref.q_d[:1].expand(batch, 3).clone(), ref.qd_d[:1].expand(batch, 3).clone()
    payload = torch.full((batch,), 10.0, **kw)
    real = real_loop(REALISTIC, sc.dt, [False, False, True], torch.tensor([100.0, 100.0, 500.0]))
    assert real is not None
    setup = control_robot(RobotConfig(), ControlConfig())  # the SCARA, rated 20 kg
    factors = setup.gain_factors(GAINS, real, **kw)  # per-joint factors, as evaluate.py's
    loops = {"ideal": (None, sc.dt), "realistic": (real, real.period)}
    times: dict[str, list[float]] = {name: [] for name in loops}
    for _ in range(repeats):
        for name, (loop, period) in loops.items():  # turn by turn
            ctrl = make_controller(
                "smc_obs", GAINS, period, model=SCARA_MODEL, joint_scale=factors.scale, rates=factors.rates
            )
            if device != "cpu":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            simulate(Plant(ScaraTerms()), ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, record=False, loop=loop)
            if device != "cpu":
                torch.cuda.synchronize()
            times[name].append(time.perf_counter() - t0)
    return {name: sc.steps * batch / statistics.median(t) for name, t in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=8192)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rates = measure(args.batch, args.repeats, args.device)
    print(f"B = {args.batch}, {args.threads} thread(s), {args.device}, median of {args.repeats}:")
    for name, rate in rates.items():
        print(f"  {name:10s} {rate:.3g} env-steps/s")
    print(f"  realistic / ideal: {rates['realistic'] / rates['ideal']:.2f}")


if __name__ == "__main__":
    main()
