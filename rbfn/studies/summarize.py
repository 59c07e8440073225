"""Summarize a Hydra multirun: one row per swept setting, mean +- std over seeds.

    python -m rbfn.studies.summarize SWEEP_DIR [--metrics KEY ...] [--out PREFIX] [--compare KEY=A,B ...] [--force]

Reads every job's metrics.json and .hydra/overrides.yaml under SWEEP_DIR, groups the jobs by the
overrides that vary across the sweep (all but `seed`), prints a Markdown table and writes
SWEEP_DIR/summary.md, summary.csv and, when `rbfn.num_centers` is swept, summary.png (error
against M, one line per other setting). `--compare centers=aco,kmeans_refine` adds a paired
table: for jobs that differ only in that key (same seed, so the same data), A - B per metric
(mean +- std over the pairs), the mean ratio A / B and how many pairs A wins (lower is better).

Jobs without a metrics.json are listed after the table with their error: "failed" when the job
recorded one in failed.json (train.py does so in a multirun), "unfinished" otherwise (running,
or killed or timed out; the last ERROR line of its log's last MiB, if any, is shown). So are
"malformed" jobs, whose metrics.json is not a JSON object (NaN and Infinity are not JSON), holds
something other than a finite number under a summarized metric (null is a blank cell: train.py
writes it where a metric does not apply), is no regular file or larger than MAX_READ_BYTES (never
read), or whose overrides cannot be read; "unreadable" directories (they cannot be listed); and
the jobs the sweep's multirun.yaml lists without a directory (`find_jobs`: "failed" where a later
job started, else "missing"). They are left out of the tables, and counted and named.

A bad argument (a SWEEP_DIR without jobs or that cannot be read, a metric no job has, a --compare
key that is not swept or values it does not take, an output that is a directory or write-protected
without --force) is a one-line error, exit status 2, and nothing is written. The outputs are
written all or none: each to a temporary file beside it, renamed over the old one once every
output is written; an earlier summary.png this summary does not draw is removed with them.

Why one module of over 500 lines: it is one command, from reading a sweep's jobs and telling
their failures apart to the tables, the figure and writing them all or none.
"""

from __future__ import annotations

import argparse
import csv
import difflib
import errno
import io
import json
import math
import os
import re
import stat
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, cast

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from yaml import YAMLError  # type: ignore[import-untyped]

from ..files import mode_kind, unwritable, write_files
from ..memory import size_text
from ..scripts import fail

__all__ = ["Job", "SweepList", "compare", "find_jobs", "load_jobs", "main", "summarize", "sweep_list"]

DEFAULT_METRICS = (
    "test_pos_err_mm_median",
    "test_pos_err_mm_p95",
    "test_pos_err_mm_max",
    "test_pos_err_mm_median_float32",
    "select_seconds",
    "train_seconds",
)


MAX_READ_BYTES = 64 << 20
"""The most read of a job's metrics.json, failed.json or overrides.yaml, or of the sweep's
multirun.yaml (they hold kilobytes): a larger file is named as unreadable, never read."""
LOG_TAIL_BYTES = 1 << 20  # the end of a job's log searched for its last error line


def _read(path: Path, limit: int = MAX_READ_BYTES, tail: bool = False) -> bytes:
    """The bytes of the regular file `path`, at most `limit` of them (with `tail`, its last `limit`
    bytes); else OSError saying why: it cannot be opened, is no regular file (a directory, a FIFO
    or a device is never read or waited on), or holds more than `limit` bytes."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO opens without waiting for a writer
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, "Is a directory")
        if not stat.S_ISREG(st.st_mode):
            raise OSError(errno.EINVAL, f"it is {mode_kind(st.st_mode)}, not a regular file; not read")
        if st.st_size > limit:
            if not tail:
                raise OSError(errno.EFBIG, f"it holds {size_text(st.st_size)}, more than {size_text(limit)}; not read")
            os.lseek(fd, st.st_size - limit, os.SEEK_SET)
        data = bytearray()
        while len(data) <= limit and (chunk := os.read(fd, limit + 1 - len(data))):
            data += chunk
    finally:
        os.close(fd)
    if len(data) > limit:  # grown since
        if not tail:
            raise OSError(errno.EFBIG, f"it holds more than {size_text(limit)}; not read")
        del data[:-limit]
    return bytes(data)


def _why(e: OSError) -> str:
    return str(e.strerror or e)


def _parse_overrides(lines) -> dict[str, str]:
    out = {}
    for line in lines:
        line = str(line).strip().removeprefix("- ").strip().strip("'\"")
        if "=" in line:
            k, v = line.split("=", 1)
            out[k] = v
    return out


def _overrides(job: Path) -> tuple[dict[str, str], str]:
    """The job's overrides from .hydra/overrides.yaml ({} without one), and why it could not be read ('')."""
    f = job / ".hydra" / "overrides.yaml"
    if not os.path.lexists(f):
        return {}, ""
    try:
        return _parse_overrides(_read(f).decode(errors="replace").splitlines()), ""
    except OSError as e:
        return {}, f".hydra/overrides.yaml cannot be read: {_why(e)}"


