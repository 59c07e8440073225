"""The benchmark suite: this framework against what users would pick instead, as ratios measured
in one process, with how cost grows.

    python -m bench [--quick] [--device cpu|cuda] [--threads 1] [--out bench/results]
    python bench/run.py --checkpoint outputs/train/DATE/TIME_ROBOT/checkpoint.pt
    python -m bench --merge a/benchmarks.json b/benchmarks.json --out DIR   # sections run apart

Writes `benchmarks.md` (tables, the performance targets met or missed, torch.profiler tables of the
slow paths of missed targets), `benchmarks.json` (every number, and the machine: platform, CPU
model, core counts, torch version, threads, device) and `scaling_<device>.png` into --out. Each
timing is the median of repeated runs after a warm-up; GPU work is synchronised. --threads sets
torch's threads and caps every other thread pool (scikit-learn/OpenMP, BLAS, onnxruntime,
MuJoCo) at the same number, so the rows compare like with like.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
import traceback
from pathlib import Path

if __package__ in (None, ""):  # `python bench/run.py`: import as a package
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    __package__ = "bench"

import torch

from bench import ik_throughput, scaling, select_time, simulator
from bench.timing import machine_info, profile_table

__all__ = ["SIZES", "run_suite", "targets", "to_markdown", "merge", "write_report", "main"]

# Problem sizes: `full` is the targets' grid; `quick` proves every path in about a minute.
SIZES = {
    "full": {
        "ik": {
            "batch": 100_000,
            "num_centers": 80,
            "refine": True,
            "repeats": 7,
            "pk_batch": 1000,
            "pk_retries": 10,
            "pk_repeats": 3,
            "compiled": True,
        },
        "select": {
            "ns": (2000, 10000, 50000),
            "ms": (40, 160),
            "max_full_s": 10.0,
            "always_full": ((10000, 40),),
            "probe": 2,
            "repeats": 3,
        },
        "sim": {
            "steps_for": {1: 1000, 64: 1000, 1024: 500, 8192: 200, 65536: 50},
            "repeats": 3,
            "scenario_s": 10.0,
            "scenario_repeats": 3,
            "compile_cap_s": 300.0,
            "scipy_s": 10.0,
            "mujoco_steps_for": {1: 1000, 8192: 20},
        },
        "scaling": {
            "ns": (1000, 2000, 5000, 10000, 20000),
            "ms": (10, 20, 40, 80, 160),
            "ks": (5, 10, 20, 40, 80),
            "repeats": 3,
        },
    },
    "quick": {
        "ik": {
            "batch": 10_000,
            "num_centers": 40,
            "refine": False,
            "repeats": 3,
            "pk_batch": 100,
            "pk_retries": 10,
            "pk_repeats": 1,
            "compiled": False,
        },
        "select": {"ns": (2000,), "ms": (40,), "max_full_s": 2.0, "always_full": (), "probe": 2, "repeats": 1},
        "sim": {
            "steps_for": {1: 100, 64: 100, 1024: 50},
            "repeats": 3,
            "scenario_s": 1.0,
            "scenario_repeats": 1,
            "compile_cap_s": 0.0,
            "scipy_s": 1.0,
            "mujoco_steps_for": {1: 200, 1024: 10},
        },
        "scaling": {"ns": (500, 1000, 2000), "ms": (10, 20, 40), "ks": (5, 10, 20), "repeats": 1},
    },
}
MUJOCO_INTEGRATORS = ("RK4", "Euler")


def run_suite(
    sizes: dict,
    device: str = "cpu",
    threads: int = 1,
    out: Path | None = None,
    checkpoint: Path | None = None,
    sections=("ik", "select", "sim", "scaling"),
    profile: bool = True,
) -> dict:
    """Run the sections with `sizes` (a SIZES entry); returns every number. With `out`, the JSON
    is rewritten as results come in, so a run cut short keeps what it measured (a section still
    running sits under "partial"); a section that fails is reported under "errors" and the
    others still run."""
    res = {
        "machine": machine_info(device, threads),
        "sizes": sizes,
        "sections": {},
        "partial": {},
        "errors": {},
        "seconds": {},
    }
    state = {}

    def save() -> None:
        if out is not None:
            (out / "benchmarks.json").write_text(json.dumps(res, indent=1, default=str))

    def partial(name: str, value) -> None:
        res["partial"][name] = value
        save()

    def ik(s: dict):
        state["net"] = ik_throughput.build_network(checkpoint, s["num_centers"], s["refine"], threads)
        compiled = s["compiled"] and (device != "cpu" or simulator.has_c_compiler())
        return ik_throughput.ik_rows(
            state["net"],
            s["batch"],
            device,
            s["repeats"],
            s["pk_batch"],
            s["pk_retries"],
            s["pk_repeats"],
            threads,
            onnx=s.get("onnx", True),
            compiled=compiled,
        )

    def select(s: dict):
        return select_time.select_rows(
            s["ns"],
            s["ms"],
            device,
            s["max_full_s"],
            s["always_full"],
            s["probe"],
            s["repeats"],
            on_row=lambda rows: partial("select", rows),
        )

    def sim(s: dict):
        r = {"steps": simulator.env_steps_rows(s["steps_for"], device, s["repeats"]), "scenario_s": s["scenario_s"]}
        partial("sim", r)
        r["scenario_eager_s"] = simulator.scenario_seconds(device, s["scenario_repeats"], s["scenario_s"])
        r["scipy"] = simulator.scipy_row(s["scipy_s"])
        r["numpy_rk4"] = simulator.numpy_rk4_row(s["scipy_s"])
        r["mujoco"] = {
            i: simulator.mujoco_rows(s["mujoco_steps_for"], threads, s["repeats"], i) for i in MUJOCO_INTEGRATORS
        }
        partial("sim", r)
        cap = s["compile_cap_s"]
        r["scenario_compiled"] = (
            simulator.compiled_scenario(device, threads, cap, s["scenario_s"]) if cap > 0 else {"status": "skipped"}
        )
        r["scenario_aot"] = (
            simulator.aot_scenario(device, threads, cap, s["scenario_s"]) if cap > 0 else {"status": "skipped"}
        )
        return r

    def scale(s: dict):
        steps = (res["sections"].get("sim") or {}).get("steps") or simulator.env_steps_rows(
            sizes["sim"]["steps_for"], device, 1
        )
        return scaling.scaling_curves(s["ns"], s["ms"], s["ks"], steps, device, repeats=s["repeats"])

    for name, fn in (("ik", ik), ("select", select), ("sim", sim), ("scaling", scale)):
        if name not in sections:
            continue
        t0 = time.perf_counter()
        try:
            res["sections"][name] = fn(sizes[name])
        except Exception:  # noqa: BLE001 - report it, keep measuring the other sections
            res["errors"][name] = traceback.format_exc()[-3000:]
            print(res["errors"][name], file=sys.stderr)
        res["partial"].pop(name, None)
        res["seconds"][name] = time.perf_counter() - t0
        save()
    res["targets"] = targets(res)
    if profile:
        t0 = time.perf_counter()
        res["profiles"] = profiles(res, sizes, device, state.get("net"))
        res["seconds"]["profiles"] = time.perf_counter() - t0
        save()
    return res


def _row(rows: list[dict], **match) -> dict | None:
    return next((r for r in rows if all(r.get(k) == v for k, v in match.items())), None)


def targets(res: dict) -> list[dict]:
    """The performance targets (and the simulator's B = 8192 throughput) against the measured numbers."""
    out, sec = [], res["sections"]

    def add(key: str, name: str, value, goal: str, met) -> None:
        out.append(
            {"key": key, "target": name, "measured": value, "goal": goal, "met": None if met is None else bool(met)}
        )

    ik = sec.get("ik", [])
    same = {r["device"] for r in ik if r["method"].startswith("closed")}
    ik = [r for r in ik if r["device"] in same]  # ratios across devices are no target's
    for r in ik:
        if r["method"].startswith("RBF network") and r["queries_per_s"] and "flag" not in r["method"]:
            add(
                "ik_closed",
                f"IK: {r['method']} vs closed form, batch {r['batch']}",
                f"{r['x_closed_form']:.3g}x the closed form's queries/s",
                ">= 0.5x",
                r["x_closed_form"] >= 0.5,
            )
    for r in ik:
        if r["method"].startswith("RBF network") and r["queries_per_s"] and r["x_pk_iterative"]:
            add(
                "ik_pk",
                f"IK: {r['method']} vs pytorch-kinematics iterative IK",
                f"{r['x_pk_iterative']:.3g}x",
                ">= 1000x",
                r["x_pk_iterative"] >= 1000,
            )
    for r in sec.get("select", []):
        if r["N"] == 10000 and r["M"] == 40 and r["method"].startswith("aco"):
            add(
                "aco_kmeans",
                f"selection: {r['method']} at N = 10000, M = 40 vs KMeans",
                f"{r['x_kmeans']:.3g}x KMeans' time ({r['seconds']:.3g} s)",
                "<= 10x",
                r["x_kmeans"] <= 10,
            )
    sim = sec.get("sim")
    if sim:
        ours = _row(sim["steps"], B=8192)
        rates = {i: _row(rows, B=8192) for i, rows in sim["mujoco"].items()}
        rates = {i: r["env_steps_per_s"] for i, r in rates.items() if r}
        if ours and rates:
            best = max(rates, key=rates.get)
            add(
                "sim_mujoco",
                "simulator vs MuJoCo rollout at B = 8192 (its faster integrator)",
                f"{ours['env_steps_per_s'] / rates[best]:.3g}x ({best})",
                ">= 10x",
                ours["env_steps_per_s"] / rates[best] >= 10,
            )
        else:
            add(
                "sim_mujoco",
                "simulator vs MuJoCo rollout at B = 8192",
                "B = 8192 not run" if any(sim["mujoco"].values()) else "mujoco not installed",
                ">= 10x",
                None,
            )
        if ours:
            add(
                "sim_4m",
                "simulator env-steps/s at B = 8192",
                f"{ours['env_steps_per_s']:.3g}",
                ">= 4e6",
                ours["env_steps_per_s"] >= 4e6,
            )
        d = sim["scenario_s"]
        add(
            "scenario",
            f"one {d:g} s scenario at B = 1, eager",
            f"{sim['scenario_eager_s']:.3g} s",
            f"< {d / 10:g} s",
            sim["scenario_eager_s"] < d / 10,
        )
        c = sim["scenario_compiled"]
        ok = c.get("status") == "ok"
        add(
            "scenario",
            f"one {d:g} s scenario at B = 1, torch.compile (compile time apart)",
            f"{c['seconds']:.3g} s (compile {c['compile_s']:.0f} s)" if ok else c["status"],
            f"< {d / 10:g} s",
            c["seconds"] < d / 10 if ok else None,
        )
        a = sim.get("scenario_aot", {})
        if a.get("status") == "ok":
            add(
                "scenario",
                f"one {d:g} s scenario at B = 1, aot (cached package, load included)",
                f"{a['cached_first_call_s']:.3g} s (built once in {a['build_s']:.0f} s)",
                f"< {d / 10:g} s",
                a["cached_first_call_s"] < d / 10,
            )
    return out


def profiles(res: dict, sizes: dict, device: str, net=None) -> dict:
    """torch.profiler tables (top ops by self CPU time) of the slow path of each missed target."""
    missed = {t["key"] for t in res["targets"] if t["met"] is False}
    out = {}
    if missed & {"ik_closed", "ik_pk"} and net is not None:
        batch = sizes["ik"]["batch"]
        net = copy.deepcopy(net).float().to(device).eval()
        x = ik_throughput.workspace_positions(batch)[1].to(device)
        with torch.inference_mode():
            net(x)
            out[f"RBF network forward, torch, batch {batch}"] = profile_table(lambda: net(x), device)
    if "aco_kmeans" in missed:
        obj = select_time.selection_objective(10000, device)
        for name in select_time.COLONIES:
            out[f"{name}, N = 10000, M = 40, 3 iterations"] = profile_table(
                lambda: select_time.time_aco(obj, name, 40, 3, device),  # noqa: B023 - called now
                device,
            )
    if missed & {"sim_mujoco", "sim_4m"}:
        run = simulator.closed_loop(8192, 0.02, device)
        run()
        out["closed loop, B = 8192, 20 steps"] = profile_table(run, device)
    if "scenario" in missed:
        # Few steps: the profiler's table of many small ops takes long to build.
        steps = round(min(0.05, sizes["sim"]["scenario_s"]) / simulator.DT)
        run = simulator.closed_loop(1, steps * simulator.DT, device)
        run()
        out[f"closed loop, B = 1, {steps} steps (eager)"] = profile_table(run, device)
    return out


def _g(v, digits: int = 3) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def _table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_g(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _md_ik(rows: list[dict]) -> list[str]:
    keys = (
        "method",
        "device",
        "batch",
        "threads",
        "queries_per_s",
        "x_closed_form",
        "x_pk_iterative",
        "median_err_mm",
        "note",
    )
    return [
        "## IK queries per second (float32)",
        "",
        _table(
            [
                "method",
                "device",
                "batch",
                "threads",
                "queries/s",
                "x closed form",
                "x pytorch-kinematics",
                "median FK error (mm)",
                "note",
            ],
            [[r.get(k) for k in keys] for r in rows],
        ),
        "",
    ]


def _md_select(rows: list[dict]) -> list[str]:
    keys = ("N", "M", "method", "device", "seconds", "x_kmeans", "iterations", "how")
    return [
        "## Centre selection time (NC_max = 100, 20 ants)",
        "",
        _table(
            ["N", "M", "method", "device", "seconds", "x KMeans", "iterations", "how"],
            [[r[k] for k in keys] for r in rows],
        ),
        "",
    ]


def _md_sim(s: dict) -> list[str]:
    def ratio(b: int, rate: float) -> float | None:  # this simulator's rate / another's
        ours = _row(s["steps"], B=b)
        return ours["env_steps_per_s"] / rate if ours else None

    rows = [
        ["rbfn.control.simulate (smc_obs, RK4)", r["device"], r["B"], r["steps"], r["env_steps_per_s"], None]
        for r in s["steps"]
    ]
    for integ, mrows in s["mujoco"].items():
        rows += [
            [
                f"MuJoCo {r['mujoco']} rollout ({integ}, open loop)",
                "cpu",
                r["B"],
                r["steps"],
                r["env_steps_per_s"],
                ratio(r["B"], r["env_steps_per_s"]),
            ]
            for r in mrows
        ]
    if not any(s["mujoco"].values()):
        rows.append(["MuJoCo rollout", "cpu", "—", "—", "not installed", None])
    sp, c = s["scipy"], s["scenario_compiled"]
    rows.append(
        [
            sp["method"],
            "cpu",
            1,
            f"{sp['duration']:g} s ({sp['nfev']} RHS calls)",
            sp["env_steps_per_s"],
            ratio(1, sp["env_steps_per_s"]),
        ]
    )
    compiled = (
        f"{c['seconds']:.3g} s after {c['compile_s']:.0f} s of compilation" if c.get("status") == "ok" else c["status"]
    )
    a = s.get("scenario_aot", {"status": "not run"})
    aot = (
        f"{a['cached_first_call_s']:.3g} s in a new process with the package cached (load and run; "
        f"{a['seconds']:.3g} s per further run), the package built once in {a['build_s']:.0f} s"
        if a.get("status") == "ok"
        else a["status"]
    )
    npy = s.get("numpy_rk4")
    npy = f"; a plain numpy RK4 loop (one environment, PD): {npy['seconds']:.3g} s" if npy else ""
    return [
        "## Closed-loop simulator (float32, dt = 1 ms, 10 kg payload)",
        "",
        _table(["method", "device", "B", "steps", "env-steps/s", "simulate / it (equal B)"], rows),
        "",
        f"One {s['scenario_s']:g} s scenario at B = 1 (payload 1-4 s of 10): eager "
        f"{s['scenario_eager_s']:.3g} s; torch.compile: {compiled}; aot: {aot}; scipy solve_ivp (one "
        f"environment, PD): {sp['seconds']:.3g} s{npy}.",
        "",
    ]


def _md_scaling(curves: dict, device: str) -> list[str]:
    rows = []
    for k, c in curves.items():
        p = f"{c['exponent']:.2f}"
        if "exponent_large_B" in c:
            p += f" ({c['exponent_large_B']:.2f} over the 3 largest B)"
        what = "one closed-loop step" if k == "B" else "one ACO iteration"
        rows.append([k, ", ".join(str(v) for v in c["x"]), what, c["fixed"], p])
    return [
        "## Scaling (time ~ x^p)",
        "",
        _table(["x", "values", "time of", "fixed", "exponent p"], rows),
        "",
        f"![scaling](scaling_{device.split(':')[0]}.png)",
        "",
    ]


def to_markdown(res: dict, command: str) -> str:
    """The report: machine, command, one table per section, targets, profiles."""
    m, sec = res["machine"], res["sections"]
    gpu = f", GPU {m['gpu']}" if m.get("gpu") else ""
    parts = [
        f"# Benchmarks ({m['device']}, {m['threads']} thread(s))",
        "",
        f"`{command}`",
        "",
        f"Machine: {m['cpu']}, {m['nproc']} CPUs ({m['usable_cpus']} usable by the run), {m['platform']}, "
        f"Python {m['python']}, torch {m['torch']}{gpu}; load average {m['load_average_1min']}.",
        "",
    ]
    parts += _md_ik(sec["ik"]) if "ik" in sec else []
    parts += _md_select(sec["select"]) if "select" in sec else []
    parts += _md_sim(sec["sim"]) if "sim" in sec else []
    parts += _md_scaling(sec["scaling"], m["device"]) if "scaling" in sec else []
    verdict = {True: "met", False: "missed", None: "—"}
    parts += [
        "## Targets",
        "",
        _table(
            ["target", "measured", "goal", "met"],
            [[t["target"], t["measured"], t["goal"], verdict[t["met"]]] for t in res["targets"]],
        ),
        "",
    ]
    for name, table in res.get("profiles", {}).items():
        parts += [f"### Profile: {name}", "", "```", table.rstrip(), "```", ""]
    for name, tb in res.get("errors", {}).items():
        parts += [f"### Section {name} failed", "", "```", tb.rstrip(), "```", ""]
    return "\n".join(parts)


def merge(results: list[dict]) -> dict:
    """One report from runs of separate sections (e.g. run side by side on separate pinned cores):
    sections and profiles of all, the first run's machine, targets recomputed."""
    res = {
        "machine": results[0]["machine"],
        "sections": {},
        "profiles": {},
        "errors": {},
        "seconds": {},
        "command": " ; ".join(r.get("command", "?") for r in results),
    }
    for r in results:
        for key in ("sections", "profiles", "errors", "seconds"):
            res[key].update(r.get(key, {}))
    res["targets"] = targets(res)
    return res


def write_report(res: dict, out: Path) -> None:
    """benchmarks.json, benchmarks.md and (with a scaling section) the scaling plot into `out`."""
    (out / "benchmarks.json").write_text(json.dumps(res, indent=1, default=str))
    (out / "benchmarks.md").write_text(to_markdown(res, res.get("command", "?")))
    m = res["machine"]
    if "scaling" in res["sections"]:
        scaling.plot_curves(
            res["sections"]["scaling"],
            out / f"scaling_{m['device'].split(':')[0]}.png",
            f"{m['cpu']}, {m['threads']} thread(s), device {m['device']}",
        )


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m bench", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes: every path in about a minute")
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    p.add_argument("--threads", type=int, default=1, help="torch and other thread pools (default 1)")
    p.add_argument("--out", type=Path, default=Path("bench/results"))
    p.add_argument("--checkpoint", type=Path, default=None, help="IK network to measure (default: train one)")
    p.add_argument("--sections", default="ik,select,sim,scaling", help="comma-separated subset")
    p.add_argument(
        "--compile-cap",
        type=float,
        default=None,
        metavar="SECONDS",
        help="cap on the torch.compile'd scenario's child process (0 skips it; default 300)",
    )
    p.add_argument("--no-profile", action="store_true", help="skip the profiles of missed targets")
    p.add_argument(
        "--merge",
        type=Path,
        nargs="+",
        metavar="JSON",
        help="run nothing: merge these benchmarks.json files into one report in --out",
    )
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    if a.merge:
        res = merge([json.loads(f.read_text()) for f in a.merge])
        write_report(res, a.out)
        return res
    if a.device.startswith("cuda") and not torch.cuda.is_available():
        p.error("--device cuda: no CUDA device is available")
    if a.threads < 1:
        p.error(f"--threads {a.threads} must be >= 1")
    torch.set_num_threads(a.threads)
    from threadpoolctl import threadpool_limits

    command = "python -m bench " + " ".join(argv if argv is not None else sys.argv[1:])
    sizes = copy.deepcopy(SIZES["quick" if a.quick else "full"])
    if a.compile_cap is not None:
        sizes["sim"]["compile_cap_s"] = a.compile_cap
    with threadpool_limits(a.threads):
        res = run_suite(sizes, a.device, a.threads, a.out, a.checkpoint, tuple(a.sections.split(",")), not a.no_profile)
    res["command"] = command
    write_report(res, a.out)
    print(to_markdown(res, command))
    return res


if __name__ == "__main__":
    main()
