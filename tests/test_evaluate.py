"""evaluate.py end to end: its metrics.json layout, every setting checked before any work, the
parts independent of each other, and the online sweep labelled by its real perturbation."""

import json
from dataclasses import replace

import pytest
import torch

import evaluate
import train
from rbfn.checkpoint import read_checkpoint
from rbfn.config import GainsConfig, OnlineConfig
from rbfn.studies.beside import can_fork
from rbfn.studies.online import evaluate_online
from rbfn.studies.rundir import RunDirInUse

from .conftest import compose_config

TRAIN = [
    "data.n_train=400",
    "data.n_val=200",
    "data.n_test=200",
    "rbfn.num_centers=12",
    "rbfn.growth.start=0",
    "centers=kmeans",
    "progress=false",
    "export=false",
]
SHORT = [
    "n_test=300",
    "control.duration=1.2",
    "control.payload_on=0.3",
    "control.payload_off=0.9",
    "control.payloads=[0.0,10.0]",
    "control.controllers=[smc,smc_obs,arbfn_kmeans]",
    "control.network.num_centers=8",
    "online.duration=4",
    "online.sizes=[0.0,0.03]",
]
CONTROL_KEYS = {"rms_err", "max_err", "max_err_payload", "peak_tau", "chattering", "limit_breach", "limit_excess"}


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    out = tmp_path_factory.mktemp("train")
    train.run(compose_config("train", *TRAIN), out)
    return out / "checkpoint.pt"


