"""robot.workspace=full through the entry points: train.py writes the charted checkpoint and its
metrics (box and whole-range figures), a finished run is not redone, evaluate.py measures it on
fresh poses and skips the online part (which adapts one box network), and the box network's paths
name what to use instead."""

import json
import math
import runpy

import pytest
import torch

import evaluate
import train
from rbfn import load_model, load_solver
from rbfn.data import full_range_split
from rbfn.export import deployed, load_pt2, read_onnx
from rbfn.solver import CHARTED_ITERATIONS

from ..conftest import ROOT, compose_config

FULL = [
    "robot=ur5",
    "robot.workspace=full",
    "robot.charts=4",
    "robot.chart_centers=40",
    "robot.chart_samples=1000",
    "centers=kmeans",
    "data.n_test=200",
    "progress=false",
    "num_threads=1",
]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    return out, train.run(compose_config("train", *FULL), out)


def test_train_writes_the_charted_checkpoint_and_its_figures(full_run):
    out, m = full_run
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith("events")) == [
        "checkpoint.pt",
        "ik.onnx",
        "ik.pt2",
        "last.pt",
        "metrics.json",
    ]
    assert json.loads((out / "metrics.json").read_text()) == m
    assert m["workspace"] == "full" and m["charts"] == 4 and m["polish_iterations"] == CHARTED_ITERATIONS
    for key in ("test_polished_success_rate", "test_full_range_polished_success_rate"):
        assert 0 <= m[key] <= 1, key
    assert 0 < m["val_E"] < float("inf")
    assert m["test_full_range_solutions_mean"] > 0 and m["test_full_range_in_workspace"] > 0
    solver = load_solver(out / "checkpoint.pt")
    x = full_range_split(solver.robot, 50, 9).x
    q, ok = solver.solve(x)
    assert q.shape == (50, 6) and bool(ok.any())
    assert train.run(compose_config("train", *FULL), out) == m  # finished: not redone


def test_the_exports_polish_in_their_graph_and_flag_what_converged(full_run, capsys):
    """ik.onnx (onnxruntime alone) and ik.pt2 answer as the deployed torch module does: the best
    answers polished in the graph, in_workspace where that polish converged (and then the joints
    reach the target within 0.1 mm / 0.1 deg by the robot's float64 kinematics), every chart's raw
    answer; examples/deploy_onnx.py prints them and flags a target 10 m away."""
    ort = pytest.importorskip("onnxruntime")
    out, m = full_run
    solver = load_solver(out / "checkpoint.pt")
    robot = solver.robot
    x = full_range_split(robot, 300, 5).x
    with torch.no_grad():
        q, ok, answers, close = deployed(solver.model, robot)(x.float())
    pos, rot = robot.errors(q.double(), x)
    assert bool(ok.any()) and bool(((pos <= 0.1) & (rot <= 0.1))[ok].all())  # flagged: reached
    assert ((q >= solver.low.float() - 1e-6) & (q <= solver.high.float() + 1e-6)).all()
    session = ort.InferenceSession(read_onnx(out / "ik.onnx"))
    assert [o.name for o in session.get_outputs()] == ["joints", "in_workspace", "answers", "closeness"]
    meta = session.get_modelmeta().custom_metadata_map
    assert meta["workspace"] == "full" and meta["charts"] == "4" and meta["base_yaw"] == "false"
    extra = {"rbfn.json": ""}
    program = load_pt2(out / "ik.pt2", extra).module()
    assert json.loads(extra["rbfn.json"]) == {k: v for k, v in meta.items() if k != "sha256"}
    for joints, inside, raw, closeness in (
        (torch.as_tensor(a) for a in session.run(None, {"poses": x.float().numpy()})),
        program(x.float()),
    ):
        assert joints.shape == (300, 6) and raw.shape == (300, 4, 6) and closeness.shape == (300, 4)
        assert float((inside != ok).double().mean()) < 0.02  # float32 rounding may tip a borderline target
        turn = torch.remainder(raw - answers + math.pi, 2 * math.pi) - math.pi
        assert float(turn.abs().max()) < 1e-3 and torch.allclose(closeness, close, atol=1e-4)
    assert 0 <= m["test_full_range_in_workspace"] <= 1
    runpy.run_path(str(ROOT / "examples" / "deploy_onnx.py"))["main"](str(out / "ik.onnx"))
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("ur5: input 'poses' ['batch', 7]") and lines[1].startswith("4 charts answer")
    assert len(lines) == 7 and all("raw answer nearest the current joints: chart" in line for line in lines[2:6])
    assert lines[6].endswith("(10 m away)  in workspace False")


def test_evaluate_measures_the_charted_network_and_skips_online(full_run, tmp_path, caplog):
    out, _ = full_run
    m = evaluate.run(
        compose_config(
            "evaluate", f"checkpoint={out / 'checkpoint.pt'}", "robot=ur5", "n_test=100", "control.enabled=false"
        ),
        tmp_path,
    )
    assert "online" not in m and m["ik"]["workspace"] == "full"
    assert 0 <= m["test_full_range_polished_success_rate"] <= 1
    assert "online: skipped" in caplog.text


def test_box_network_paths_name_the_solver_for_a_charted_checkpoint(full_run):
    out, _ = full_run
    with pytest.raises(ValueError, match=r"charted network \(robot\.workspace=full\): rbfn\.load_solver"):
        load_model(out / "checkpoint.pt")


def test_bad_chart_count_is_refused_before_any_work(tmp_path):
    with pytest.raises(ValueError, match=r"robot\.charts"):
        train.run(compose_config("train", *FULL, "robot.charts=0"), tmp_path)
    assert list(tmp_path.iterdir()) == []
