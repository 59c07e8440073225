import json

import pytest
import torch

from rbfn.config import ControlConfig, GainsConfig, NetworkConfig, ACOConfig, validate_control
from rbfn.control.study import run_control

KEYS = {"rms_err", "max_err", "max_err_payload", "peak_tau", "chattering"}


def _short(**kw):
    net = NetworkConfig(num_centers=8, aco=ACOConfig(iterations=5, ants=6, archive_size=6))
    base = dict(duration=1.2, payload_on=0.3, payload_off=0.9, payloads=[0.0, 10.0], network=net,
                controllers=["pd", "ctc", "smc", "smc_obs", "arbfn_aco", "arbfn_kmeans"])
    base.update(kw)
    return ControlConfig(**base)


def test_run_control_writes_the_nested_metrics_and_figures(tmp_path):
    cfg = _short()
    metrics = run_control(cfg, GainsConfig(), out_dir=tmp_path)
    info = metrics.pop("_info")
    assert set(metrics) == set(cfg.controllers)
    for name, cases in metrics.items():
        assert set(cases) == {"0kg", "10kg"}
        for m in cases.values():
            assert set(m) == KEYS and all(len(v) == 3 for v in m.values())
            assert all(torch.isfinite(torch.tensor(v)).all() for v in m.values())
        assert (tmp_path / f"control_{name}.png").stat().st_size > 10_000
    assert set(info["select_seconds"]) == {"arbfn_aco", "arbfn_kmeans"}
    json.dumps(metrics)
    # The unknown payload hurts the controller without an observer far more than with one.
    assert metrics["smc"]["10kg"]["rms_err"][2] > 10 * metrics["smc_obs"]["10kg"]["rms_err"][2]


@pytest.mark.parametrize("change,match", [
    ({"controllers": ["pd", "lqr"]}, "unknown controller 'lqr'"),
    ({"controllers": ["arbfn_magic"]}, "unknown controller 'arbfn_magic'"),
    ({"payloads": [-1.0]}, "control.payloads"),
    ({"dtype": "float16"}, "control.dtype='float16' is not allowed"),
])
def test_bad_control_config(change, match):
    with pytest.raises(ValueError, match=match):
        validate_control(_short(**change), GainsConfig())


@pytest.mark.parametrize("field,value,match", [
    ("K", float("nan"), "gains.K=nan must be finite"),
    ("Lambda", 0.0, "gains.Lambda=0.0 must be > 0"),
    ("gamma", -1.0, "gains.gamma=-1.0 must be >= 0"),
    ("robust", "tanh", "gains.robust='tanh' is not allowed"),
])
def test_bad_gains(field, value, match):
    g = GainsConfig()
    setattr(g, field, value)
    with pytest.raises(ValueError, match=match):
        validate_control(_short(), g)


def test_payload_window_outside_the_horizon():
    with pytest.raises(ValueError, match=r"payload window \[0.3, 5.0\]"):
        run_control(_short(payload_off=5.0), GainsConfig())


@pytest.mark.parametrize("gains,k", [("paper", 15.0), ("tuned", 50.0)])
def test_gains_group_composes(gains, k):
    from pathlib import Path

    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    import evaluate  # noqa: F401  (registers the schemas)

    conf = str(Path(__file__).resolve().parents[2] / "conf")
    with initialize_config_dir(config_dir=conf, version_base="1.3"):
        cfg = OmegaConf.to_object(compose("evaluate", overrides=[f"gains={gains}"]))
    assert cfg.gains.K == k and cfg.gains.Lambda <= 20 and cfg.control.controllers[-2:] == ["arbfn_aco", "arbfn_kmeans"]
    validate_control(cfg.control, cfg.gains)


def test_control_gains_preset_composes():
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    import evaluate  # noqa: F401

    conf = str(Path(__file__).resolve().parents[2] / "conf")
    with initialize_config_dir(config_dir=conf, version_base="1.3"):
        cfg = compose("evaluate", overrides=["experiment=control_gains"], return_hydra_config=True)
    assert cfg.hydra.sweeper.params["gains.K"] == "15,30,50" and cfg.ik is False
