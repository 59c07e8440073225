"""Summarize a Hydra multirun: one row per swept setting, mean +- std over seeds.

    python -m rbfn.summarize SWEEP_DIR [--metrics KEY ...] [--out PREFIX] [--compare KEY=A,B ...]

Reads every job's metrics.json and .hydra/overrides.yaml under SWEEP_DIR, groups the jobs by the
overrides that vary across the sweep (all but `seed`), prints a Markdown table and writes
SWEEP_DIR/summary.md, summary.csv and, when `rbfn.num_centers` is swept, summary.png (error
against M, one line per other setting). `--compare centers=aco,kmeans_refine` adds a paired
table: for jobs that differ only in that key (same seed, so the same data), A - B per metric
(mean +- std over the pairs), the mean ratio A / B and how many pairs A wins (lower is better).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import math
from collections import defaultdict
from pathlib import Path

__all__ = ["load_jobs", "summarize", "compare", "main"]

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
                stats[key] = _mean_std(vals)
        rows.append((g, len(groups[g]), stats))
    return swept, rows


def _mean_std(vals: list[float]) -> tuple[float, float]:
    mean = sum(vals) / len(vals)
    std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else 0.0
    return mean, std


def compare(jobs, key: str, a: str, b: str, metrics=DEFAULT_METRICS, ignore=("seed",)):
    """Paired comparison of `key`=a against `key`=b, pairing jobs whose other overrides all agree.

    Returns (group keys, rows): each row = (group values, n pairs, {metric: (mean diff, std diff,
    mean ratio a / b, pairs where a is lower)}), grouped by the other swept keys (not `ignore`).
    """
    swept = [k for k in summarize(jobs, (), ignore)[0] if k != key]
    by_rest = {tuple(sorted((k, v) for k, v in o.items() if k != key)): m for o, m in jobs if o.get(key) == b}
    groups: dict[tuple, list[tuple[dict, dict]]] = defaultdict(list)
    for o, m in jobs:
        if o.get(key) == a:
            partner = by_rest.get(tuple(sorted((k, v) for k, v in o.items() if k != key)))
            if partner is not None:
                groups[tuple(o.get(k, "") for k in swept)].append((m, partner))
    if not groups:
        raise ValueError(f"no pairs of jobs with {key}={a} and {key}={b} agreeing on every other override")
    rows = []
    for g in sorted(groups, key=lambda t: tuple((isinstance(_num(x), float), _num(x)) for x in t)):
        stats = {}
        for metric in metrics:
            pairs = [(float(ma[metric]), float(mb[metric])) for ma, mb in groups[g]
                     if ma.get(metric) is not None and mb.get(metric) is not None]
            if pairs:
                mean, std = _mean_std([x - y for x, y in pairs])
                ratio = sum(x / y for x, y in pairs) / len(pairs) if all(y for _, y in pairs) else math.nan
                stats[metric] = (mean, std, ratio, sum(x < y for x, y in pairs))
        rows.append((g, len(groups[g]), stats))
    return swept, rows


def compare_to_markdown(key, a, b, swept, rows, metrics) -> str:
    head = [*swept, "pairs"] + [c for m in metrics for c in (f"{m}: {a} − {b}", f"{a} / {b}", f"{a} lower")]
    lines = [f"{key}: {a} against {b}, paired by seed", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for g, n, stats in rows:
        cells = [*g, str(n)]
        for m in metrics:
            if m in stats:
                d, sd, r, wins = stats[m]
                cells += [f"{d:+.3g} ± {sd:.2g}", f"{r:.3f}", f"{wins}/{n}"]
            else:
                cells += ["", "", ""]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


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
    from matplotlib.figure import Figure       # object API: no pyplot, no backend switch

    i_m = swept.index("rbfn.num_centers")
    lines: dict[tuple, list] = defaultdict(list)
    for g, _, stats in rows:
        if metric in stats:
            lines[g[:i_m] + g[i_m + 1:]].append((float(g[i_m]), *stats[metric]))
    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.subplots()
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
    return True


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m rbfn.summarize", description=__doc__.splitlines()[0])
    p.add_argument("sweep_dir", type=Path)
    p.add_argument("--metrics", nargs="+", default=list(DEFAULT_METRICS))
    p.add_argument("--out", type=Path, default=None, help="output prefix (default SWEEP_DIR/summary)")
    p.add_argument("--compare", action="append", default=[], metavar="KEY=A,B",
                   help="paired table of KEY=A against KEY=B (repeatable)")
    a = p.parse_args(argv)
    jobs = load_jobs(a.sweep_dir)
    swept, rows = summarize(jobs, a.metrics)
    md = to_markdown(swept, rows, a.metrics)
    for spec in a.compare:
        key, _, values = spec.partition("=")
        pair = values.split(",")
        if not key or len(pair) != 2:
            p.error(f"--compare {spec!r}: expected KEY=A,B")
        md += "\n" + compare_to_markdown(key, *pair, *compare(jobs, key, *pair, a.metrics), a.metrics)
    prefix = a.out or a.sweep_dir / "summary"
    Path(f"{prefix}.md").write_text(md)
    Path(f"{prefix}.csv").write_text(to_csv(swept, rows, a.metrics))
    plotted = plot_against_m(swept, rows, a.metrics[0], Path(f"{prefix}.png"))
    print(md)
    print(f"wrote {prefix}.md, {prefix}.csv" + (f", {prefix}.png" if plotted else ""))


if __name__ == "__main__":
    main()
