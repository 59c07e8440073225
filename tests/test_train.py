"""A small training run end to end: files written, metrics consistent, checkpoint reloads."""
import json

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from torch.utils.tensorboard import SummaryWriter

import evaluate
import train
from rbfn import load_model
from rbfn.robots import forward_kinematics

from .test_config import CONF

SMALL = ["data.n_train=400", "data.n_val=200", "data.n_test=300", "rbfn.num_centers=12",
         "rbfn.growth.start=6", "centers.aco.iterations=5", "centers.refine.steps=20",
         "centers.aco.candidates=100", "progress=false"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = OmegaConf.to_object(compose("train", overrides=SMALL))
    return out, train.run(cfg, out)


def test_outputs_written(trained):
    out, metrics = trained
    assert (out / "checkpoint.pt").is_file()
    assert list(out.glob("events.out.tfevents.*"))
    on_disk = json.loads((out / "metrics.json").read_text())
    for key in ("num_centers", "test_joint_rmse", "test_pos_err_mm_median", "test_pos_err_mm_p95",
                "test_pos_err_mm_max", "select_seconds", "train_seconds"):
        assert key in on_disk
    assert on_disk["num_centers"] == 12
    assert [g["num_centers"] for g in on_disk["growth"]] == [6, 12]
    assert not list(out.glob("*.tmp"))


def test_checkpoint_reloads_and_reproduces_metrics(trained, chain, small_data):
    out, metrics = trained
    model = load_model(out / "checkpoint.pt")
    assert not model.training
    x = small_data.test.x
    for dtype in (torch.float32, torch.float64):
        q = model.to(dtype)(x.to(dtype))
        assert q.shape == (x.shape[0], 3) and q.dtype == dtype
    model.double()
    err = (forward_kinematics(chain, model(x)) - x).norm(dim=-1) * 1000
    # A 12-centre network on 400 samples: centimetre-level, far better than no model at all.
    assert err.median() < 50.0
    assert 0 < metrics["test_pos_err_mm_median"] < 50.0


def test_positions_outside_workspace_are_flagged(trained):
    model = load_model(trained[0] / "checkpoint.pt")
    outside = torch.tensor([[0.05, 0.0, -1.0], [3.0, 0.0, -1.0], [1.0, 1.0, -4.0]], dtype=torch.float64)
    assert not model.in_workspace(outside).any()


def test_evaluate_fresh_test_set(trained, tmp_path):
    out, _ = trained
    cfg = evaluate.EvalConfig(checkpoint=str(out / "checkpoint.pt"), n_test=500)
    m = evaluate.evaluate_ik(out / "checkpoint.pt", cfg, tmp_path, SummaryWriter(str(tmp_path)))
    assert m["test_seed"] not in (0, 1, 2)  # training streams are seed * 1000 + {0, 1, 2}
    assert (tmp_path / "workspace_error_map.png").is_file()
    assert abs(m["test_pos_err_mm_median_float32"] / m["test_pos_err_mm_median"] - 1) < 0.05


def test_online_adaptation_end_to_end(trained, tmp_path):
    from rbfn.config import OnlineConfig
    from rbfn.control.online_study import evaluate_online
    from rbfn.config import GainsConfig

    out, _ = trained
    cfg = OnlineConfig(duration=4.0, sizes=[0.0, 0.03])
    m = evaluate_online(out / "checkpoint.pt", cfg, GainsConfig(), out_dir=tmp_path)
    for key in ("task_err_mm_rms_first_2s", "task_err_mm_rms_last_2s", "task_err_mm_rms_no_adapt",
                "task_err_mm_rms_analytic_nominal"):
        assert m[key] > 0 and m[key] == m[key]
    # On the perturbed robot the adapted network ends better than the frozen one.
    assert m["task_err_mm_rms_last_2s"] < m["task_err_mm_rms_no_adapt"]
    assert [r["size"] for r in m["sweep"]] == [0.0, 0.03]
    assert (tmp_path / "online_task_error.png").is_file()
    adapted, original = load_model(tmp_path / "checkpoint_online.pt"), load_model(out / "checkpoint.pt")
    assert not torch.equal(adapted.head.weight, original.head.weight)
    assert torch.equal(adapted.centers, original.centers)
