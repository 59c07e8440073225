"""The benchmark suite runs end to end at tiny sizes and writes its report (no timing asserted)."""

import json

import pytest
import torch

from bench.run import merge, run_suite, targets, to_markdown, write_report
from bench.timing import fit_exponent

from .conftest import compose_config

TINY = {
    "ik": {
        "batch": 500,
        "num_centers": 10,
        "refine": False,
        "repeats": 1,
        "pk_batch": 10,
        "pk_retries": 2,
        "pk_repeats": 1,
        "compiled": False,
        "onnx": False,
    },
    "select": {"ns": (300, 400), "ms": (5,), "max_full_s": 0.0, "always_full": ((300, 5),), "probe": 2, "repeats": 1},
    "sim": {
        "steps_for": {1: 5, 8: 5},
        "repeats": 1,
        "scenario_s": 0.02,
        "scenario_repeats": 1,
        "compile_cap_s": 0.0,
        "scipy_s": 0.05,
        "mujoco_steps_for": {1: 5, 8: 2},
    },
    "scaling": {"ns": (200, 300), "ms": (3, 5), "ks": (2, 4), "repeats": 1},
}


def test_exponent_fit_recovers_a_power_law():
    assert fit_exponent([1, 10, 100], [2.0, 200.0, 20000.0]) == pytest.approx(2.0)


def test_suite_runs_at_tiny_sizes(tmp_path):
    res = run_suite(TINY, "cpu", 1, tmp_path)
    ik = {r["method"].split(" (")[0].split(",")[0]: r for r in res["sections"]["ik"]}
    assert ik["closed-form SCARA IK"]["median_err_mm"] < 1e-2  # exact up to float32 rounding
    assert ik["pytorch-kinematics PseudoInverseIK"]["median_err_mm"] < 1.0
    assert all(r["queries_per_s"] is None or r["queries_per_s"] > 0 for r in ik.values())
    sel = res["sections"]["select"]
    assert {r["how"].split(":")[0] for r in sel} == {"median of 1", "extrapolated"}
    assert all(r["seconds"] > 0 for r in sel)
    sim = res["sections"]["sim"]
    assert [r["B"] for r in sim["steps"]] == [1, 8] and sim["scipy"]["ok"]
    assert set(res["sections"]["scaling"]) == {"N", "M", "K", "B"}
    saved = json.loads((tmp_path / "benchmarks.json").read_text())  # written as results came in
    assert saved["machine"]["threads"] == torch.get_num_threads() and not saved["errors"]
    write_report(merge([saved]), tmp_path)  # what --merge writes
    assert (tmp_path / "scaling_cpu.png").stat().st_size > 0
    assert (tmp_path / "benchmarks.md").read_text().count("## ") >= 5
    text = to_markdown(res, "python -m bench (tiny)")
    for heading in ("IK queries per second", "Centre selection time", "Closed-loop simulator", "Scaling", "Targets"):
        assert heading in text
    assert all(t["met"] in (True, False, None) for t in targets(res))


def test_select_time_command_sets_and_reports_threads(capsys):
    from bench import select_time

    rows = select_time.main(["--n", "300", "--m", "5", "--iterations", "2", "--repeats", "1", "--threads", "1"])
    assert [r["method"].split(" ")[0] for r in rows] == list(select_time.COLONIES)
    assert all(r["threads"] == 1 and r["iterations"] == 2 and r["x_kmeans"] > 0 for r in rows)
    assert "1 thread(s)" in capsys.readouterr().out


def test_loop_throughput_measures_both_loops():
    from bench.loop_throughput import measure

    rates = measure(batch=4, repeats=1, device="cpu")
    assert set(rates) == {"ideal", "realistic"} and all(r > 0 for r in rates.values())


def test_tune_gains_takes_your_arm_from_overrides_and_keeps_the_evaluations_cases_out():
    from bench.tune_gains import tuning_config
    from rbfn.robots.kinematics import urdf_path

    ur5 = str(urdf_path("ur5"))
    cfg = tuning_config("scara", ["robot=urdf", f"robot.urdf={ur5}", "robot.end_link=ee_link"])
    assert cfg.robot.name == "ur5" and len(cfg.robot.home) == 6  # derived from the URDF, not the SCARA's
    rated = cfg.robot.rated_payload
    assert rated > 0 and cfg.control.payloads == [round(0.3 * rated, 6), round(0.8 * rated, 6)]
    assert cfg.control.duration == 6.0 and cfg.loop.noise_seed == 1 and not cfg.loop.ideal
    assert tuning_config("scara").robot.name == "scara"


