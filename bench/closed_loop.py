"""ACO-tuned against k-means centres in the closed loop, over seeds: runs `evaluate.py`'s control
part once per seed (realistic loop, the robot's defaults, the tracking law whose network the
searches tune) with the three searches and the twin,
then writes the held-out tables and the tuning curves.

    python -m bench.closed_loop --robot scara --seeds 0,1,2,3,4 --out multirun/closed_loop
    python -m bench.closed_loop --robot ur5 --seeds 0,1,2,3,4 --out multirun/closed_loop
    python -m bench.closed_loop --summarize multirun/closed_loop [--figure docs/closed_loop_tuning.png]

Seed S sets the search and the twin's k-means (`control.network.seed=S`), the tuning scenarios
(`control.network.tune.seed=S+1`) and the evaluation's sensor noise (`loop.noise_seed=S`); seed 0
is evaluate.py's default. A seed whose OUT/<robot>_s<S>/metrics.json exists is not run again.
The summary reads every OUT/<robot>_s<S>/metrics.json: per robot and seed the held-out cost
(mean over the payload cases of sum_j RMS_j / smc's RMS_j) of every controller, the ratio of
`arbfn_aco` to `arbfn_kmeans`, and to the better of `arbfn_random` and `arbfn_cmaes`, and the
tuning's cost and seconds; `--figure` draws each search's best-so-far tuning cost per iteration
relative to the twin's (mean over the seeds that ran all three searches, thin lines each seed).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
from pathlib import Path

from rbfn.config import ADAPTIVE, CLOSED_LOOP_SEARCHES
from rbfn.studies.control import held_out

__all__ = ["CONTROLLERS", "SEARCHES", "run_seed", "load", "tables", "figure", "main"]

SEARCHES = tuple(ADAPTIVE + m for m in CLOSED_LOOP_SEARCHES)  # arbfn_aco, arbfn_random, arbfn_cmaes
CONTROLLERS = ("pd", "ctc", "smc", "smc_obs", "arbfn_kmeans", *SEARCHES)
ROOT = Path(__file__).resolve().parents[1]


def run_seed(robot: str, seed: int, out: Path, extra: list[str]) -> Path:
    """Run evaluate.py's control part for `robot` at `seed` into out/<robot>_s<seed> (skipped where
    its metrics.json exists); the run directory."""
    run_dir = out / f"{robot}_s{seed}"
    if (run_dir / "metrics.json").exists():
        return run_dir
    cmd = [
        sys.executable,
        str(ROOT / "evaluate.py"),
        f"robot={robot}",
        "ik=false",
        "online.enabled=false",
        f"control.controllers=[{','.join(CONTROLLERS)}]",
        "control.network.law=tracking",  # the law whose network the closed-loop searches tune
        f"control.network.seed={seed}",
        f"control.network.tune.seed={seed + 1}",
        f"loop.noise_seed={seed}",
        f"hydra.run.dir={run_dir}",
        *extra,
    ]
    print(" ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)
    return run_dir


def load(out: Path) -> dict[str, dict[int, dict]]:
    """robot -> seed -> metrics.json, for every out/<robot>_s<seed>/metrics.json."""
    runs: dict[str, dict[int, dict]] = {}
    for path in sorted(out.glob("*_s*/metrics.json")):
        match = re.fullmatch(r"(.+)_s(\d+)", path.parent.name)
        if match:
            runs.setdefault(match[1], {})[int(match[2])] = json.loads(path.read_text())
    return runs


def tables(runs: dict[str, dict[int, dict]]) -> str:
    """Markdown: per robot, every seed's held-out cost per controller and the paired ratios."""
    lines = []
    for robot, seeds in runs.items():
        names = [n for n in CONTROLLERS if any(n in m["control"] for m in seeds.values())]
        lines += [
            f"**{robot}** (held-out: mean over the payload cases of sum_j RMS_j / smc's RMS_j; smc = n)",
            "",
            "| seed | " + " | ".join(f"`{n}`" for n in names) + " | aco / kmeans | aco / best other search |",
            "|---" * (len(names) + 3) + "|",
        ]
        ratios, others = [], []
        for seed, m in sorted(seeds.items()):
            cost = {n: held_out(m["control"], n) for n in names if n in m["control"]}
            ratio = cost["arbfn_aco"] / cost["arbfn_kmeans"]
            searched = [cost[n] for n in SEARCHES[1:] if n in cost]  # a seed may run arbfn_aco alone
            ratios.append(ratio)
            other = "-"
            if searched:
                others.append(cost["arbfn_aco"] / min(searched))
                other = f"{others[-1]:.3f}"
            cells = " | ".join(f"{cost[n]:.3f}" if n in cost else "-" for n in names)
            lines.append(f"| {seed} | {cells} | {ratio:.3f} | {other} |")
        lines += [
            "",
            f"aco / kmeans: mean {statistics.fmean(ratios):.3f}, range {min(ratios):.3f} to {max(ratios):.3f}, "
            f"below 1 in {sum(r < 1 for r in ratios)}/{len(ratios)} seeds, at most 0.7 in "
            f"{sum(r <= 0.7 for r in ratios)}/{len(ratios)}"
            + (
                f"; aco / the better other search: mean {statistics.fmean(others):.3f}, "
                f"at most 1 in {sum(r <= 1 for r in others)}/{len(others)} seeds"
                if others
                else ""
            ),
            "",
            "| seed | " + " | ".join(f"`{n}` tuning cost" for n in ("arbfn_kmeans", *SEARCHES)) + " | tuning s |",
            "|---" * 6 + "|",
        ]
        for seed, m in sorted(seeds.items()):
            tuning = m["control_info"]["tuning"]
            cells = " | ".join(
                f"{tuning[n]['cost']:.3f}" + (" (twin kept)" if tuning[n].get("kept_twin") else "")
                if n in tuning
                else "-"
                for n in ("arbfn_kmeans", *SEARCHES)
            )
            seconds = m["control_info"].get("tuning_seconds")
            lines.append(f"| {seed} | {cells} | {'-' if seconds is None else f'{seconds:.0f}'} |")
        lines.append("")
    return "\n".join(lines)