def test_every_part_end_to_end(ckpt, tmp_path, monkeypatch):
    threads, seen = torch.get_num_threads(), []
    import rbfn.studies.evaluation

    control = rbfn.studies.evaluation.evaluate_control
    monkeypatch.setattr(
        rbfn.studies.evaluation,
        "evaluate_control",
        lambda *a, **kw: seen.append(torch.get_num_threads()) or control(*a, **kw),
    )
    torch.set_num_threads(2)  # the suite runs one thread; the default is more
    try:
        m = evaluate.run(compose_config("evaluate", f"checkpoint={ckpt}", *SHORT), tmp_path)
        # Beside the forked parts this process ran one torch thread, and has its own count back.
        assert seen == [1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert set(on_disk) >= {"ik", "online", "control", "control_info", "test_pos_err_mm_median"}
    assert on_disk["ik"]["test_pos_err_mm_median"] == m["test_pos_err_mm_median"] > 0
    assert on_disk["ik"]["test_seed"] == 0
    assert set(on_disk["control"]) == {"smc", "smc_obs", "arbfn_kmeans"}
    for cases in on_disk["control"].values():
        assert set(cases) == {"0kg", "10kg"}
        keys = CONTROL_KEYS | {"saturated"}  # the default realistic loop
        assert all(set(c) == keys and all(len(v) == 3 for v in c.values()) for c in cases.values())
    info = on_disk["control_info"]
    assert set(info) == {
        "loop", "network", "gains", "select_seconds", "sim_seconds", "torque_limits", "phase_one", "feedforward",
        "estimate_rate", "feedback_growth",
    }  # fmt: skip
    assert info["loop"]["name"] == "realistic"
    assert info["network"] == {"law": "two_phase", "objective": "fit"}  # the realistic loop's
    assert info["phase_one"]["payloads"][0] == 0.0 and info["phase_one"]["seconds"] > 0
    assert info["feedforward"]["mode"] == "chosen" and info["feedforward"]["seconds"] > 0
    assert info["estimate_rate"]["chosen"]["arbfn_kmeans"] in [0.05 * f for f in info["estimate_rate"]["factors"]]
    assert info["feedback_growth"]["chosen"]["arbfn_kmeans"] in [1.5 * f for f in info["feedback_growth"]["factors"]]
    assert on_disk["control_info"]["torque_limits"] == [100.0, 100.0, 500.0]  # the SCARA's URDF efforts
    assert on_disk["online"]["task_err_mm_rms_last_2s"] < on_disk["online"]["task_err_mm_rms_no_adapt"]
    for name in (
        "workspace_error_map.png",
        "online_task_error.png",
        "control_smc.png",
        "checkpoint_online.pt",
        "metrics.json",
    ):
        assert (tmp_path / name).is_file(), name
    assert list(tmp_path.glob("events.out.tfevents.*"))
    # The checkpoint's parts ran in a forked process beside the control part (this machine forks);
    # one after the other in this process they give the same metrics.
    assert can_fork("cpu")
    seq = evaluate.run(compose_config("evaluate", f"checkpoint={ckpt}", *SHORT, "parallel=false"), tmp_path / "seq")
    assert _without_times(seq) == _without_times(m)


def _without_times(m):
    if isinstance(m, dict):
        return {k: _without_times(v) for k, v in m.items() if "seconds" not in k and k != "checkpoint"}
    return m


def test_explicit_seed_is_a_seed_not_a_stream(ckpt, tmp_path):
    m = evaluate.run(
        compose_config(
            "evaluate", f"checkpoint={ckpt}", "seed=0", "n_test=300", "online.enabled=false", "control.enabled=false"
        ),
        tmp_path,
    )
    trained = read_checkpoint(ckpt)["metrics"]
    # Seed 0 is the training seed: a fresh set, not the training set (where the error is lower).
    assert m["test_seed"] == 0 and m["test_pos_err_mm_median"] != trained["test_pos_err_mm_median"]


@pytest.mark.parametrize(
    "override,match",
    [
        ("control.dt=-1", "control.dt=-1"),
        ("online.path=spiral", "spiral"),
        ("online.update_every=0", "online.update_every=0"),
        ("control.integrator=rk2", "rk2"),
        ("control.controllers=[smc,lqr]", "control.controllers='lqr'"),
        ("online.sizes=[0.0,0.02]", "online.sizes"),
        ("device=gpu", "device='gpu'"),
        ("num_threads=-1", "num_threads=-1"),
    ],
)
def test_bad_settings_stop_before_any_work(ckpt, tmp_path, override, match):
    with pytest.raises(Exception) as e:
        evaluate.run(compose_config("evaluate", f"checkpoint={ckpt}", override), tmp_path)
    assert match in f"{e.value} {e.value.__cause__}"
    assert list(tmp_path.iterdir()) == []


def test_online_runs_without_the_ik_part(ckpt, tmp_path):
    m = evaluate.run(
        compose_config(
            "evaluate",
            f"checkpoint={ckpt}",
            "ik=false",
            "control.enabled=false",
            "online.duration=4",
            "online.sizes=[0.03]",
        ),
        tmp_path,
    )
    assert "online" in m and "ik" not in m


def test_online_sweep_rows_carry_the_real_perturbation(ckpt):
    cfg = OnlineConfig(duration=4.0, link_error=[0.02, -0.01], offset_error=[0.01, 0.0, 0.0], sizes=[0.0, 0.02, 0.04])
    m = evaluate_online(read_checkpoint(ckpt), cfg, GainsConfig())
    rows = {r["size"]: r for r in m["sweep"]}
    assert rows[0.02]["link_error"] == pytest.approx([0.02, -0.01]) and rows[0.02]["offset_error"][0] == pytest.approx(
        0.01
    )
    assert rows[0.04]["link_error"] == pytest.approx([0.04, -0.02])
    assert rows[0.0]["link_error"] == [0.0, 0.0]
    assert m["task_err_mm_rms_last_2s"] == rows[0.02]["task_err_mm_rms_last_2s"]


@pytest.mark.slow
def test_online_ahead_of_time_equals_eager(ckpt, tmp_path, monkeypatch):
    """online.aot runs the same closed loop from a package compiled ahead of time (two control
    periods per update here: the package's graph, and its compile time, grow with the periods)."""
    import shutil

    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("AOTInductor's CPU backend needs a C++ compiler")
    monkeypatch.setenv("ACO_RBFN_CACHE", str(tmp_path))
    cfg = OnlineConfig(duration=0.5, sizes=[0.03], update_every=2)
    eager = evaluate_online(read_checkpoint(ckpt), cfg, GainsConfig())
    aot = evaluate_online(read_checkpoint(ckpt), replace(cfg, aot=True), GainsConfig())
    assert len(list((tmp_path / "aot").glob("chunk-*.pt2"))) == 1
    for key in ("task_err_mm_rms_first_2s", "task_err_mm_rms_last_2s", "weight_change_norm"):
        assert aot[key] == pytest.approx(eager[key], rel=1e-9, abs=1e-12), key


@pytest.mark.slow
def test_command_line_runs_the_control_part_alone(tmp_path):
    import subprocess
    import sys

    from .conftest import ROOT

    r = subprocess.run(
        [
            sys.executable,
            "evaluate.py",
            "ik=false",
            "online.enabled=false",
            "control.duration=1.2",
            "control.payload_on=0.3",
            "control.payload_off=0.9",
            "control.controllers=[smc]",
            f"hydra.run.dir={tmp_path}",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert list(m) == ["control", "control_info", "evaluate_seconds", "robots", "skipped"]
    assert (
        list(m["control"]) == ["smc"] and m["robots"] == {"control": "scara (quill, 3 joints)"} and m["skipped"] == {}
    )
    assert "Closed loop" in (tmp_path / "evaluate.log").read_text()
    assert "ik: false" in (tmp_path / ".hydra" / "config.yaml").read_text()  # written by evaluate.py


def test_a_directory_holding_files_is_refused_before_any_work(ckpt, tmp_path):
    (tmp_path / "metrics.json").write_text("{}")
    with pytest.raises(RunDirInUse, match="holds files already"):
        evaluate.run(
            compose_config(
                "evaluate", f"checkpoint={ckpt}", "n_test=300", "online.enabled=false", "control.enabled=false"
            ),
            tmp_path,
        )
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]


def test_nothing_to_evaluate_is_an_error_naming_why(tmp_path):
    missing = tmp_path / "typo"
    with pytest.raises(ValueError, match=r"nothing to evaluate: outputs_dir=.*typo.*no such directory.*control"):
        evaluate.run(compose_config("evaluate", f"outputs_dir={missing}", "control.enabled=false"), tmp_path / "a")
    with pytest.raises(ValueError, match=r"nothing to evaluate: ik, online.enabled and control.enabled are all false"):
        evaluate.run(
            compose_config("evaluate", "ik=false", "online.enabled=false", "control.enabled=false"), tmp_path / "b"
        )
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_metrics_name_the_robot_of_every_part_and_what_was_skipped(panda_ckpt, tmp_path):
    from rbfn.checkpoint import save_sealed

    from .studies.test_evaluation import CONTROL, composed

    save_sealed(tmp_path / "panda.pt", panda_ckpt)
    # The `robot` group left at its default (the SCARA): every part evaluates the checkpoint's Panda.
    m = evaluate.run(
        composed(f"checkpoint={tmp_path / 'panda.pt'}", "n_test=200", "online.enabled=false", "loop=ideal", *CONTROL),
        tmp_path / "run",
    )
    assert m["robots"] == dict.fromkeys(("ik", "control"), "panda (panda_hand, 6 joints)")
    assert m["skipped"] == {}
    missing = tmp_path / "none"
    m = evaluate.run(composed(f"outputs_dir={missing}", "online.enabled=false", *CONTROL), tmp_path / "alone")
    assert m["robots"] == {"control": "scara (quill, 3 joints)"} and "no checkpoint.pt" in m["skipped"]["ik"]


def test_metrics_json_is_strict_json_with_undefined_values_named(tmp_path):
    from rbfn.studies.rundir import write_json

    write_json(tmp_path / "m.json", {"a": 1.0, "b": float("nan"), "c": {"d": [1.0, float("inf")]}})
    m = json.loads((tmp_path / "m.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-strict {c}"))
    assert m["a"] == 1.0 and m["b"] is None and m["c"]["d"] == [1.0, None]
    assert set(m["undefined"]) == {"b", "c.d[1]"} and "nan is not a number JSON can hold" in m["undefined"]["b"]
