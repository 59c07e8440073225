"""The packaged robots and the closed-form registry: one folder per robot shipped as package data,
preset values only in conf/robot, the SCARA's closed-form constants those of its URDF, and closed
forms chosen for exactly the URDF they were written for."""

import re
from dataclasses import asdict, fields
from importlib.resources import files
from pathlib import Path

import pytest
import torch

from rbfn.config import ROBOT_PRESETS, ControlConfig, RobotConfig
from rbfn.control import control_robot
from rbfn.robots import scara
from rbfn.robots.arm_terms import ArmTerms
from rbfn.robots.dynamics import load_arm
from rbfn.robots.kinematics import parse_urdf, read_urdf, urdf_path
from rbfn.robots.registry import CONF_ROBOT, closed_form, preset
from rbfn.robots.scara import ScaraTerms

ROOT = Path(__file__).resolve().parents[2]


def test_the_packaged_robots_are_the_folders_and_the_presets():
    folders = sorted(p.parent.name for p in (ROOT / "rbfn" / "robots").glob("*/*.urdf") if p.stem == p.parent.name)
    presets = sorted(p.stem for p in CONF_ROBOT.glob("*.yaml") if p.stem != "urdf")  # urdf: any user's arm
    assert folders == sorted(ROBOT_PRESETS) == presets
    assert CONF_ROBOT == ROOT / "conf" / "robot"


def test_each_urdf_is_package_data():
    """pip install ships what pyproject's package-data names: rbfn/robots/NAME/NAME.urdf."""
    globs = re.search(r'^"rbfn\.robots" = \[(.*)\]', (ROOT / "pyproject.toml").read_text(), re.M).group(1)
    for name in ROBOT_PRESETS:
        resource = files(f"rbfn.robots.{name}") / f"{name}.urdf"
        assert resource.is_file() and Path(str(resource)) == urdf_path(name)
        assert any(Path(f"{name}/{name}.urdf").match(glob.strip(' "')) for glob in globs.split(","))


def test_preset_values_come_from_conf_robot():
    for name in ROBOT_PRESETS:
        values = preset(name)
        arm = load_arm(name)  # end link and gravity: the preset's
        assert values.name == name and arm.end_link == values.end_link
        assert torch.equal(arm.gravity_vector, torch.tensor([0.0, 0.0, -values.gravity], dtype=torch.float64))
    with pytest.raises(ValueError, match=r"name='kuka' is not a packaged robot; allowed: \['scara', 'ur5', 'panda'\]"):
        preset("kuka")


def test_robot_config_defaults_are_the_scara_preset():
    """RobotConfig() is the SCARA of conf/robot/scara.yaml, but for the values left to resolve:
    gravity (null: the preset's, 9.8) and home (empty: the paper trajectory has none), and the
    realistic loop's controller rate and encoders (unknown for an arbitrary URDF: null, empty)."""
    default, scara_yaml = asdict(RobotConfig()), asdict(preset("scara"))
    differ = {f.name for f in fields(RobotConfig) if default[f.name] != scara_yaml[f.name]}
    assert differ == {"gravity", "home", "control_rate", "encoder_counts"}
    assert default["gravity"] is None and default["home"] == [] and default["control_rate"] is None
    assert default["encoder_counts"] == []


def test_scara_constants_are_its_urdf_and_preset():
    """ScaraParams: l1, l2 the joint origins, m1, m2, m3 the link masses, links 1 and 2 uniform
    rods (centre of mass at half length, inertia m l^2 / 12), g conf/robot/scara.yaml's."""
    p, urdf = scara.ScaraParams(), parse_urdf(read_urdf(scara.URDF_PATH), "scara.urdf", inertials=True)
    joints, links = urdf.joint_map, urdf.link_map
    assert (joints["joint2"].origin.xyz[0], joints["joint3"].origin.xyz[0]) == (p.l1, p.l2)
    for link, mass, length in (("link1", p.m1, p.l1), ("link2", p.m2, p.l2), ("quill", p.m3, 0.0)):
        inertial = links[link].inertial
        assert inertial.mass == mass and inertial.origin.xyz[0] == length / 2
        assert inertial.inertia.izz == pytest.approx(mass * length**2 / 12, rel=1e-14, abs=1e-15)
    assert p.g == preset("scara").gravity


def test_closed_forms_are_chosen_for_exactly_their_urdf():
    text = read_urdf(scara.URDF_PATH)
    closed = closed_form(text, scara.END_LINK)
    assert isinstance(closed, scara.ScaraClosedForm) and closed.params == scara.ScaraParams()
    assert closed_form(text, scara.END_LINK, gravity=9.81).params.g == 9.81
    assert closed_form(text, "link2") is None and closed_form(text, scara.END_LINK, {"joint3": 1.0}) is None
    assert closed_form(re.sub(r'<mass value="0.5"', '<mass value="0.6"', text), scara.END_LINK) is None
    assert closed_form(read_urdf(urdf_path("ur5")), "ee_link") is None
    assert closed_form(read_urdf(urdf_path("panda")), "panda_hand") is None


def test_the_closed_loop_asks_the_registry(tmp_path):
    """The SCARA's closed form by its URDF, whatever its label or how it is given; another payload
    link, or a copy of the URDF changed, takes the URDF forms."""
    by_name = control_robot(RobotConfig(name="scara"), ControlConfig())
    by_file = control_robot(RobotConfig(name="any", urdf=str(scara.URDF_PATH)), ControlConfig())
    by_text = control_robot(RobotConfig(name="any"), ControlConfig(), urdf_text=read_urdf(scara.URDF_PATH))
    for setup in (by_name, by_file, by_text):
        assert isinstance(setup.dynamics, ScaraTerms) and setup.scale is None
    other_link = control_robot(RobotConfig(), ControlConfig(payload_link="link2"))
    copy = tmp_path / "scara.urdf"
    copy.write_text(read_urdf(scara.URDF_PATH).replace('<robot name="scara">', '<robot name="copy">'))
    for setup in (other_link, control_robot(RobotConfig(urdf=str(copy)), ControlConfig())):
        assert isinstance(setup.dynamics, ArmTerms) and setup.scale is not None