def figure(runs: dict[str, dict[int, dict]], path: Path) -> None:
    """Each search's best-so-far tuning cost per iteration, one panel per robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 4), squeeze=False)
    colours = {"arbfn_aco": "C0", "arbfn_random": "C1", "arbfn_cmaes": "C2", "arbfn_kmeans": "k"}
    for ax, (robot, seeds) in zip(axes[0], runs.items()):
        # the means over the seeds every search ran, so that they compare like with like
        common = [k for k, m in seeds.items() if all(n in m["control_info"]["tuning"] for n in SEARCHES)]
        for name in SEARCHES:
            curves = {}
            for k, m in seeds.items():  # each seed's scenarios differ: relative to its own twin
                tuning = m["control_info"]["tuning"]
                if name in tuning:
                    curves[k] = [v / tuning["arbfn_kmeans"]["cost"] for v in tuning[name]["curve"]]
            for c in curves.values():
                ax.plot(range(1, len(c) + 1), c, color=colours[name], alpha=0.25, lw=0.8)
            if common:
                mean = [statistics.fmean(v) for v in zip(*(curves[k] for k in common))]
                ax.plot(range(1, len(mean) + 1), mean, color=colours[name], lw=2, label=f"{name} (mean)")
        ax.axhline(1.0, color="k", ls="--", lw=1, label="arbfn_kmeans, the twin")
        ax.set(
            title=f"{robot}: means over seeds {', '.join(map(str, common))}; thin: every seed",
            xlabel="iteration (each: a batch of candidates x the tuning scenarios)",
            ylabel="best tuning cost so far / the twin's",
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="scara")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--out", type=Path, default=Path("multirun/closed_loop"))
    ap.add_argument("--summarize", type=Path, default=None, help="only summarize this directory's runs")
    ap.add_argument("--figure", type=Path, default=None, help="write the tuning curves' figure here (PNG)")
    ap.add_argument("overrides", nargs="*", help="more evaluate.py overrides for every seed")
    args = ap.parse_args(argv)
    out = args.summarize or args.out
    if args.summarize is None:
        try:
            seeds = [int(s) for s in args.seeds.split(",")]
        except ValueError:
            ap.error(f"--seeds={args.seeds!r}: give comma-separated integers, e.g. 0,1,2,3,4")
        for seed in seeds:
            run_seed(args.robot, seed, args.out, args.overrides)
    runs = load(out)
    if not runs:
        ap.error(f"no <robot>_s<seed>/metrics.json under {out}")
    print(tables(runs))
    if args.figure is not None:
        figure(runs, args.figure)
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