@dataclass
class Job:
    """One job of a sweep: its overrides, and its metrics or why it has none."""

    path: Path
    overrides: dict[str, str]
    status: str  # one of STATUSES
    metrics: dict | None = None
    error: str = ""


# Summarized, then the ways a job is left out: "failed" (its failed.json, or its directory gone
# although a later job of the sweep started), "unfinished" (running, killed, timed out),
# "malformed" (its metrics.json or overrides cannot be used), "missing" (the sweep lists it, it
# has no directory: not started, or failed leaving no record), "unreadable" (a directory that
# cannot be listed, or a job's path that is no directory).
STATUSES = ("completed", "failed", "unfinished", "malformed", "missing", "unreadable")

# A job directory holds one of these (the log: Hydra opens RUN_DIR/<job name>.log at the start).
_MARKERS = ("metrics.json", "failed.json", "last.pt")
_LOG_ERROR = re.compile(r"\]\[(?:ERROR|CRITICAL)\] - (.*)$")


def _job_number(path: Path, root: Path) -> tuple:
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in path.relative_to(root).parts)


def _last_log_error(job: Path) -> tuple[str, str]:
    """The last ERROR line of the job's logs (each searched in its last LOG_TAIL_BYTES), and the
    logs that could not be read ('' when all could)."""
    found, unreadable = "", []
    for log in sorted(job.glob("*.log")):
        try:
            text = _read(log, LOG_TAIL_BYTES, tail=True).decode(errors="replace")
        except OSError as e:
            unreadable.append(f"{log.name} cannot be read: {_why(e)}")
            continue
        for line in text.splitlines():
            m = _LOG_ERROR.search(line)
            if m:
                found = m.group(1).strip()
    return found, "; ".join(unreadable)


def _mtime(path: Path) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return -1


def _load_job(d: Path) -> Job:
    metrics, failed = d / "metrics.json", d / "failed.json"
    over, over_error = _overrides(d)

    def job(status: str, error: str = "", got: dict | None = None, overrides: dict | None = None) -> Job:
        if over_error:
            error = f"{error}; {over_error}" if error else over_error
        return Job(d, overrides or over, status, got, error)

    # A rerun that completed after a recorded failure leaves a metrics.json newer than failed.json.
    if os.path.lexists(metrics) and not (os.path.lexists(failed) and _mtime(failed) > _mtime(metrics)):
        try:
            got = json.loads(_read(metrics), parse_constant=_not_json)
        except OSError as e:
            return job("malformed", f"metrics.json cannot be read: {_why(e)}")
        except ValueError as e:
            return job("malformed", f"metrics.json is not valid JSON: {e}")
        if not isinstance(got, dict):
            return job("malformed", f"metrics.json holds a JSON {_json_type(got)}, not an object of metrics")
        if over_error:  # its setting unknown: it belongs in no row
            return job("malformed", "its overrides are unknown")
        return job("completed", got=got)
    if os.path.lexists(failed):
        try:
            rec = json.loads(_read(failed))
        except (OSError, ValueError) as e:
            return job("failed", f"unreadable failed.json: {_why(e) if isinstance(e, OSError) else e}")
        if not isinstance(rec, dict):
            return job("failed", f"unreadable failed.json: a JSON {_json_type(rec)}, not an object")
        recorded = _parse_overrides(rec["overrides"]) if isinstance(rec.get("overrides"), list) else {}
        return job("failed", f"{rec.get('error', 'error')}: {rec.get('message', '')}", overrides=recorded)
    logged, bad_logs = _last_log_error(d)
    error = logged or (
        "no metrics.json: still running, or stopped without an error (killed, "
        "timed out)" + ("; a rerun resumes from its last.pt" if (d / "last.pt").is_file() else "")
    )
    return job("unfinished", f"{error}; {bad_logs}" if bad_logs else error)


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


