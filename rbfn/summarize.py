"""Summarize a Hydra multirun: one row per swept setting, mean +- std over seeds.

    python -m rbfn.summarize SWEEP_DIR [--metrics KEY ...] [--out PREFIX] [--compare KEY=A,B ...]

Reads every job's metrics.json and .hydra/overrides.yaml under SWEEP_DIR, groups the jobs by the
overrides that vary across the sweep (all but `seed`), prints a Markdown table and writes
SWEEP_DIR/summary.md, summary.csv and, when `rbfn.num_centers` is swept, summary.png (error
against M, one line per other setting). `--compare centers=aco,kmeans_refine` adds a paired
table: for jobs that differ only in that key (same seed, so the same data), A - B per metric
(mean +- std over the pairs), the mean ratio A / B and how many pairs A wins (lower is better).

Jobs without a metrics.json are listed after the table with their error: "failed" when the job
recorded one in failed.json (train.py does so in a multirun), "unfinished" otherwise (running,
or killed or timed out; the last ERROR line of its log, if any, is shown).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import math
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Job", "find_jobs", "load_jobs", "summarize", "compare", "main"]

DEFAULT_METRICS = ("test_pos_err_mm_median", "test_pos_err_mm_p95", "test_pos_err_mm_max",
                   "test_pos_err_mm_median_float32", "select_seconds", "train_seconds")


def _parse_overrides(lines) -> dict[str, str]:
    out = {}
    for line in lines:
        line = str(line).strip().removeprefix("- ").strip().strip("'\"")
        if "=" in line:
            k, v = line.split("=", 1)
            out[k] = v
    return out


def _overrides(job: Path) -> dict[str, str]:
    f = job / ".hydra" / "overrides.yaml"
    return _parse_overrides(f.read_text().splitlines()) if f.is_file() else {}


@dataclass
class Job:
    """One job directory of a sweep: its overrides, and its metrics or why it has none."""

    path: Path
    overrides: dict[str, str]
    status: str                  # "completed", "failed" or "unfinished"
    metrics: dict | None = None
    error: str = ""


# A job directory holds one of these (the log: Hydra opens RUN_DIR/<job name>.log at the start).
_MARKERS = ("metrics.json", "failed.json", ".hydra/overrides.yaml", "last.pt", "*.log")
_LOG_ERROR = re.compile(r"\]\[(?:ERROR|CRITICAL)\] - (.*)$")


def _job_number(path: Path, root: Path) -> tuple:
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in path.relative_to(root).parts)


def _last_log_error(job: Path) -> str:
    found = ""
    for log in sorted(job.glob("*.log")):
        for line in log.read_text(errors="replace").splitlines():
            m = _LOG_ERROR.search(line)
            if m:
                found = m.group(1).strip()
    return found


def _load_job(d: Path) -> Job:
    metrics, failed = d / "metrics.json", d / "failed.json"
    # A rerun that completed after a recorded failure leaves a metrics.json newer than failed.json.
    if metrics.is_file() and not (failed.is_file() and failed.stat().st_mtime_ns > metrics.stat().st_mtime_ns):
        try:
            return Job(d, _overrides(d), "completed", json.loads(metrics.read_text()))
        except (OSError, ValueError) as e:
            return Job(d, _overrides(d), "failed", error=f"unreadable metrics.json: {e}")
    if failed.is_file():
        try:
            rec = json.loads(failed.read_text())
            over = _parse_overrides(rec.get("overrides") or []) or _overrides(d)
            return Job(d, over, "failed", error=f"{rec.get('error', 'error')}: {rec.get('message', '')}")
        except (OSError, ValueError, AttributeError) as e:
            return Job(d, _overrides(d), "failed", error=f"unreadable failed.json: {e}")
    error = _last_log_error(d) or ("no metrics.json: still running, or stopped without an error (killed, "
                                   "timed out)" + ("; a rerun resumes from its last.pt" if (d / "last.pt").is_file()
                                                   else ""))
    return Job(d, _overrides(d), "unfinished", error=error)


def find_jobs(sweep_dir: Path) -> list[Job]:
    """Every job directory under `sweep_dir` (itself included), in job-number order.

    Hidden directories (.submitit, .hydra) are not jobs; a directory is a job when it holds a
    metrics.json, failed.json, .hydra/overrides.yaml, last.pt or a log file.
    """
    sweep_dir = Path(sweep_dir)
    dirs = set()
    for pattern in _MARKERS:
        for f in sweep_dir.glob(f"**/{pattern}"):
            d = f.parents[pattern.count("/")]
            if f.is_file() and not any(p.startswith(".") for p in d.relative_to(sweep_dir).parts):
                dirs.add(d)
    return [_load_job(d) for d in sorted(dirs, key=lambda d: _job_number(d, sweep_dir))]


def load_jobs(sweep_dir: Path) -> list[tuple[dict[str, str], dict]]:
    """(overrides, metrics) for every completed job under `sweep_dir` (one holding a metrics.json)."""
    jobs = [(j.overrides, j.metrics) for j in find_jobs(sweep_dir) if j.status == "completed"]
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


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def failures_to_markdown(jobs: list[Job], sweep_dir: Path) -> str:
    """The jobs without metrics: job, status, the overrides that vary across the sweep, error."""
    known = [j.overrides for j in jobs if j.overrides]       # a job killed at its start may have none
    keys = sorted({k for o in known for k in o})
    varying = [k for k in keys if len({o.get(k) for o in known}) > 1]
    bad = [j for j in jobs if j.status != "completed"]
    lines = [f"Jobs without metrics ({len(bad)} of {len(jobs)})", "", "| job | status | overrides | error |",
             "|---|---|---|---|"]
    for j in bad:
        shown = [k for k in (varying or keys) if k in j.overrides]
        over = " ".join(f"{k}={j.overrides[k]}" for k in shown)
        name = j.path.relative_to(sweep_dir).as_posix()
        lines.append(f"| {_cell(name)} | {j.status} | {_cell(over)} | {_cell(j.error)} |")
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
    found = find_jobs(a.sweep_dir)
    if not found:
        p.error(f"no job directories under {a.sweep_dir} (none holds a metrics.json, failed.json, "
                ".hydra/overrides.yaml, last.pt or log file)")
    jobs = [(j.overrides, j.metrics) for j in found if j.status == "completed"]
    swept, rows = summarize(jobs, a.metrics) if jobs else ([], [])
    md = to_markdown(swept, rows, a.metrics) if jobs else "No completed job.\n"
    for spec in a.compare:
        key, _, values = spec.partition("=")
        pair = values.split(",")
        if not key or len(pair) != 2:
            p.error(f"--compare {spec!r}: expected KEY=A,B")
        try:
            md += "\n" + compare_to_markdown(key, *pair, *compare(jobs, key, *pair, a.metrics), a.metrics)
        except ValueError as e:
            p.error(f"--compare {spec}: {e}")
    if len(jobs) < len(found):
        md += "\n" + failures_to_markdown(found, a.sweep_dir)
    prefix = a.out or a.sweep_dir / "summary"
    Path(f"{prefix}.md").write_text(md)
    Path(f"{prefix}.csv").write_text(to_csv(swept, rows, a.metrics))
    plotted = bool(jobs) and plot_against_m(swept, rows, a.metrics[0], Path(f"{prefix}.png"))
    counts = {s: sum(j.status == s for j in found) for s in ("completed", "failed", "unfinished")}
    print(md)
    print(f"{len(found)} jobs: " + ", ".join(f"{n} {s}" for s, n in counts.items()))
    print(f"wrote {prefix}.md, {prefix}.csv" + (f", {prefix}.png" if plotted else ""))


if __name__ == "__main__":
    main()
