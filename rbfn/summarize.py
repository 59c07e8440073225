"""Summarize a Hydra multirun: one row per swept setting, mean +- std over seeds.

    python -m rbfn.summarize SWEEP_DIR [--metrics KEY ...] [--out PREFIX] [--compare KEY=A,B ...] [--force]

Reads every job's metrics.json and .hydra/overrides.yaml under SWEEP_DIR, groups the jobs by the
overrides that vary across the sweep (all but `seed`), prints a Markdown table and writes
SWEEP_DIR/summary.md, summary.csv and, when `rbfn.num_centers` is swept, summary.png (error
against M, one line per other setting). `--compare centers=aco,kmeans_refine` adds a paired
table: for jobs that differ only in that key (same seed, so the same data), A - B per metric
(mean +- std over the pairs), the mean ratio A / B and how many pairs A wins (lower is better).

Jobs without a metrics.json are listed after the table with their error: "failed" when the job
recorded one in failed.json (train.py does so in a multirun), "unfinished" otherwise (running,
or killed or timed out; the last ERROR line of its log, if any, is shown). So are "malformed" jobs,
whose metrics.json is not a JSON object (NaN and Infinity are not JSON) or holds something other than
a finite number under a summarized metric (null is a blank cell: train.py writes it where a metric
does not apply); they are left out of the tables.

A bad argument (a SWEEP_DIR without jobs, a metric no job has, a --compare key that is not swept or
values it does not take, an output that is a directory or write-protected without --force) is a
one-line error, exit status 2, and nothing is written. The outputs are written all or none: each to
a temporary file beside it, renamed over the old one once every output is written.
"""

from __future__ import annotations

import argparse
import csv
import difflib
import io
import json
import math
import re
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import cast

from .files import unwritable, write_files
from .scripts import fail

__all__ = ["Job", "compare", "find_jobs", "load_jobs", "main", "summarize"]

DEFAULT_METRICS = (
    "test_pos_err_mm_median",
    "test_pos_err_mm_p95",
    "test_pos_err_mm_max",
    "test_pos_err_mm_median_float32",
    "select_seconds",
    "train_seconds",
)


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
    try:
        return _parse_overrides(f.read_text(errors="replace").splitlines())
    except OSError:
        return {}


@dataclass
class Job:
    """One job directory of a sweep: its overrides, and its metrics or why it has none."""

    path: Path
    overrides: dict[str, str]
    status: str  # "completed", "failed", "unfinished" or "malformed"
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
        try:
            text = log.read_text(errors="replace")
        except OSError:
            continue
        for line in text.splitlines():
            m = _LOG_ERROR.search(line)
            if m:
                found = m.group(1).strip()
    return found


def _load_job(d: Path) -> Job:
    metrics, failed = d / "metrics.json", d / "failed.json"
    # A rerun that completed after a recorded failure leaves a metrics.json newer than failed.json.
    if metrics.exists() and not (failed.is_file() and failed.stat().st_mtime_ns > metrics.stat().st_mtime_ns):
        try:
            got = json.loads(metrics.read_text(), parse_constant=_not_json)
        except OSError as e:
            return Job(d, _overrides(d), "malformed", error=f"metrics.json cannot be read: {e.strerror or e}")
        except ValueError as e:
            return Job(d, _overrides(d), "malformed", error=f"metrics.json is not valid JSON: {e}")
        if not isinstance(got, dict):
            return Job(
                d,
                _overrides(d),
                "malformed",
                error=f"metrics.json holds a JSON {_json_type(got)}, not an object of metrics",
            )
        return Job(d, _overrides(d), "completed", got)
    if failed.is_file():
        try:
            rec = json.loads(failed.read_text())
        except (OSError, ValueError) as e:
            return Job(d, _overrides(d), "failed", error=f"unreadable failed.json: {e}")
        if not isinstance(rec, dict):
            return Job(
                d, _overrides(d), "failed", error=f"unreadable failed.json: a JSON {_json_type(rec)}, not an object"
            )
        over = _parse_overrides(rec["overrides"]) if isinstance(rec.get("overrides"), list) else {}
        return Job(d, over or _overrides(d), "failed", error=f"{rec.get('error', 'error')}: {rec.get('message', '')}")
    error = _last_log_error(d) or (
        "no metrics.json: still running, or stopped without an error (killed, "
        "timed out)" + ("; a rerun resumes from its last.pt" if (d / "last.pt").is_file() else "")
    )
    return Job(d, _overrides(d), "unfinished", error=error)


def _not_json(token: str):
    raise ValueError(f"{token} is not a JSON number")


def _json_type(v) -> str:
    return {
        bool: "boolean",
        int: "number",
        float: "number",
        str: "string",
        list: "array",
        dict: "object",
        type(None): "null",
    }[type(v)]


def _is_number(v) -> bool:
    """A finite JSON number (bool is not one)."""
    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    except OverflowError:  # an int beyond float's range
        return False