def test_tuning_time_times_the_whole_tuning_and_each_search():
    from bench.tuning_time import evaluation_config, measure

    small = ["control.duration=2", "control.payload_off=1.5", "control.network.num_centers=4"]
    small += ["control.network.tune.iterations=2", "control.network.tune.population=3"]
    small += ["control.network.tune.scenarios=1", "control.network.tune.duration=1"]
    cfg = evaluation_config("scara", small)
    net = cfg.control.network.resolved(realistic=not cfg.loop.ideal)
    assert net.law == "tracking" and net.objective == "closed_loop" and not cfg.loop.ideal  # the tuned law
    r = measure(cfg, ["smc", "arbfn_kmeans", "arbfn_aco"], repeats=1, device="cpu")
    assert r["comparison_s"] >= r["tuning_s"] >= r["search_s"]["arbfn_aco"] > 0
    # 2 x 3 candidates on 1 scenario, then the confirmation's 2 (and the twin's 1 where it was kept)
    assert set(r["search_s"]) == {"arbfn_aco"} and r["episodes"]["arbfn_aco"] in (8, 9)


def test_closed_loop_summary_pairs_each_seeds_runs(tmp_path):
    from bench.closed_loop import figure, load, main, tables

    def run(scale: float) -> dict:  # smc's RMS 1 per joint; the others `scale` x theirs
        control = {"smc": {"0kg": {"rms_err": [1.0, 1.0]}, "10kg": {"rms_err": [1.0, 1.0]}}}
        factors = {"arbfn_kmeans": 1.0, "arbfn_aco": scale, "arbfn_random": 0.9, "arbfn_cmaes": 0.95}
        for name, f in factors.items():
            control[name] = {case: {"rms_err": [0.5 * f, 0.5 * f]} for case in ("0kg", "10kg")}
        tuning = {n: {"cost": f, "curve": [1.0, f], "kept_twin": False} for n, f in factors.items()}
        return {"control": control, "control_info": {"tuning": tuning, "tuning_seconds": 12.0}}

    for seed, scale in ((0, 0.6), (1, 0.8), (2, 0.8)):
        (tmp_path / f"scara_s{seed}").mkdir()
        m = run(scale)
        if seed == 2:  # a seed run with arbfn_aco alone
            for part in (m["control"], m["control_info"]["tuning"]):
                del part["arbfn_random"], part["arbfn_cmaes"]
        (tmp_path / f"scara_s{seed}" / "metrics.json").write_text(json.dumps(m))
    runs = load(tmp_path)
    assert list(runs) == ["scara"] and sorted(runs["scara"]) == [0, 1, 2]
    text = tables(runs)
    assert "| 0 | 2.000 | 1.000 | 0.600 | 0.900 | 0.950 | 0.600 | 0.667 |" in text  # smc = n = 2
    assert "| 2 | 2.000 | 1.000 | 0.800 | - | - | 0.800 | - |" in text
    assert "below 1 in 3/3 seeds, at most 0.7 in 1/3" in text and "at most 1 in 2/2 seeds" in text
    figure(runs, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 0
    with pytest.raises(SystemExit):  # nothing to summarize
        main(["--summarize", str(tmp_path / "empty")])


def test_ik_path_counts_jumps_and_unsolved_points():
    from bench.ik_path import jumps, path_joints

    low, high = torch.tensor([0.0, -1.0], dtype=torch.float64), torch.tensor([2.0, 1.0], dtype=torch.float64)
    q = path_joints(low, high, 11, reach=0.25)
    assert torch.allclose(q[0], torch.tensor([0.5, -0.5], dtype=torch.float64)) and torch.allclose(
        q[-1], -q[0] + 2 * q[5]
    )
    ok = torch.ones(11, dtype=torch.bool)
    assert jumps(q, ok, 0.15) == 0  # the path's own steps are 0.1
    bent = q.clone()
    bent[6:, 1] += 1.0  # one step of 1 rad: a branch jump
    ok[9] = False  # and a point not solved
    assert jumps(bent, ok, 0.15) == 2


def test_base_yaw_bench_redraws_only_the_first_joint(scara_robot):
    from bench.base_yaw import turned_targets

    q = 0.5 * (scara_robot.low + scara_robot.high).expand(50, -1).clone()
    turned, x = turned_targets(scara_robot, q)
    assert torch.equal(turned[:, 1:], q[:, 1:]) and turned[:, 0].abs().max() <= torch.pi
    assert torch.allclose(x, scara_robot.targets(turned)) and float(turned[:, 0].std()) > 1.0


def _tree_urdf(tmp_path, joints):
    """A URDF file of (parent, child, type) joints, every link named once."""
    links = {p for p, _, _ in joints} | {c for _, c, _ in joints}
    body = "".join(f'<link name="{k}"/>' for k in sorted(links))
    body += "".join(
        f'<joint name="{p}_{c}" type="{t}"><parent link="{p}"/><child link="{c}"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        for p, c, t in joints
    )
    path = tmp_path / "r.urdf"
    path.write_text(f'<robot name="r">{body}</robot>')
    return path


def test_the_corpus_finds_an_arms_trunk_below_its_gripper_and_skips_two_arms(tmp_path):
    from bench.urdf_corpus import trunk

    arm = [("base", "l1", "revolute"), ("l1", "l2", "revolute"), ("l2", "l3", "revolute"), ("l3", "l4", "revolute"),
           ("l4", "flange", "fixed"), ("flange", "f1", "prismatic"), ("flange", "f2", "prismatic")]  # fmt: skip
    assert trunk(_tree_urdf(tmp_path, arm)) == ("flange", 4, "")
    two = [("base", f"{s}{i}", "revolute") if i == 1 else (f"{s}{i - 1}", f"{s}{i}", "revolute")
           for s in "ab" for i in range(1, 4)]  # fmt: skip
    end, _, why = trunk(_tree_urdf(tmp_path, two))
    assert end is None and "fewer than 3" in why


def test_tracik_solves_the_same_poses_and_is_checked_by_our_forward_kinematics():
    """TRAC-IK on a few UR5 poses from its URDF text: every answer reaches its pose within 0.1 mm
    and 0.1 deg by our forward kinematics; a pose out of reach counts as a failure."""
    pytest.importorskip("pytracik")
    from bench.tracik import tracik_row
    from rbfn.data import make_split
    from rbfn.robots.robot import load_robot

    robot = load_robot(compose_config("train", "robot=ur5").robot)
    split = make_split(robot, 20, 3)
    assert tracik_row(robot, split.x, 0.02)["success"] == 1.0
    far = split.x[:4].clone()
    far[:, 0] += 5.0
    row = tracik_row(robot, torch.cat([split.x[:4], far]), 0.005)
    assert row["success"] == 0.5 and row["n"] == 8


def test_ik_full_trains_measures_and_finds_the_analytic_solutions(capsys, tmp_path):
    pytest.importorskip("eaik")
    from bench.ik_full import main

    main(["--charts", "4", "--centers", "30", "--samples", "300", "--n", "60", "--tracik-n", "10", "--all-n", "10",
          "--repeats", "1", "--out", str(tmp_path)])  # fmt: skip
    rows = [json.loads(line) for line in capsys.readouterr().out.strip().splitlines()]
    by = {r.get("row"): r for r in rows}
    assert rows[0]["charts"] == 4 and (tmp_path / "charts.pt").is_file()
    assert by["polished"]["outside_limits"] == 0 and 0.0 <= by["polished"]["success"] <= 1.0
    assert by["all"]["analytic"] > 1.0 and 0.0 <= by["all"]["analytic_found"] <= 1.0  # a UR5 pose: up to 8
    assert by["tracik"]["success"] == 1.0 and by["tracik"]["success_runs"] == [1.0]
    whole = next(r for r in rows if r.get("row") == "polished" and r["poses"] == "whole joint range")
    assert len(whole["ratio_runs"]) == 1 and whole["ratio"] == whole["ratio_runs"][0] > 0.0