def _walk(sweep_dir: Path) -> tuple[list[Path], list[Job]]:
    """The job directories under `sweep_dir` (itself included) and, as "unreadable" jobs, the
    directories that could not be listed. Hidden directories (.submitit, .hydra) are not jobs, and
    symbolic links to directories are not followed."""
    dirs, unreadable, todo = [], [], [sweep_dir]
    while todo:
        d = todo.pop()
        try:
            with os.scandir(d) as it:
                entries = list(it)
        except OSError as e:
            if d == sweep_dir:
                raise
            unreadable.append(Job(d, {}, "unreadable", error=f"the directory cannot be read: {_why(e)}"))
            continue
        names = {e.name for e in entries}
        if (
            names.intersection(_MARKERS)
            or any(n.endswith(".log") for n in names)
            or os.path.lexists(d / ".hydra" / "overrides.yaml")
        ):
            dirs.append(d)
        todo += [Path(e.path) for e in entries if not e.name.startswith(".") and e.is_dir(follow_symlinks=False)]
    return dirs, unreadable


class SweepList(NamedTuple):
    """What a multirun's multirun.yaml says of its jobs: each job number's overrides (None where
    unknown), whether its launcher starts them in order, and why no list could be made ('')."""

    overrides: list[dict[str, str]] | None
    in_order: bool
    note: str


def sweep_list(sweep_dir: Path) -> SweepList:
    """The jobs of the Hydra multirun in `sweep_dir`, from its multirun.yaml (which Hydra writes
    before the first job starts): the basic sweeper's product of the swept values, in job-number
    order, or a sweeper's n_trials jobs (Optuna's; their overrides unknown). Job N's directory is
    SWEEP_DIR/N (hydra.sweep.subdir=${hydra.job.num}, the default)."""
    path = Path(sweep_dir) / "multirun.yaml"
    if not os.path.lexists(path):
        return SweepList(None, True, "")
    cannot = "jobs without a directory cannot be counted"
    try:
        cfg: Any = OmegaConf.to_container(OmegaConf.create(_read(path).decode(errors="replace")), resolve=False)
        hydra = cfg["hydra"]
        subdir, sweeper, launcher = hydra["sweep"]["subdir"], hydra["sweeper"], hydra.get("launcher") or {}
        task = list(hydra["overrides"]["task"] or [])
    except OSError as e:
        return SweepList(None, True, f"multirun.yaml cannot be read: {_why(e)}; {cannot}")
    except (YAMLError, OmegaConfBaseException, TypeError, KeyError, AttributeError) as e:
        why = f"no {e}" if isinstance(e, KeyError) else " ".join(str(e).split())
        return SweepList(None, True, f"multirun.yaml is not a Hydra multirun's ({why}); {cannot}")
    in_order = "submitit" not in str(launcher.get("_target_", ""))  # a SLURM array starts its tasks in any order
    if subdir != "${hydra.job.num}":
        return SweepList(None, in_order, f"multirun.yaml: hydra.sweep.subdir={subdir} is not job numbers; {cannot}")
    if str(sweeper.get("_target_", "")).endswith(".BasicSweeper"):
        from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
        from hydra.core.override_parser.overrides_parser import OverridesParser

        params = [f"{k}={v}" for k, v in (sweeper.get("params") or {}).items()]
        try:
            parsed = OverridesParser.create().parse_overrides([*params, *map(str, task)])
            batches = BasicSweeper.split_arguments(parsed, None)
        except Exception as e:  # noqa: BLE001  (Hydra's parser raises its own types)
            return SweepList(None, in_order, f"multirun.yaml: its sweep cannot be listed ({e}); {cannot}")
        return SweepList([_parse_overrides(job) for batch in batches for job in batch], in_order, "")
    trials = sweeper.get("n_trials")
    if isinstance(trials, int) and not isinstance(trials, bool) and trials >= 0:
        return SweepList([{}] * trials, in_order, "")
    return SweepList(None, in_order, f"multirun.yaml: sweeper {sweeper.get('_target_')} lists no jobs; {cannot}")