def _bad_metric(metrics: dict, keys) -> str:
    """Why a job's `metrics` cannot be summarized under `keys` ('' when it can): a value that is
    neither a finite number nor null (absent and null values are blank cells)."""
    for k in keys:
        v = metrics.get(k)
        if v is None or _is_number(v):
            continue
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            return f"metrics.json: {k} is a number beyond float's range"
        return f"metrics.json: {k} is a JSON {_json_type(v)} ({json.dumps(v)[:60]}), not a number"
    return ""


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
    jobs = [(j.overrides, cast(dict, j.metrics)) for j in find_jobs(sweep_dir) if j.status == "completed"]
    if not jobs:
        raise FileNotFoundError(f"no metrics.json under {sweep_dir}")
    return jobs


def _num(v: str):
    try:
        return float(v)
    except ValueError:
        return v


def _order(value: str) -> tuple:
    """Sort key of an override's value: numbers by value, after the words."""
    return isinstance(_num(value), float), _num(value)


def _order_all(values: tuple) -> tuple:
    return tuple(map(_order, values))


def summarize(jobs, metrics=DEFAULT_METRICS, ignore=("seed",)):
    """(group keys, rows): each row = (group values, n, {metric: (mean, std)})."""
    keys = sorted({k for o, _ in jobs for k in o})
    swept = [k for k in keys if k not in ignore and len({o.get(k) for o, _ in jobs}) > 1]
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for o, m in jobs:
        groups[tuple(o.get(k, "") for k in swept)].append(m)
    rows = []
    for g in sorted(groups, key=_order_all):
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


