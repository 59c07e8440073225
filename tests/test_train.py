"""Training end to end: files written, metrics consistent, the checkpoint reloads, the run
directory is locked while in use, and a refused run leaves it exactly as it was."""

import json
import subprocess
import sys

import pytest
import torch

import train
from rbfn import load_model
from rbfn.robots import forward_kinematics
from rbfn.studies.rundir import RunDirInUse

from .conftest import ROOT, compose_config
from .studies.test_rundir_lock import held_elsewhere

SMALL = [
    "data.n_train=400",
    "data.n_val=200",
    "data.n_test=300",
    "rbfn.num_centers=12",
    "rbfn.growth.start=6",
    "centers.aco.iterations=5",
    "centers.refine.full.steps=20",
    "centers.aco.ant_system.candidates=100",
    "progress=false",
]


def _snapshot(d):
    """Every file under d with its bytes and mtime."""
    return {p.relative_to(d): (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return out, train.run(compose_config("train", *SMALL), out, {".hydra/overrides.yaml": "- seed=0\n"})


def test_outputs_written(trained):
    out, metrics = trained
    for name in ("checkpoint.pt", "ik.onnx", "ik.pt2", "metrics.json", "last.pt", ".hydra/overrides.yaml"):
        assert (out / name).is_file(), name
    assert list(out.glob("events.out.tfevents.*"))
    on_disk = json.loads((out / "metrics.json").read_text())
    assert on_disk == json.loads(json.dumps(metrics))
    assert on_disk["num_centers"] == 12
    assert [g["num_centers"] for g in on_disk["growth"]] == [6, 12]
    assert 0 < on_disk["select_seconds"] <= on_disk["train_seconds"]
    assert (on_disk["selector"], on_disk["centers_chosen_by"], on_disk["selection_note"]) == ("aco", "aco", None)
    assert not list(out.glob("*.tmp"))


def test_checkpoint_reloads_and_reproduces_metrics(trained, chain, scara_robot):
    out, metrics = trained
    model = load_model(out / "checkpoint.pt", dtype=torch.float64)
    assert not model.training
    from rbfn.data import make_dataset

    data = make_dataset(scara_robot, (400, 200, 300), seed=0)
    x = data.test.x  # the run's own test set: metrics must reproduce
    err = (forward_kinematics(chain, model(x)) - x).norm(dim=-1) * 1000
    assert float(err.median()) == pytest.approx(metrics["test_pos_err_mm_median"], rel=1e-6)
    # A 12-centre network on 400 samples: about 1 cm, far better than a constant guess (~0.5 m).
    assert metrics["test_pos_err_mm_median"] < 25.0


def test_positions_outside_workspace_are_flagged(trained):
    model = load_model(trained[0] / "checkpoint.pt")
    outside = torch.tensor([[0.05, 0.0, -1.0], [3.0, 0.0, -1.0], [1.0, 1.0, -4.0]], dtype=torch.float64)
    assert not model.in_workspace(outside).any()


def test_finished_run_is_left_alone_and_another_config_is_refused(trained):
    out, metrics = trained
    before = _snapshot(out)
    assert train.run(compose_config("train", *SMALL), out) == metrics
    with pytest.raises(ValueError, match="different configuration"):
        train.run(compose_config("train", *SMALL, "seed=1"), out, {".hydra/overrides.yaml": "- seed=1\n"})
    assert _snapshot(out) == before


def test_a_run_directory_in_use_is_refused(tmp_path):
    with held_elsewhere(tmp_path), pytest.raises(RunDirInUse, match="in use by another process"):
        train.run(compose_config("train", *SMALL), tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_another_commands_results_are_refused(tmp_path):
    (tmp_path / "metrics.json").write_text('{"ik": {}, "evaluate_seconds": {"ik": 1.0}}')  # evaluate.py's
    before = _snapshot(tmp_path)
    with pytest.raises(ValueError, match=r"metrics.json is not a training run's"):
        train.run(compose_config("train", *SMALL), tmp_path, {".hydra/overrides.yaml": "- seed=0\n"})
    assert _snapshot(tmp_path) == before


@pytest.mark.slow
def test_refused_rerun_on_the_command_line_leaves_the_directory_as_it_was(tmp_path):
    args = [
        sys.executable,
        "train.py",
        *SMALL,
        "rbfn.growth.start=0",
        "centers=kmeans",
        "export=false",
        f"hydra.run.dir={tmp_path}",
    ]
    first = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr[-3000:]
    before = _snapshot(tmp_path)
    second = subprocess.run([*args, "seed=3"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert second.returncode != 0 and "different configuration" in second.stderr
    assert _snapshot(tmp_path) == before
    assert "seed=3" not in (tmp_path / ".hydra" / "overrides.yaml").read_text()
    # The run's messages went to its log file, not only to the terminal.
    assert "test position error median" in (tmp_path / "train.log").read_text()


@pytest.mark.parametrize("extra", [["rbfn.solver=lms"], ["experiment=paper", "rbfn.num_centers=20"]])
def test_lms_solver_and_paper_preset_run(tmp_path, extra):
    cfg = compose_config("train", *SMALL, "export=false", "centers.aco.iterations=3", *extra)
    m = train.run(cfg, tmp_path)
    assert m["test_pos_err_mm_median"] > 0 and all(g["val_E"] > 0 for g in m["growth"])


def test_export_command_writes_models_that_reproduce_the_checkpoint(trained, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    out, _ = trained
    r = subprocess.run(
        [sys.executable, "-m", "rbfn.export", str(out / "checkpoint.pt"), "--out-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    x = torch.tensor([[1.2, 0.8, -1.0], [0.5, 1.4, -0.7], [2.5, 0.0, -1.0]], dtype=torch.float32)
    from rbfn.checkpoint import read_checkpoint
    from rbfn.export import deployed
    from rbfn.robots.robot import robot_from_record

    robot = robot_from_record(read_checkpoint(out / "checkpoint.pt")["robot"])
    with torch.no_grad():  # the exports turn targets around the base (the SCARA's first joint) as this module does
        q, inside = deployed(load_model(out / "checkpoint.pt"), robot)(x)
    sess = ort.InferenceSession(str(tmp_path / "ik.onnx"), providers=["CPUExecutionProvider"])
    q_onnx, inside_onnx = sess.run(["joints", "in_workspace"], {"positions": x.numpy()})
    assert torch.allclose(torch.from_numpy(q_onnx), q, atol=1e-5)
    assert inside_onnx.tolist() == inside.tolist()
    prog = torch.export.load(str(tmp_path / "ik.pt2")).module()
    assert torch.allclose(prog(x)[0], q, atol=1e-5)
