"""robot=urdf: a user's arm works from its URDF and end link alone (rbfn.robots.derive), and the
shipped presets pass through unchanged. Arms from example-robot-data (skipped without it)."""

import logging
import math
from importlib import metadata
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from rbfn.config import ROBOT_PRESETS, Target
from rbfn.robots.derive import (
    CONDITIONED,
    ENCODER_COUNTS,
    PAYLOAD_MARGIN,
    SIZES,
    box_conditioning,
    derive_evaluate,
    derive_train,
    load_urdf_arm,
)
from rbfn.robots.robot import load_robot
from tests.conftest import CONF, TINY_TRAIN, compose_config


def _erd(rel: str) -> Path:
    """example-robot-data's robots/`rel`, or skip."""
    try:
        path = Path(str(metadata.distribution("example-robot-data").locate_file(""))) / "cmeel.prefix"
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    found = path / "share" / "example-robot-data" / "robots" / rel
    if not found.is_file():
        pytest.skip(f"example-robot-data ships no {rel}")
    return found


def _urdf(rel: str, end_link: str, *more: str) -> list[str]:
    return ["robot=urdf", f"robot.urdf={_erd(rel)}", f"robot.end_link={end_link}", *more]


Z1 = ("z1_description/urdf/z1.urdf", "link06")  # Unitree Z1: 6 joints, effort limits 30-60 N m


def test_a_6_joint_arm_gets_every_key_from_its_urdf():
    cfg = derive_train(compose_config("train", *_urdf(*Z1)))
    cfg.check()
    r = cfg.robot
    arm, _ = load_urdf_arm(r)
    assert r.name == "z1_description" and r.target == Target.pose and r.gravity == 9.81
    lo, hi = (v.tolist() for v in arm.joint_limits())
    for j in range(arm.n):  # home inside its box, the box inside the URDF limits, at most +-box_halfwidth
        assert lo[j] <= r.joint_low[j] <= r.home[j] <= r.joint_high[j] <= hi[j]
        assert r.joint_high[j] - r.joint_low[j] <= 2 * r.box_halfwidth + 1e-12
    # The rated payload: its gravity torque at home within the margin of every effort limit, and
    # 15 % more (past the rounding down to 2 digits) leaves it on some joint.
    home, effort = torch.tensor([r.home], dtype=torch.float64), arm.effort_limits()
    assert r.rated_payload > 0
    assert bool((arm.gravity(home, r.rated_payload)[0].abs() <= PAYLOAD_MARGIN * effort + 1e-9).all())
    assert not bool((arm.gravity(home, 1.15 * r.rated_payload)[0].abs() <= PAYLOAD_MARGIN * effort).all())
    assert r.control_rate == 500.0 and r.encoder_counts == [float(ENCODER_COUNTS)] * 6
    s = SIZES[Target.pose]
    assert (cfg.rbfn.num_centers, cfg.rbfn.growth.start) == (s.num_centers, s.growth_start)
    assert (cfg.data.n_train, cfg.data.n_val, cfg.data.n_test) == (s.n_train, s.n_val, s.n_test)


