"""Wall time of the closed-loop tuning in one `evaluate.py`: the robot's evaluation config as
evaluate.py composes it (realistic loop, its gains) under the law the tuning searches
(`control.network.law=tracking`, whose objective is then `closed_loop`),
its control comparison run with `--controllers` (default: evaluate.py's own, whose one tuned
controller is `arbfn_aco`), timed as a whole and in its tuning part
(`control_info.tuning_seconds`: the tuning scenarios' `smc` references, every search and its
confirmation), medians of `--repeats` runs:

    python -m bench.tuning_time --robot scara [--threads 2] [--repeats 1] [--device cpu]
    python -m bench.tuning_time --robot ur5 --controllers smc,arbfn_kmeans,arbfn_aco,arbfn_random,arbfn_cmaes

Trailing arguments are evaluate.py's overrides (e.g. `control.network.tune.iterations=32`). Every
row prints the threads, the device, the budget (closed-loop episodes) and each search's own
seconds beside the whole tuning's.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
from dataclasses import replace

import torch

from rbfn.control.comparison import compare_controllers
from rbfn.studies.control import check_control

from .timing import machine_info, timed

__all__ = ["evaluation_config", "measure", "main"]


def composed(name: str, overrides: list[str]):
    """The composed config `name` ("train" or "evaluate", conf/) with `overrides`, as its dataclass."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from rbfn.studies.cli import register_configs

    register_configs()
    conf = str(pathlib.Path(__file__).resolve().parents[1] / "conf")
    with initialize_config_dir(config_dir=conf, version_base=None):
        return OmegaConf.to_object(compose(name, overrides=overrides))


def evaluation_config(robot: str, overrides: list[str] | None = None):
    """evaluate.py's composed config (its dataclass) for `robot` with `overrides`, under the
    tracking law (whose network the closed-loop tuning searches) unless they choose one."""
    from rbfn.robots.derive import derive_evaluate

    extra = list(overrides or [])
    chosen = [] if any(o.startswith("robot=") for o in extra) else [f"robot={robot}"]
    if not any(o.startswith("control.network.law=") for o in extra):
        chosen.append("control.network.law=tracking")
    return derive_evaluate(composed("evaluate", [*chosen, *extra]))


def measure(cfg, controllers: list[str] | None, repeats: int, device: str) -> dict:
    """Medians over `repeats` runs of the comparison's wall time, its tuning's, and each search's (s)."""
    control = cfg.control if controllers is None else replace(cfg.control, controllers=controllers)
    setup = check_control(control, cfg.robot)
    whole, tuning, searches = [], [], {}
    episodes = {}
    runs: list = []

    def run() -> None:
        runs[:] = [compare_controllers(control, cfg.gains, device, setup=setup, loop=cfg.loop)]  # the last only

    for _ in range(repeats):
        whole.append(timed(run, device))  # GPU work included
        res = runs[-1]
        tuning.append(res.tuning_seconds)
        for name, run in res.runs.items():
            if run.tuned is not None and run.tuned.x is not None:
                searches.setdefault(name, []).append(run.tuned.seconds)
                episodes[name] = run.tuned.episodes
    return {
        "robot": cfg.robot.name,
        "controllers": list(control.controllers),
        "comparison_s": statistics.median(whole),
        "tuning_s": statistics.median(tuning),
        "search_s": {k: statistics.median(v) for k, v in searches.items()},
        "episodes": episodes,
        "repeats": repeats,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="scara")
    ap.add_argument("--controllers", default=None, help="comma-separated; default: evaluate.py's control.controllers")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("overrides", nargs="*", help="evaluate.py overrides")
    args = ap.parse_args(argv)
    if args.threads < 1 or args.repeats < 1:
        ap.error(f"--threads={args.threads} and --repeats={args.repeats} must both be >= 1")
    torch.set_num_threads(args.threads)
    cfg = evaluation_config(args.robot, args.overrides)
    controllers = None if args.controllers is None else args.controllers.split(",")
    r = measure(cfg, controllers, args.repeats, args.device)
    info = machine_info(args.device, args.threads)
    print(
        f"machine: {info['cpu']}, {info['usable_cpus']} usable CPUs, torch {info['torch']}, "
        f"{info['threads']} threads, device {args.device}, load average {info['load_average_1min']}"
    )
    print(f"{r['robot']}: controllers {','.join(r['controllers'])}; medians of {r['repeats']} run(s)")
    print(f"  comparison {r['comparison_s']:.1f} s, of which the closed-loop tuning {r['tuning_s']:.1f} s")
    for name, s in r["search_s"].items():
        print(f"  {name}: search {s:.1f} s, {r['episodes'][name]} closed-loop episodes with its confirmation")


if __name__ == "__main__":
    main()
