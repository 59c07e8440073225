"""evaluate.py's robot: the checkpoint's for every part (its gains and loop facts included), a
robot override naming another refused before any work, the `robot` group's without a checkpoint."""

import re
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import evaluate
import train
from rbfn.robots.kinematics import read_urdf, urdf_path
from rbfn.studies.evaluation import for_checkpoint

from ..conftest import CONF, ROOT, TINY_TRAIN, compose_config

# The closed loop at its shortest: one controller, 300 steps (the realistic loop, by default).
CONTROL = [
    "control.duration=0.6",
    "control.dt=0.002",
    "control.payload_on=0.1",
    "control.payload_off=0.4",
    "control.controllers=[smc]",
    "parallel=false",
]
UR5 = "ur5 (ee_link, 6 joints)"


def composed(*overrides: str):
    """evaluate.py's config for the command line `overrides`, as its main composes it."""
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return OmegaConf.to_object(for_checkpoint(compose("evaluate", overrides=list(overrides)), overrides))


@pytest.fixture(scope="module")
def ur5_ckpt(tmp_path_factory):
    out = tmp_path_factory.mktemp("ur5")
    train.run(compose_config("train", "robot=ur5", *TINY_TRAIN, "rbfn.growth.start=0"), out)
    return out / "checkpoint.pt"


def test_a_checkpoint_is_evaluated_on_its_robot_control_part_included(ur5_ckpt, tmp_path):
    parts = [f"checkpoint={ur5_ckpt}", "n_test=200", "online.enabled=false", *CONTROL]
    cfg = composed(*parts)  # the `robot` group left at its default, the SCARA
    # The config robot=ur5 composes: the UR5's realistic gains, its 500 Hz loop and encoders.
    assert cfg == compose_config("evaluate", *parts, "robot=ur5")
    assert cfg.gains == compose_config("evaluate", "robot=ur5").gains != compose_config("evaluate").gains
    assert cfg.loop.control_rate == 500.0 and len(cfg.loop.encoder_counts) == 6
    m = evaluate.run(cfg, tmp_path)
    assert m["robots"] == {"ik": UR5, "control": UR5}
    assert list(m["control"]["smc"]) == ["0kg", "2.5kg", "5kg"]  # 0, half and all of the rated 5 kg
    assert all(len(v) == 6 for c in m["control"]["smc"].values() for v in c.values())
    assert m["control_info"]["gains"]["K"] == cfg.gains.K and len(m["control_info"]["gains"]["joint_scale"]) == 6


def test_a_named_checkpoint_chooses_the_closed_loops_robot_with_its_other_parts_off(ur5_ckpt, tmp_path):
    """checkpoint=PATH ik=false online.enabled=false: the closed loop on the checkpoint's arm (the
    UR5), not the `robot` group's default (the SCARA); without checkpoint=, the group's."""
    parts = ["ik=false", "online.enabled=false", *CONTROL]
    m = evaluate.run(composed(f"checkpoint={ur5_ckpt}", *parts), tmp_path / "named")
    assert m["robots"] == {"control": UR5} and len(m["control"]["smc"]["0kg"]["rms_err"]) == 6
    assert composed(*parts).robot.name == "scara"


@pytest.mark.parametrize(
    "overrides,said",
    [
        (["robot=panda"], "checkpoint=.*, but robot=panda chooses another robot"),
        (["robot.end_link=wrist_3_link"], "ik=false online.enabled=false robot=ur5 robot.end_link=wrist_3_link"),
    ],
)
def test_a_robot_override_naming_another_robot_is_refused(ur5_ckpt, tmp_path, overrides, said):
    with pytest.raises(ValueError, match=said) as e:
        composed(f"checkpoint={ur5_ckpt}", *overrides)
    assert f"holds a network of {UR5}" in str(e.value)
    # The newest checkpoint, picked by default, the same.
    with pytest.raises(ValueError, match=re.escape(f"the newest checkpoint, {ur5_ckpt}, holds a network of {UR5}")):
        composed(f"outputs_dir={ur5_ckpt.parent}", "robot=scara")
    # evaluate.run given a config of another robot refuses it too, and writes nothing.
    with pytest.raises(ValueError, match=re.escape(f"holds a network of {UR5}, but robot=panda")):
        evaluate.run(compose_config("evaluate", f"checkpoint={ur5_ckpt}", "robot=panda"), tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_the_command_line_refuses_another_robot_in_one_line_and_writes_nothing(ur5_ckpt, tmp_path):
    run_dir = tmp_path / "run"
    r = subprocess.run(
        [sys.executable, "evaluate.py", f"checkpoint={ur5_ckpt}", "robot=panda", f"hydra.run.dir={run_dir}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and r.stderr.startswith("error: "), r.stderr
    assert "ur5 (ee_link, 6 joints)" in r.stderr and "robot=panda" in r.stderr
    assert not run_dir.exists()


def test_without_a_checkpoint_the_robot_group_decides(ur5_ckpt, tmp_path):
    cfg = composed("ik=false", "online.enabled=false", "robot=ur5", *CONTROL)
    assert cfg == compose_config("evaluate", "ik=false", "online.enabled=false", "robot=ur5", *CONTROL)
    none = composed(f"outputs_dir={tmp_path / 'none'}", "robot=ur5", *CONTROL)  # none found
    assert none.robot.name == "ur5"
    m = evaluate.run(cfg, tmp_path / "run")
    assert m["robots"] == {"control": UR5} and list(m["control"]["smc"]) == ["0kg", "2.5kg", "5kg"]


@pytest.mark.parametrize("name", ["my_arm", "ur5"])  # a URDF of its own; a copy of the shipped UR5's
def test_a_users_arm_is_evaluated_from_the_checkpoints_urdf_text_when_its_file_is_gone(tmp_path, name):
    path = tmp_path / f"{name}.urdf"
    path.write_text(read_urdf(urdf_path("ur5")).replace('<robot name="ur5"', f'<robot name="{name}"', 1))
    arm = ["robot=urdf", f"robot.urdf={path}", "robot.end_link=ee_link"]
    train.run(compose_config("train", *arm, *TINY_TRAIN, "rbfn.growth.start=0"), tmp_path / "train")
    path.unlink()
    cfg = composed(f"checkpoint={tmp_path / 'train' / 'checkpoint.pt'}", "n_test=200", "online.enabled=false", *CONTROL)
    # robot=urdf with the keys derived at training (not the UR5 preset's, for the copy either)
    assert cfg.robot.name == name and not cfg.robot.derive and cfg.robot.urdf == str(path)
    assert cfg.gains == compose_config("evaluate", "robot=urdf").gains
    m = evaluate.run(cfg, tmp_path / "run")
    label = f"{name} (ee_link, 6 joints)"
    assert m["robots"] == {"ik": label, "control": label}
    half = f"{cfg.robot.rated_payload / 2:g}kg"
    assert list(m["control"]["smc"]) == ["0kg", half, f"{cfg.robot.rated_payload:g}kg"]


def test_a_url_given_as_the_checkpoint_is_refused_as_a_url():
    """As a path, the URL's "//" would fold into a local name, reported as a missing file."""
    url = "https://example.com/run/checkpoint.pt"
    with pytest.raises(ValueError, match=rf"^checkpoint={re.escape(url)} is a URL; aco-rbfn reads and writes local"):
        composed(f"checkpoint={url}")
