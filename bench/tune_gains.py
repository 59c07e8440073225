"""The procedure behind `gains=realistic`: one gain set per robot for the realistic loop, equal for
every controller, chosen on tuning scenarios that are not the evaluation's.

Held fixed: the robot's tuned feedback (K, Lambda, epsilon, the boundary layer) and the dead zone
derived from the loop's noise (conf/gains/realistic.yaml). Searched: the observer's bandwidth K_o
and the adaptation rate Gamma, over a grid. Tuning scenarios: 6 s (the evaluation's: 10 s), the
disturbance at 3 rad/s (evaluation: 2 rad/s), payloads of 0.3 and
0.8 times the rated payload (evaluation: 0, 0.5 and 1), sensor-noise seed 1 (evaluation: 0).
Controllers scored: `smc_obs` and `arbfn_kmeans` (the ACO controller is left out, so that the
gains cannot favour it). A set is admissible when no scored controller diverges or spends more
than 1 % of the time at a torque limit on any joint, with Gamma as given and doubled (a gain margin
of 2 on the adaptation: on the UR5, Gamma = 2000 diverges where 1000 is still the best on the
tuning scenarios). Among those, the sets whose worst ratio (over
controllers, payloads and joints) of RMS error to `smc`'s RMS is within 5 % of the smallest are
tied (with per-joint rates, `gains.inertia_scaling`, a joint whose rates are capped is the same under
many sets), and the one with the smallest mean ratio wins; sets equal in that too, to rounding (every
joint's observer capped), go to the K_o nearest the derived one in conf/gains/robot/<robot>_realistic.yaml.
Where none is admissible, the one with the least time saturated.

    python -m bench.tune_gains --robot scara [--observer 5,10,25,50,100] [--gamma 50,100,200,500]
    python -m bench.tune_gains robot=urdf robot.urdf=PATH robot.end_link=LINK   # your arm

Trailing arguments are evaluate.py's overrides (your arm's keys, derived from the URDF as
evaluate.py derives them; a `robot=` among them replaces --robot). The last line prints the chosen
set as the overrides to pass to evaluate.py.
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from dataclasses import replace

import torch

from rbfn.control.comparison import compare_controllers
from rbfn.control.simulator import SimulationDiverged
from rbfn.studies.control import check_control

from .tuning_time import evaluation_config

SCORED = ("smc_obs", "arbfn_kmeans")


def tuning_config(robot: str, overrides: list[str] | None = None):
    """The evaluation config of `robot` (or of a `robot=` among `overrides`, evaluate.py's
    overrides) in the realistic loop, with the tuning scenarios; robot=urdf's keys derived."""
    cfg = evaluation_config(robot, ["loop=realistic", "gains=realistic", *(overrides or [])])
    rated = cfg.robot.rated_payload
    cfg.control = replace(
        cfg.control,
        duration=6.0,
        payload_on=1.0,
        payload_off=4.0,
        disturbance_freq=3.0,
        payloads=[round(0.3 * rated, 6), round(0.8 * rated, 6)],
        controllers=["smc", *SCORED],
    )
    cfg.loop = replace(cfg.loop, noise_seed=1)
    return cfg


def score(cfg, observer: float, gamma: float) -> tuple[float, float, float]:
    """(worst and mean RMS / smc's RMS over the scored controllers, payloads and joints; worst share
    of time at a torque limit); (inf, inf, inf) where the loop diverges."""
    gains = replace(cfg.gains, observer_gain=observer, gamma=gamma)
    setup = check_control(cfg.control, cfg.robot)
    try:
        res = compare_controllers(cfg.control, gains, "cpu", setup=setup, loop=cfg.loop)
    except SimulationDiverged:
        return math.inf, math.inf, math.inf
    smc = res.runs["smc"].metrics
    ratios, saturated = [], 0.0
    for name in SCORED:
        for case, m in res.runs[name].metrics.items():
            ratios += [c / s for c, s in zip(m["rms_err"], smc[case]["rms_err"])]
            saturated = max(saturated, *m["saturated"])
    return max(ratios), sum(ratios) / len(ratios), saturated


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="scara")
    ap.add_argument("--observer", default="5,10,25,50,100")
    ap.add_argument("--gamma", default="50,100,200,500")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("overrides", nargs="*", help="evaluate.py overrides, e.g. robot=urdf robot.urdf=PATH ...")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = tuning_config(args.robot, args.overrides)
    scores: dict[tuple[float, float], tuple[float, float, float]] = {}

    def scored(ko: float, gm: float) -> tuple[float, float, float]:
        if (ko, gm) not in scores:
            t0 = time.perf_counter()
            scores[ko, gm] = worst, mean, sat = score(cfg, ko, gm)
            print(
                f"K_o {ko:7.1f}  Gamma {gm:7.1f}  RMS/smc worst {worst:9.3g} mean {mean:9.3g}"
                f"  saturated {100 * sat:6.2f} %  ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        return scores[ko, gm]

    def ok(ko: float, gm: float) -> bool:
        worst, _, sat = scored(ko, gm)
        return sat <= 0.01 and math.isfinite(worst)

    rows, admissible = [], []
    for ko, gm in itertools.product(map(float, args.observer.split(",")), map(float, args.gamma.split(","))):
        worst, mean, sat = scored(ko, gm)
        rows.append((ko, gm, worst, sat, mean))
        if ok(ko, gm) and ok(ko, 2 * gm):
            admissible.append(rows[-1])
    if admissible:
        least = min(r[2] for r in admissible)
        derived = cfg.gains.observer_gain
        tied = [r for r in admissible if r[2] <= 1.05 * least]
        lowest = min(r[4] for r in tied)  # equal to rounding: the rates capped the same way
        equal = [r for r in tied if r[4] <= (1 + 1e-9) * lowest]
        best = min(equal, key=lambda r: abs(math.log(r[0] / derived)))
    else:
        best = min(rows, key=lambda r: (r[3], r[2]))
    print(
        f"chosen for {cfg.robot.name}: observer_gain {best[0]}, gamma {best[1]} "
        f"({'admissible' if admissible else 'none admissible: least saturated'}); "
        f"for evaluate.py: gains.observer_gain={best[0]:g} gains.gamma={best[1]:g}"
    )


if __name__ == "__main__":
    main()