def test_a_singular_middle_moves_the_home_off_it_and_a_given_singular_home_is_warned_of(caplog):
    """The SCARA's URDF through robot=urdf: the middle of its limits straightens the elbow (q2 = 0),
    where the box would hold both elbow branches. The derived home moves off it, to a box holding
    one elbow branch (q2 of one sign), and the log says why; a home given there is kept and warned
    of; given off it, no warning."""
    scara = ["robot=urdf", "robot.urdf=rbfn/robots/scara/scara.urdf", "robot.end_link=quill"]
    with caplog.at_level(logging.INFO, logger="rbfn.robots.derive"):
        cfg = derive_train(compose_config("train", *scara))
    r = cfg.robot
    assert r.target == Target.position and cfg.rbfn.num_centers == SIZES[Target.position].num_centers
    assert r.joint_low[1] > 0 or r.joint_high[1] < 0, (r.joint_low, r.joint_high)  # one elbow branch
    assert any("has a singularity in its box" in m for m in caplog.messages)
    assert not any("singular configuration" in m for m in caplog.messages)
    assert derive_train(compose_config("train", *scara)).robot.home == r.home  # seeded: the same home
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="rbfn.robots.derive"):
        derive_train(compose_config("train", *scara, "robot.home=[0.0,0.0,1.0]"))
    assert any("singular configuration" in m for m in caplog.messages)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="rbfn.robots.derive"):
        derive_train(compose_config("train", *scara, "robot.home=[1.0,1.0,1.0]"))
    assert not any("singular" in m for m in caplog.messages)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="rbfn.robots.derive"):  # no payload to bound: the IK trains
        assert derive_train(compose_config("train", *scara, "robot.gravity=0")).robot.rated_payload == 0.0
    assert any(
        "robot.rated_payload: no joint is both loaded" in m and "the IK needs none" in m for m in caplog.messages
    )
    with pytest.raises(ValueError, match=r"robot\.home=\[1\.0, 1\.0, 2\.5\] is not allowed: joint joint3 at 2\.5 lies "
                       r"outside its URDF limits \[0, 2\]"):  # fmt: skip
        derive_train(compose_config("train", *scara, "robot.home=[1.0,1.0,2.5]"))


def test_an_arm_pointing_straight_up_at_the_middle_of_its_limits_gets_a_home_it_can_learn_and_carry_from():
    """Kinova's Jaco (example-robot-data, 6 joints): the middle of its limits stands it straight up
    (q2 = q3 = q5 = pi), a singularity, and no payload loads a joint there. The derived home's box
    is well conditioned, and the rated payload is positive and within the effort margin."""
    over = _urdf("kinova_description/robots/kinova.urdf", "j2s6s200_end_effector")
    r = derive_train(compose_config("train", *over)).robot
    lo, hi = torch.tensor(r.joint_low, dtype=torch.float64), torch.tensor(r.joint_high, dtype=torch.float64)
    home = torch.tensor([r.home], dtype=torch.float64)
    assert float(box_conditioning(load_robot(r), home, lo, hi, r.box_halfwidth)[0]) >= 2 * CONDITIONED
    arm, _ = load_urdf_arm(r)
    assert r.rated_payload > 0
    loaded = arm.gravity(home, r.rated_payload)[0].abs()
    assert bool((loaded <= PAYLOAD_MARGIN * arm.effort_limits() + 1e-9).all())


