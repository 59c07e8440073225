"""Summarize a Hydra multirun: one row per swept setting, mean +- std over seeds.

    python -m rbfn.summarize SWEEP_DIR [--metrics KEY ...] [--out PREFIX]

Reads every job's metrics.json and .hydra/overrides.yaml under SWEEP_DIR, groups the jobs by the
overrides that vary across the sweep (all but `seed`), prints a Markdown table and writes
SWEEP_DIR/summary.md, summary.csv and, when `rbfn.num_centers` is swept, summary.png (error
against M, one line per other setting).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import math
from collections import defaultdict
from pathlib import Path

__all__ = ["load_jobs", "summarize", "main"]

DEFAULT_METRICS = ("test_pos_err_mm_median", "test_pos_err_mm_p95", "test_pos_err_mm_max",
                   "test_pos_err_mm_median_float32", "select_seconds", "train_seconds")


def _overrides(job: Path) -> dict[str, str]:
    f = job / ".hydra" / "overrides.yaml"
    out = {}
    if f.is_file():
        for line in f.read_text().splitlines():
            line = line.strip().removeprefix("- ").strip().strip("'\"")
            if "=" in line:
                k, v = line.split("=", 1)
                out[k] = v
    return out


def load_jobs(sweep_dir: Path) -> list[tuple[dict[str, str], dict]]:
    """(overrides, metrics) for every job directory under `sweep_dir` holding a metrics.json."""
    jobs = []
    for m in sorted(sweep_dir.glob("**/metrics.json")):
        jobs.append((_overrides(m.parent), json.loads(m.read_text())))
    if not jobs:
        raise FileNotFoundError(f"no metrics.json under {sweep_dir}")
    return jobs


def _num(v: str):
    try:
        return float(v)
    except ValueError:
        return v


def summarize(jobs, metrics=DEFAULT_METRICS, ignore=("seed",)):
    """(group keys, rows): each row = (group values, n, {metric: (mean, std)})."""
    keys = sorted({k for o, _ in jobs for k in o})
    swept = [k for k in keys if k not in ignore and len({o.get(k) for o, _ in jobs}) > 1]
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for o, m in jobs:
        groups[tuple(o.get(k, "") for k in swept)].append(m)
    rows = []
    for g in sorted(groups, key=lambda t: tuple((isinstance(_num(x), float), _num(x)) for x in t)):
        stats = {}
        for key in metrics:
            vals = [float(m[key]) for m in groups[g] if key in m and m[key] is not None]
            if vals:
                mean = sum(vals) / len(vals)
                std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
                stats[key] = (mean, std)
        rows.append((g, len(groups[g]), stats))
    return swept, rows


def to_markdown(swept, rows, metrics) -> str:
    head = [*swept, "n", *metrics]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for g, n, stats in rows:
        cells = [*g, str(n)] + [f"{stats[k][0]:.4g} ± {stats[k][1]:.2g}" if k in stats else "" for k in metrics]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def to_csv(swept, rows, metrics) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow([*swept, "n", *[f"{k}_{s}" for k in metrics for s in ("mean", "std")]])
    for g, n, stats in rows:
        w.writerow([*g, n, *[x for k in metrics for x in (stats.get(k, ("", ""))[0], stats.get(k, ("", ""))[1])]])
    return buf.getvalue()


def plot_against_m(swept, rows, metric: str, path: Path) -> bool:
    """Error against M (log-log), one line per setting of the other swept keys."""
    if "rbfn.num_centers" not in swept:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    i_m = swept.index("rbfn.num_centers")
    lines: dict[tuple, list] = defaultdict(list)
    for g, _, stats in rows:
        if metric in stats:
            lines[g[:i_m] + g[i_m + 1:]].append((float(g[i_m]), *stats[metric]))
    fig, ax = plt.subplots(figsize=(6.4, 4.8), constrained_layout=True)
    for label, pts in sorted(lines.items()):
        pts.sort()
        ax.errorbar([p[0] for p in pts], [p[1] for p in pts], yerr=[p[2] for p in pts], marker="o",
                    capsize=3, label=", ".join(label) or "all")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("M (hidden nodes)")
    ax.set_ylabel(metric)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m rbfn.summarize", description=__doc__.splitlines()[0])
    p.add_argument("sweep_dir", type=Path)
    p.add_argument("--metrics", nargs="+", default=list(DEFAULT_METRICS))
    p.add_argument("--out", type=Path, default=None, help="output prefix (default SWEEP_DIR/summary)")
    a = p.parse_args(argv)
    swept, rows = summarize(load_jobs(a.sweep_dir), a.metrics)
    md = to_markdown(swept, rows, a.metrics)
    prefix = a.out or a.sweep_dir / "summary"
    Path(f"{prefix}.md").write_text(md)
    Path(f"{prefix}.csv").write_text(to_csv(swept, rows, a.metrics))
    plotted = plot_against_m(swept, rows, a.metrics[0], Path(f"{prefix}.png"))
    print(md)
    print(f"wrote {prefix}.md, {prefix}.csv" + (f", {prefix}.png" if plotted else ""))


if __name__ == "__main__":
    main()
