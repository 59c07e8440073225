"""Every config option composes; bad values fail early with a message naming the value."""
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import MissingConfigException
from omegaconf import OmegaConf

import train  # noqa: F401  (registers the schemas)
from rbfn.config import SELECTORS, TrainConfig, validate_train
from rbfn.data import check_finite

CONF = str(Path(__file__).resolve().parents[1] / "conf")


def _cfg(*overrides: str) -> TrainConfig:
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return OmegaConf.to_object(compose("train", overrides=list(overrides)))


@pytest.mark.parametrize("name", SELECTORS)
def test_every_centers_option_composes_and_validates(name):
    cfg = _cfg(f"centers={name}")
    assert cfg.centers.name == name
    validate_train(cfg)


def test_evaluate_config_composes():
    import evaluate  # noqa: F401

    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose("evaluate", overrides=["checkpoint=x.pt"])
    assert cfg.checkpoint == "x.pt"


def test_unknown_selector_names_it():
    with pytest.raises(MissingConfigException, match="foo"):
        _cfg("centers=foo")


def test_mistyped_value_fails_at_composition():
    with pytest.raises(Exception, match="num_centers"):
        _cfg("rbfn.num_centers=many")


@pytest.mark.parametrize("override,match", [
    ("rbfn.num_centers=0", "rbfn.num_centers=0"),
    ("rbfn.num_centers=-3", "rbfn.num_centers=-3"),
    ("rbfn.num_centers=5000", "rbfn.num_centers=5000 exceeds"),
    ("centers.width_scale=-1.0", "centers.width_scale=-1.0"),
    ("centers.name=bogus", "centers.name='bogus'"),
    ("robot.joint_high=[2.0,0.3,1.5]", "joint 2"),
    ("centers.aco.rho=1.5", "rho=1.5"),
    ("device=tpu", "device='tpu'"),
])
def test_bad_values_fail_with_message(override, match):
    with pytest.raises(ValueError, match=match.replace("[", r"\[").replace(".", r"\.")):
        validate_train(_cfg(override))


def test_nan_in_data_is_named():
    x = torch.zeros(5, 3)
    x[2, 1] = float("nan")
    with pytest.raises(ValueError, match="train positions contains non-finite values .first at row 2"):
        check_finite("train positions", x)


def test_nan_in_training_data_stops_run(tmp_path, monkeypatch):
    real = train.make_dataset

    def poisoned(*a, **k):
        d = real(*a, **k)
        d.train.x[7, 0] = float("nan")
        return d

    monkeypatch.setattr(train, "make_dataset", poisoned)
    cfg = _cfg("data.n_train=50", "data.n_val=20", "data.n_test=20", "rbfn.num_centers=5", "progress=false")
    with pytest.raises(ValueError, match="train positions contains non-finite values .first at row 7"):
        train.run(cfg, tmp_path)
    assert not (tmp_path / "checkpoint.pt").exists()


def test_joint_range_outside_urdf_limits():
    cfg = _cfg("robot.joint_high=[2.0,3.0,1.5]", "progress=false")
    with pytest.raises(ValueError, match="joint2 .* leaves the URDF limits"):
        train.load_robot(cfg, "cpu")


@pytest.mark.parametrize("experiment", ["paper", "aco_vs_kmeans"])
def test_experiment_presets_compose(experiment):
    validate_train(_cfg(f"experiment={experiment}"))
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose("train", overrides=[f"experiment={experiment}"], return_hydra_config=True)
    if experiment == "paper":
        assert cfg.centers.aco.colony == "ant_system" and cfg.centers.width_rule == "paper"
        assert (cfg.centers.aco.rho, cfg.centers.aco.Q, cfg.centers.aco.iterations) == (0.9, 100.0, 100)
    else:
        assert cfg.hydra.sweeper.params["seed"] == "0,1,2,3,4"


@pytest.mark.parametrize("launcher,target", [("joblib", "JoblibLauncher"), ("slurm", "SlurmLauncher")])
def test_launchers_compose(launcher, target):
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher" if launcher == "joblib"
                        else "hydra_plugins.hydra_submitit_launcher")
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose("train", overrides=[f"hydra/launcher={launcher}"], return_hydra_config=True)
    assert cfg.hydra.launcher._target_.endswith(target)