def test_box_conditioning_tells_a_box_across_a_singularity_from_one_beside_it():
    cfg = derive_train(compose_config("train", "robot=scara")).robot
    robot = load_robot(cfg)
    lo, hi = torch.tensor([-3.0, -2.5, 0.0], dtype=torch.float64), torch.tensor([3.0, 2.5, 2.0], dtype=torch.float64)
    homes = torch.tensor([[1.0, 0.0, 1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    across, beside = box_conditioning(robot, homes, lo, hi, 0.5).tolist()
    assert across < CONDITIONED <= beside


def test_the_sizes_are_the_presets():
    for target, name in ((Target.pose, "ur5"), (Target.position, "scara")):
        raw = OmegaConf.load(Path(CONF) / "sizing" / f"{name}.yaml")
        s = SIZES[target]
        assert (raw.rbfn.num_centers, raw.rbfn.growth.start) == (s.num_centers, s.growth_start)
        assert (raw.data.n_train, raw.data.n_val, raw.data.n_test) == (s.n_train, s.n_val, s.n_test)


def test_given_keys_win_and_each_key_is_logged(caplog):
    home = [0.1, 1.2, -1.5, 0.0, 0.2, 0.0]
    over = ["robot.name=my_z1", "robot.rated_payload=1.5", f"robot.home={home}", "robot.box_halfwidth=0.2"]
    with caplog.at_level(logging.INFO, logger="rbfn.robots.derive"):
        cfg = derive_train(compose_config("train", *_urdf(*Z1), *over, "rbfn.num_centers=50"))
    r = cfg.robot
    assert (r.name, r.rated_payload, r.home, cfg.rbfn.num_centers) == ("my_z1", 1.5, home, 50)
    assert r.joint_low == pytest.approx([v - 0.2 for v in home]) and r.joint_high == pytest.approx(
        [v + 0.2 for v in home]
    )
    lines = {m.split(" = ")[0]: m for m in caplog.messages}
    for key in ("robot.name", "robot.rated_payload", "robot.home", "rbfn.num_centers"):
        assert lines[key].endswith("(given)"), lines[key]
    for key in ("robot.target", "robot.gravity", "robot.control_rate", "robot.encoder_counts", "data.n_train"):
        assert "given" not in lines[key], lines[key]


@pytest.mark.parametrize("robot", ROBOT_PRESETS)
def test_the_presets_pass_through_unchanged(robot):
    train = compose_config("train", f"robot={robot}")
    assert derive_train(train) == train
    for loop in ("ideal", "realistic"):
        cfg = compose_config("evaluate", f"robot={robot}", f"loop={loop}")
        assert derive_evaluate(cfg) is cfg


def test_a_7_joint_arm_takes_one_joint_as_an_input_or_holds_it():
    """The Panda through robot=urdf: one joint becomes the network's input beside the pose, the one
    that leaves the other six best conditioned over the box (the upper-arm roll, joint 3; the base
    joint ties with it there, its axis in line at q2 = 0, and stays an output, as it turns targets
    about the base); given, it is kept; held with robot.locked, there is none."""
    panda = ("panda_description/urdf/panda.urdf", "panda_link8")
    cfg = derive_train(compose_config("train", *_urdf(*panda)))
    assert cfg.robot.target == Target.pose and len(cfg.robot.joint_low) == 7
    assert cfg.robot.redundancy == "panda_joint3"
    lo, hi = (torch.tensor(v, dtype=torch.float64) for v in (cfg.robot.joint_low, cfg.robot.joint_high))
    home = torch.tensor([cfg.robot.home], dtype=torch.float64)
    robot = load_robot(cfg.robot)
    per_joint = box_conditioning(robot, home.expand(7, -1), lo, hi, cfg.robot.box_halfwidth, drop=torch.arange(7))
    assert int(per_joint[1:].argmax()) + 1 == 2  # joint 3, the best of all but the base (which turns the arm)
    given = derive_train(compose_config("train", *_urdf(*panda, "robot.redundancy=panda_joint1"))).robot
    assert given.redundancy == "panda_joint1"
    with pytest.raises(ValueError, match=r"robot\.redundancy='nope' is not allowed: allowed are the free joints"):
        derive_train(compose_config("train", *_urdf(*panda, "robot.redundancy=nope")))
    held = derive_train(compose_config("train", *_urdf(*panda, "+robot.locked.panda_joint3=0.0"))).robot
    assert held.target == Target.pose and len(held.joint_low) == 6 and held.redundancy == ""


def test_a_5_joint_arm_learns_the_poses_it_reaches():
    so100 = ("so_arm_description/urdf/so100.urdf", "gripper")
    cfg = derive_train(compose_config("train", *_urdf(*so100)))
    assert cfg.robot.target == Target.pose and len(cfg.robot.home) == 5


def test_the_urdf_and_end_link_are_required():
    with pytest.raises(ValueError, match=r"robot\.urdf=''.*robot\.urdf=PATH"):
        derive_train(compose_config("train", "robot=urdf"))
    with pytest.raises(ValueError, match=r"robot\.end_link=''.*link06"):
        derive_train(compose_config("train", *_urdf(Z1[0], "")))
    with pytest.raises(ValueError, match=r"robot\.end_link='nope'"):
        derive_train(compose_config("train", *_urdf(Z1[0], "nope")))
    with pytest.raises(ValueError, match=r"robot\.target=None.*robot=urdf derives it"):
        compose_config("train", "robot.target=null").check()


def test_the_realistic_loop_takes_the_derived_sensing():
    real = derive_evaluate(compose_config("evaluate", *_urdf(*Z1), "loop=realistic"))
    assert real.loop.control_rate == 500.0 and real.loop.encoder_counts == [float(ENCODER_COUNTS)] * 6
    assert real.gains.observer_gain == 25.0  # conf/gains/robot/urdf_realistic.yaml
    assert derive_evaluate(compose_config("evaluate", *_urdf(*Z1), "loop=ideal")).loop.ideal
    given = derive_evaluate(compose_config("evaluate", *_urdf(*Z1), "loop=realistic", "loop.control_rate=1000"))
    assert given.loop.control_rate == 1000.0 and given.robot.control_rate == 500.0


def test_train_then_evaluate_a_urdf_arm(tmp_path):
    """train.py and evaluate.py's procedures on the Z1 from its URDF and end link alone: the
    checkpoint names it, and no closed-loop torque exceeds its effort limits, in either loop."""
    import evaluate
    import train

    arm = _urdf(*Z1)
    train.run(compose_config("train", *arm, *TINY_TRAIN), tmp_path / "train")
    ckpt = tmp_path / "train" / "checkpoint.pt"
    effort = load_urdf_arm(derive_train(compose_config("train", *arm)).robot)[0].effort_limits().tolist()
    short = ["control.duration=1", "control.payload_on=0.6", "control.payload_off=0.9", "parallel=false"]
    # The closed-loop tuning at a small budget: what it finds is not this test's subject.
    short += [
        "control.network.tune.population=4",
        "control.network.tune.iterations=2",
        "control.network.tune.scenarios=1",
    ]
    for loop in ("ideal", "realistic"):
        parts = [f"checkpoint={ckpt}", "n_test=200"] if loop == "ideal" else ["ik=false"]
        cfg = compose_config("evaluate", *arm, f"loop={loop}", *parts, "online.enabled=false", *short)
        metrics = evaluate.run(cfg, tmp_path / loop)
        assert set(metrics["robots"].values()) == {"z1_description (link06, 6 joints)"}
        assert metrics["control"]["pd"].keys() == {"0kg", "1kg", "2kg"}  # 0, half and all of the rated 2 kg
        for cases in metrics["control"].values():
            for m in cases.values():
                assert all(math.isfinite(t) and t <= e + 1e-9 for t, e in zip(m["peak_tau"], effort)), m["peak_tau"]
    assert metrics["control_info"]["loop"]["encoder_counts"] == [float(ENCODER_COUNTS)] * 6


def test_an_arm_whose_inertials_are_unusable_trains_its_ik_with_a_warning(tmp_path, caplog):
    """The IK needs no dynamics: a URDF whose last link has no mass (M(q) singular) still derives
    every key, the warning naming the joint and saying the closed loop will refuse the arm; the
    rated payload is not derived from meaningless gravity torques (0 kg, said why)."""
    from rbfn.robots.kinematics import urdf_path

    text = urdf_path("ur5").read_text().replace('<mass value="0.1879"/>', '<mass value="0"/>')
    text = text.replace(
        'ixx="0.00039459" ixy="0" ixz="0" iyy="0.00039459" iyz="0" izz="0.00033822"',
        'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"',
    )
    (tmp_path / "arm.urdf").write_text(text)
    with caplog.at_level(logging.INFO, logger="rbfn.robots.derive"):
        cfg = derive_train(
            compose_config("train", "robot=urdf", f"robot.urdf={tmp_path / 'arm.urdf'}", "robot.end_link=ee_link")
        )
    assert cfg.robot.rated_payload == 0.0 and len(cfg.robot.home) == 6
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(
        "the closed loop (evaluate.py's control part) cannot simulate this arm's dynamics and will refuse it; the IK "
        "needs none and trains: joint 'wrist_3_joint' moves no mass or inertia" in m
        for m in warned
    ), warned
    assert (
        "robot.rated_payload = 0 kg (not derived: the URDF's inertials are unusable for dynamics (above))"
        in caplog.messages
    )