def find_jobs(sweep_dir: Path, listed: SweepList | None = None) -> list[Job]:
    """Every job under `sweep_dir` (itself included), in job-number order; `listed`: the sweep's
    `sweep_list` where already read.

    A directory is a job when it holds a metrics.json, failed.json, .hydra/overrides.yaml, last.pt
    or a log file (whatever their kind: one that cannot be read is reported). The jobs the sweep's
    multirun.yaml lists (`sweep_list`) are all reported: one without a directory is "failed" where
    a later job of the sweep has started (its launcher starts them in order, so it started too,
    and its directory was tidied away: it failed before writing any result or its failed.json, as
    on a full disk), else "missing" (not started, or gone so); a listed directory without any of
    the files is "unfinished". OSError where `sweep_dir` itself cannot be listed.
    """
    sweep_dir = Path(sweep_dir)
    dirs, jobs = _walk(sweep_dir)
    jobs += [_load_job(d) for d in dirs]
    listed = sweep_list(sweep_dir) if listed is None else listed
    if listed.overrides is not None:
        known = {j.path for j in jobs}
        for j in jobs:  # a job killed at its start, or whose overrides cannot be read: the sweep's
            if not j.overrides and j.path.parent == sweep_dir and j.path.name.isdigit():
                j.overrides = (
                    dict(listed.overrides[int(j.path.name)]) if int(j.path.name) < len(listed.overrides) else {}
                )
        numbers = [int(p.name) for p in known if p.parent == sweep_dir and p.name.isdigit()]
        last = max(numbers, default=-1)
        for n, over in enumerate(listed.overrides):
            d = sweep_dir / str(n)
            if d in known:
                continue
            if os.path.islink(d) or (os.path.lexists(d) and not d.is_dir()):
                what = "a symbolic link (not followed)" if os.path.islink(d) else "not a directory"
                jobs.append(Job(d, over, "unreadable", error=f"the job's path is {what}"))
            elif d.is_dir():
                jobs.append(Job(d, over, "unfinished", error="its directory holds no record yet: starting, or stopped"))
            elif listed.in_order and n < last:
                error = (
                    "no job directory: it started (a later job did) and failed before writing any result or "
                    "its failed.json (a full disk?), so its directory was tidied away"
                )
                jobs.append(Job(d, over, "failed", error=error))
            else:
                error = (
                    "no job directory: not started (the sweep is running, or was stopped), or failed before "
                    "writing any result or its failed.json (a full disk?) and tidied away"
                )
                jobs.append(Job(d, over, "missing", error=error))
    return sorted(jobs, key=lambda j: _job_number(j.path, sweep_dir))


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


def _parser() -> argparse.ArgumentParser:
    """The command line of `main`."""
    p = argparse.ArgumentParser(
        prog="python -m rbfn.studies.summarize",
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
    return p


def main(argv: list[str] | None = None) -> None:
    p = _parser()
    a = p.parse_args(argv)
    if not a.sweep_dir.is_dir():
        fail(p, f"SWEEP_DIR {a.sweep_dir}: " + ("is not a directory" if a.sweep_dir.exists() else "no such directory"))
    try:
        listed = sweep_list(a.sweep_dir)
        found = find_jobs(a.sweep_dir, listed)
    except OSError as e:
        fail(p, f"SWEEP_DIR {a.sweep_dir}: cannot be read: {_why(e)}")
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
    if listed.note:
        md += f"\nNot counted: {listed.note}.\n"
    prefix = a.out or a.sweep_dir / "summary"
    files = {Path(f"{prefix}.md"): md.encode(), Path(f"{prefix}.csv"): to_csv(swept, rows, metrics).encode()}
    png = plot_against_m(swept, rows, metrics[0]) if jobs and metrics else None
    # A figure of an earlier summary that this one does not draw goes with the tables it belonged to
    # (a file or a link; a directory of that name is no figure of ours).
    old_png = Path(f"{prefix}.png")
    stale = [old_png] if png is None and (old_png.is_symlink() or old_png.is_file()) else []
    if png is not None:
        files[Path(f"{prefix}.png")] = png
    where = f"--out {a.out}" if a.out else f"SWEEP_DIR {a.sweep_dir} (the default output folder; --out picks another)"
    problem = unwritable([*files, *stale], a.force)
    if problem:
        fail(p, f"{where}: {problem}")
    try:
        write_files(files, remove=stale)
    except OSError as e:
        fail(p, f"{where}: cannot write the summary, nothing was replaced: {e}", status=1)
    counts = {s: sum(j.status == s for j in found) for s in STATUSES}
    print(md)
    print(f"{len(found)} jobs: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n or s in STATUSES[:3]))
    print("wrote " + ", ".join(map(str, files)) + "".join(f"; removed the stale {f}" for f in stale))


if __name__ == "__main__":
    main()