def compare(jobs, key: str, a: str, b: str, metrics=DEFAULT_METRICS, ignore=("seed",)) -> tuple[list[str], list]:
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
    for g in sorted(groups, key=_order_all):
        stats = {}
        for metric in metrics:
            pairs = [
                (float(ma[metric]), float(mb[metric]))
                for ma, mb in groups[g]
                if ma.get(metric) is not None and mb.get(metric) is not None
            ]
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
        cells = [*map(_cell, g), str(n)]
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
        cells = [*map(_cell, g), str(n)] + [
            f"{stats[k][0]:.4g} ± {stats[k][1]:.2g}" if k in stats else "" for k in metrics
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def failures_to_markdown(jobs: list[Job], sweep_dir: Path) -> str:
    """The jobs left out of the tables: job, status, the overrides that vary across the sweep, error."""
    known = [j.overrides for j in jobs if j.overrides]  # a job killed at its start may have none
    keys = sorted({k for o in known for k in o})
    varying = [k for k in keys if len({o.get(k) for o in known}) > 1]
    bad = [j for j in jobs if j.status != "completed"]
    lines = [
        f"Jobs not summarized ({len(bad)} of {len(jobs)})",
        "",
        "| job | status | overrides | error |",
        "|---|---|---|---|",
    ]
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


def plot_against_m(swept, rows, metric: str) -> bytes | None:
    """Error against M (log-log), one line per setting of the other swept keys, as PNG bytes; None
    when `rbfn.num_centers` is not swept or no group has a positive number of centres and `metric`."""
    if "rbfn.num_centers" not in swept:
        return None
    from matplotlib.figure import Figure  # object API: no pyplot, no backend switch

    i_m = swept.index("rbfn.num_centers")
    lines: dict[tuple, list] = defaultdict(list)
    for g, _, stats in rows:
        m = _num(g[i_m])
        if metric in stats and isinstance(m, float) and m > 0:
            lines[g[:i_m] + g[i_m + 1 :]].append((m, *stats[metric]))
    if not lines:
        return None
    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.subplots()
    for label, pts in sorted(lines.items()):
        pts.sort()
        ax.errorbar(
            [p[0] for p in pts],
            [p[1] for p in pts],
            yerr=[p[2] for p in pts],
            marker="o",
            capsize=3,
            label=", ".join(label) or "all",
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("M (hidden nodes)")
    ax.set_ylabel(metric)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    return buf.getvalue()


def _did_you_mean(word: str, known) -> str:
    close = difflib.get_close_matches(word, list(known), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


def _metrics(p: argparse.ArgumentParser, asked: list[str] | None, jobs: list[Job]) -> list[str]:
    """The metrics to summarize: those asked for (each a number in some job, else a usage error
    naming the numbers the jobs hold), or the default ones that some job holds."""
    if asked is None:
        held = {k for j in jobs for k in cast(dict, j.metrics)}  # completed jobs: metrics read
        return [k for k in DEFAULT_METRICS if k in held] if jobs else list(DEFAULT_METRICS)
    asked = list(dict.fromkeys(asked))
    numeric = sorted({k for j in jobs for k, v in cast(dict, j.metrics).items() if _is_number(v)})
    unknown = [k for k in asked if k not in numeric]
    if jobs and unknown:
        names = ", ".join(repr(k) + _did_you_mean(repr(k), map(repr, numeric)) for k in unknown)
        fail(
            p,
            f"--metrics: no number named {names} in any job's metrics.json; the jobs' numeric metrics are: "
            f"{', '.join(numeric) or 'none'}",
        )
    return asked


def _compare_pair(p: argparse.ArgumentParser, spec: str, jobs) -> tuple[str, str, str]:
    """KEY, A, B of a --compare KEY=A,B whose KEY varies across `jobs` and takes the values A and B
    (which may hold commas); else a usage error naming the swept keys or KEY's values."""
    key, eq, values = spec.partition("=")
    if not key or not eq:
        fail(p, f"--compare {spec}: expected KEY=A,B")
    taken: dict[str, set] = defaultdict(set)
    for o, _ in jobs:
        for k, v in o.items():
            taken[k].add(v)
    swept = sorted(k for k in taken if len({o.get(k) for o, _ in jobs}) > 1)
    if key not in swept:
        fail(
            p,
            f"--compare {spec}: {key} is not a swept override{_did_you_mean(key, swept)}; swept: "
            f"{', '.join(swept) or 'none'}" + ("" if jobs else " (no completed job)"),
        )
    pairs = [(values[:i], values[i + 1 :]) for i, c in enumerate(values) if c == ","]
    pair = next((ab for ab in pairs if ab[0] != ab[1] and set(ab) <= taken[key]), None)
    if pair is None:
        fail(
            p,
            f"--compare {spec}: expected {key}=A,B with A and B two different values of {key}: "
            f"{', '.join(sorted(taken[key], key=_order))}",
        )
    return key, *pair


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m rbfn.summarize",
        description=__doc__.splitlines()[0],
        epilog="Jobs whose metrics.json is damaged are listed as malformed and left out of the tables. A bad "
        "argument is an error (exit status 2) that writes nothing; the outputs are replaced all together "
        "or not at all (exit status 1 if writing them fails).",
    )
    p.add_argument(
        "sweep_dir",
        type=Path,
        metavar="SWEEP_DIR",
        help="a Hydra multirun directory (hydra.sweep.dir), one subdirectory per job",
    )
    p.add_argument(
        "--metrics",
        nargs="+",
        default=None,
        metavar="KEY",
        help="numeric keys of the jobs' metrics.json to tabulate (default: whichever of "
        f"{', '.join(DEFAULT_METRICS)} the jobs have)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="PREFIX",
        help="write PREFIX.md, PREFIX.csv and, when rbfn.num_centers is swept, PREFIX.png (default SWEEP_DIR/summary)",
    )
    p.add_argument(
        "--compare",
        action="append",
        default=[],
        metavar="KEY=A,B",
        help="paired table of KEY=A against KEY=B over jobs equal in every other override "
        "(KEY a swept override; repeatable)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write even over write-protected outputs or into a write-protected directory (replaced "
        "files keep their mode)",
    )
    a = p.parse_args(argv)
    if not a.sweep_dir.is_dir():
        fail(p, f"SWEEP_DIR {a.sweep_dir}: " + ("is not a directory" if a.sweep_dir.exists() else "no such directory"))
    found = find_jobs(a.sweep_dir)
    if not found:
        fail(
            p,
            f"SWEEP_DIR {a.sweep_dir}: no job directories under it (none holds a metrics.json, failed.json, "
            ".hydra/overrides.yaml, last.pt or log file)",
        )
    metrics = _metrics(p, a.metrics, [j for j in found if j.status == "completed"])
    for j in found:
        if j.status == "completed" and _bad_metric(cast(dict, j.metrics), metrics):
            j.status, j.error = "malformed", _bad_metric(cast(dict, j.metrics), metrics)
    jobs = [(j.overrides, cast(dict, j.metrics)) for j in found if j.status == "completed"]
    swept, rows = summarize(jobs, metrics) if jobs else ([], [])
    md = to_markdown(swept, rows, metrics) if jobs else "No completed job.\n"
    for spec in a.compare:
        key, x, y = _compare_pair(p, spec, jobs)
        try:
            md += "\n" + compare_to_markdown(key, x, y, *compare(jobs, key, x, y, metrics), metrics)
        except ValueError as e:
            fail(p, f"--compare {spec}: {e}")
    if len(jobs) < len(found):
        md += "\n" + failures_to_markdown(found, a.sweep_dir)
    prefix = a.out or a.sweep_dir / "summary"
    files = {Path(f"{prefix}.md"): md.encode(), Path(f"{prefix}.csv"): to_csv(swept, rows, metrics).encode()}
    png = plot_against_m(swept, rows, metrics[0]) if jobs and metrics else None
    if png is not None:
        files[Path(f"{prefix}.png")] = png
    where = f"--out {a.out}" if a.out else f"SWEEP_DIR {a.sweep_dir} (the default output folder; --out picks another)"
    problem = unwritable(files, a.force)
    if problem:
        fail(p, f"{where}: {problem}")
    try:
        write_files(files)
    except OSError as e:
        fail(p, f"{where}: cannot write the summary, nothing was replaced: {e}", status=1)
    counts = {s: sum(j.status == s for j in found) for s in ("completed", "failed", "unfinished", "malformed")}
    print(md)
    print(f"{len(found)} jobs: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n or s != "malformed"))
    print("wrote " + ", ".join(map(str, files)))


if __name__ == "__main__":
    main()
