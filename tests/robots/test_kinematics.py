"""URDF loading and FK: the SCARA against its closed form, loader errors, the shipped UR5 and Panda
against Pinocchio on example-robot-data's descriptions, URDF documents in any encoding (and the
files and entities the loader must not read), and every URDF example-robot-data ships against
Pinocchio (the Pinocchio tests skipped without those packages)."""

import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from rbfn.robots import forward_kinematics, forward_kinematics_pose, joint_limits, load_serial_chain, scara, urdf_path
from rbfn.robots.kinematics import MAX_URDF_BYTES, read_urdf
from tests.guarded import run_guarded

joints = st.lists(st.tuples(st.floats(-3.1, 3.1), st.floats(-2.5, 2.5), st.floats(0.0, 2.0)), min_size=1, max_size=16)


@settings(max_examples=30, deadline=None)
@given(joints)
def test_urdf_fk_matches_closed_form_float64(chain, qs):
    q = torch.tensor(qs, dtype=torch.float64)
    assert torch.allclose(forward_kinematics(chain, q), scara.fk(q), atol=1e-14, rtol=0)


def test_float32_chain_close_to_closed_form():
    chain32 = load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float32)
    q = torch.rand(100, 3, dtype=torch.float64) * 2
    assert (forward_kinematics(chain32, q.float()).double() - scara.fk(q)).abs().max() < 1e-6


def test_fk_convention():
    # q = 0: arm stretched along x; z = -q3 (joint 3 positive downward).
    q = torch.tensor([[0.0, 0.0, 0.7], [torch.pi / 2, 0.0, 0.0], [0.0, torch.pi / 2, 0.0]], dtype=torch.float64)
    expect = torch.tensor([[1.8, 0.0, -0.7], [0.0, 1.8, 0.0], [1.0, 0.8, 0.0]], dtype=torch.float64)
    assert torch.allclose(scara.fk(q), expect, atol=1e-12)


def test_closed_form_ik_inverts_fk_on_branch():
    g = torch.Generator().manual_seed(0)
    q = torch.tensor([0.0, 0.3, 0.5]) + torch.rand(500, 3, generator=g, dtype=torch.float64) * torch.tensor(
        [2.0, 1.7, 1.0]
    )
    assert torch.allclose(scara.ik(scara.fk(q)), q, atol=1e-9)


def test_bad_end_link_names_links():
    with pytest.raises(
        ValueError,
        match=r"scara\.urdf: end_link 'gripper' is not a link of the URDF; "
        r"links: \['base', 'link1', 'link2', 'quill'\]",
    ):
        load_serial_chain(scara.URDF_PATH, "gripper")


# --- Loader API and errors ------------------------------------------------------------------


def _urdf(joints: str, links=("a", "b", "c", "d")) -> str:
    return "<robot name='t'>" + "".join(f"<link name='{n}'/>" for n in links) + joints + "</robot>"


def _joint(
    name,
    parent,
    child,
    kind="revolute",
    extra="<axis xyz='0 0 1'/><limit lower='-1' upper='1' effort='1' velocity='1'/>",
):
    return (
        f"<joint name='{name}' type='{kind}'><parent link='{parent}'/><child link='{child}'/>"
        f"<origin xyz='0.1 0 0'/>{extra}</joint>"
    )


def test_pose_is_position_and_rotation(chain):
    q = torch.rand(5, 3, dtype=torch.float64)
    pose = forward_kinematics_pose(chain, q)
    assert pose.shape == (5, 4, 4)
    assert torch.equal(pose[:, :3, 3], forward_kinematics(chain, q))
    rot = pose[:, :3, :3]
    assert torch.allclose(rot @ rot.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(5, 3, 3), atol=1e-15)
    # SCARA: rotation about z by q1 + q2.
    c, s = torch.cos(q[:, 0] + q[:, 1]), torch.sin(q[:, 0] + q[:, 1])
    assert torch.allclose(rot[:, 0, 0], c, atol=1e-15) and torch.allclose(rot[:, 1, 0], s, atol=1e-15)


def test_frames_are_links_and_offsets_exact(chain):
    assert chain.get_frame_names(exclude_fixed=False) == ["base", "link1", "link2", "quill"]
    assert chain.get_joint_parameter_names() == ["joint1", "joint2", "joint3"]
    assert chain.dtype == torch.float64
    low, high = joint_limits(chain)
    assert low.tolist() == [-3.14159265358979, -2.6, 0.0] and high.tolist() == [3.14159265358979, 2.6, 2.0]
    q = torch.zeros(1, 3, dtype=torch.float64)
    assert forward_kinematics(chain, q)[0].tolist() == [1.8, 0.0, 0.0]  # 1.0 + 0.8, exactly


def test_malformed_urdf_file_named(tmp_path):
    path = tmp_path / "broken_arm.urdf"
    path.write_text(scara.URDF_PATH.read_text().replace("</robot>", ""))
    with pytest.raises(ValueError, match=r"broken_arm\.urdf: malformed URDF: .*line"):
        load_serial_chain(path, "quill")
    path.write_text(_urdf(_joint("j1", "a", "b").replace("<parent link='a'/>", "")))
    with pytest.raises(ValueError, match=r"broken_arm\.urdf: malformed URDF: .*parent"):
        load_serial_chain(path, "b")
    # A str is the URDF's text, never a file name.
    with pytest.raises(
        ValueError,
        match=r"URDF text: '.*\.urdf' is not URDF text; allowed: XML whose root "
        r"element is <robot> \(a string is never read as a file name",
    ):
        load_serial_chain(str(path), "b")


def test_branch_of_a_tree_is_a_serial_chain():
    text = _urdf(_joint("j1", "a", "b") + _joint("j2", "b", "c") + _joint("j3", "b", "d"))
    chain = load_serial_chain(text, "d")
    assert chain.get_joint_parameter_names() == ["j1", "j3"]
    assert chain.get_frame_names(exclude_fixed=False) == ["a", "b", "d"]
    assert forward_kinematics(chain, torch.zeros(1, 2))[0].tolist() == [0.2, 0.0, 0.0]


def test_disconnected_urdf_errors():
    text = _urdf(_joint("j1", "a", "b") + _joint("j2", "c", "d"))
    with pytest.raises(ValueError, match=r"one tree with one root link; it has 2 root links \['a', 'c'\]"):
        load_serial_chain(text, "b")


def test_link_with_two_parents_errors():
    text = _urdf(_joint("j1", "a", "b") + _joint("j2", "a", "c") + _joint("j3", "c", "b"))
    with pytest.raises(ValueError, match="'b' is the child of two joints"):
        load_serial_chain(text, "b")


def test_joint_to_undefined_link_errors():
    with pytest.raises(ValueError, match="joint 'j2' names link 'e', which is not defined"):
        load_serial_chain(_urdf(_joint("j1", "a", "b") + _joint("j2", "b", "e")), "b")


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_unsupported_joint_on_path_errors(kind):
    text = _urdf(_joint("j1", "a", "b") + _joint("free", "b", "c", kind, "") + _joint("j3", "a", "d"))
    with pytest.raises(ValueError, match=f"URDF text: joint 'free' \\(b -> c\\) is of type '{kind}'"):
        load_serial_chain(text, "c")
    # Off the path it does not matter.
    assert load_serial_chain(text, "d").get_joint_parameter_names() == ["j3"]


def test_continuous_joint_unlimited_and_default_axis():
    text = _urdf(
        _joint("j1", "a", "b", "continuous", "<limit effort='1' velocity='2'/>")
        + _joint("j2", "b", "c", "prismatic", "<limit lower='0' upper='0.5' effort='1' velocity='1'/>"),
        links=("a", "b", "c"),
    )
    chain = load_serial_chain(text, "c")
    low, high = joint_limits(chain)
    assert low.tolist() == [-math.inf, 0.0] and high.tolist() == [math.inf, 0.5]
    # No <axis>: URDF's default (1, 0, 0); the prismatic joint moves along x.
    assert torch.allclose(
        forward_kinematics(chain, torch.tensor([[0.0, 0.3]], dtype=torch.float64)),
        torch.tensor([[0.5, 0.0, 0.0]], dtype=torch.float64),
        atol=1e-15,
    )


def test_shipped_urdfs_load():
    for name, end, n in (
        ("scara", "quill", 3),
        ("ur5", "ee_link", 6),
        ("ur5", "tool0", 6),
        ("panda", "panda_link8", 7),
        ("panda", "panda_hand", 7),
    ):
        chain = load_serial_chain(urdf_path(name), end)
        assert len(chain.get_joint_parameter_names()) == n
        low, high = joint_limits(chain)
        assert bool(torch.isfinite(low).all() and (low < high).all())
    for name in ("kuka", "../robots/ur5", str(urdf_path("ur5"))[:-5]):
        with pytest.raises(
            ValueError,
            match=f"name='{name}' is not a URDF shipped with rbfn.robots; allowed: "
            r"\['panda', 'scara', 'ur5'\]",
        ):
            urdf_path(name)


# --- UR5 and Panda against Pinocchio on example-robot-data's descriptions ---------------------
#
# Our ur5.urdf is written from UR's DH table (link frames are DH frames), example-robot-data's
# from ROS-Industrial's ur_description (other intermediate link frames); base_link, base, tool0
# and ee_link are the same frames in both, so no constant transform is needed. The Panda's
# link frames are Franka's modified-DH frames in both. example-robot-data's UR5 writes pi/2 to
# 11 digits: its frames are off by ~1e-11.

REFERENCE = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", ["ee_link", "tool0"], ["base_link", "base", "tool0", "ee_link"]),
    "panda": (
        "panda_description/urdf/panda.urdf",
        ["panda_link8", "panda_hand"],
        [f"panda_link{i}" for i in range(9)] + ["panda_hand", "panda_hand_tcp"],
    ),
}


@pytest.fixture(scope="module", params=sorted(REFERENCE))
def reference(request):
    """(name, Pinocchio model and data of example-robot-data's URDF)."""
    pin = pytest.importorskip("pinocchio")
    rel = REFERENCE[request.param][0]
    if rel not in ERD_URDFS:
        pytest.skip(f"example-robot-data (installed: {bool(ERD_URDFS)}) ships no {rel}")
    model = pin.buildModelFromUrdf(str(ERD_URDFS[rel]))
    return request.param, pin, model, model.createData()


def _pin_q(pin, model, names, q):
    """Pinocchio configuration (nq,) for our joint values `q` (n,), other joints neutral (a
    continuous joint's two coordinates are (cos q, sin q))."""
    qp = pin.neutral(model)
    for name, v in zip(names, q):
        joint = model.joints[model.getJointId(name)]
        qp[joint.idx_q : joint.idx_q + joint.nq] = [math.cos(v), math.sin(v)] if joint.nq == 2 else [v]
    return qp


def _errors(pin, a, b):
    """Max position error (m) and rotation angle (rad) between poses (N, 4, 4)."""
    pos = np.abs(a[:, :3, 3] - b[:, :3, 3]).max()
    rot = max(np.linalg.norm(pin.log3(ra.T @ rb)) for ra, rb in zip(a[:, :3, :3], b[:, :3, :3]))
    return pos, rot


def test_end_link_pose_matches_pinocchio(reference):
    name, pin, model, data = reference
    g = torch.Generator().manual_seed(1)
    for end in REFERENCE[name][1]:
        chain = load_serial_chain(urdf_path(name), end, torch.float64)
        names = chain.get_joint_parameter_names()
        low, high = joint_limits(chain)
        q = low + torch.rand(1000, len(names), generator=g, dtype=torch.float64) * (high - low)
        ours = forward_kinematics_pose(chain, q).numpy()
        fid = model.getFrameId(end)
        ref = []
        for qi in q.numpy():
            pin.framesForwardKinematics(model, data, _pin_q(pin, model, names, qi))
            ref.append(data.oMf[fid].homogeneous.copy())
        pos, rot = _errors(pin, ours, np.stack(ref))
        assert pos < 1e-9 and rot < 1e-9, (name, end, pos, rot)


def test_frames_match_pinocchio_at_zero(reference):
    name, pin, model, data = reference
    frames = REFERENCE[name][2]
    ours = []
    for link in frames:
        chain = load_serial_chain(urdf_path(name), link)
        ours.append(
            forward_kinematics_pose(chain, torch.zeros(1, len(chain.get_joint_parameter_names()), dtype=torch.float64))[
                0
            ].numpy()
        )
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    ref = np.stack([data.oMf[model.getFrameId(link)].homogeneous for link in frames])
    pos, rot = _errors(pin, np.stack(ours), ref)
    assert pos < 1e-9 and rot < 1e-9, (name, pos, rot)


def test_jacobian_matches_pinocchio(reference):
    # Every joint axis (direction and location) in the world frame, whatever the link frames.
    name, pin, model, data = reference
    end = REFERENCE[name][1][0]
    chain = load_serial_chain(urdf_path(name), end)
    names = chain.get_joint_parameter_names()
    low, high = joint_limits(chain)
    q = low + torch.rand(50, len(names), generator=torch.Generator().manual_seed(2), dtype=torch.float64) * (high - low)
    ours = chain.jacobian(q).numpy()
    cols = [model.joints[model.getJointId(n)].idx_v for n in names]
    for qi, ji in zip(q.numpy(), ours):
        ref = pin.computeFrameJacobian(
            model, data, _pin_q(pin, model, names, qi), model.getFrameId(end), pin.LOCAL_WORLD_ALIGNED
        )[:, cols]
        assert np.abs(ji - ref).max() < 1e-9


# --- Every URDF document loads: encodings, BOM, comments, meshes; entities and files stay out -----

_BODY = (
    "<robot name='t'><!-- café --><?editor keep?>"
    "<link name='a'><visual><geometry><mesh filename='package://nowhere/a.stl'/></geometry>"
    "<material name='m'><texture/></material></visual></link>"
    "<link name='b'><collision><geometry><mesh filename='file:///dev/zero'/></geometry></collision></link>"
    "<link name='c'/>"
    "<joint name='j1' type='revolute'><!-- inside --><parent link='a'/><child link='b'/>"
    "<origin xyz='0.1 0 0.2' rpy='0 0.5 0'/><axis xyz='0 0 1'/>"
    "<limit lower='-1' upper='1' effort='1' velocity='1'/></joint>"
    + _joint("j2", "b", "c")
    + "<transmission name='tr'><joint name='j1'/></transmission></robot>"
)
_DOCUMENTS = {
    "utf-8 declaration": ('<?xml version="1.0" encoding="utf-8"?>\n' + _BODY).encode(),
    "UTF-8 declaration, standalone": ("<?xml version='1.0' encoding='UTF-8' standalone='yes'?>" + _BODY).encode(),
    "latin-1 declaration": ('<?xml version="1.0" encoding="latin-1"?>\n' + _BODY).encode("latin-1"),
    "ISO-8859-1 declaration": ('<?xml version="1.0" encoding="ISO-8859-1"?>' + _BODY).encode("latin-1"),
    "cp1252 declaration": ('<?xml version="1.0" encoding="cp1252"?>' + _BODY).encode("cp1252"),
    "UTF-8 BOM": b"\xef\xbb\xbf" + ('<?xml version="1.0"?>\n' + _BODY).encode(),
    "UTF-8 BOM, no declaration": b"\xef\xbb\xbf" + _BODY.encode(),
    "UTF-16 with BOM": ('<?xml version="1.0" encoding="UTF-16"?>\n' + _BODY).encode("utf-16"),
    "comments first": ("<!-- generated -->\n<!-- by hand -->\n" + _BODY).encode(),
}

_CODECS = {
    "latin-1 declaration": "latin-1",
    "ISO-8859-1 declaration": "latin-1",
    "cp1252 declaration": "cp1252",
    "UTF-16 with BOM": "utf-16",
}


def _same_chain(chain, ref):
    q = torch.rand(20, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(3)) * 2 - 1
    assert chain.get_joint_parameter_names() == ["j1", "j2"]
    assert torch.equal(forward_kinematics_pose(chain, q), forward_kinematics_pose(ref, q))


@pytest.mark.parametrize("name", sorted(_DOCUMENTS))
def test_urdf_document_loads_from_file_bytes_and_text(tmp_path, name):
    ref = load_serial_chain(_BODY, "c")
    data = _DOCUMENTS[name]
    path = tmp_path / "arm.urdf"
    path.write_bytes(data)
    _same_chain(load_serial_chain(path, "c"), ref)
    _same_chain(load_serial_chain(data, "c"), ref)
    text = read_urdf(path)
    assert "café" in text and not text.startswith("\ufeff")
    _same_chain(load_serial_chain(text, "c"), ref)
    # The text as another reader decodes it: declaration (lxml alone refuses a str naming an
    # encoding) and BOM kept.
    decoded = data.decode(_CODECS.get(name, "utf-8"))
    _same_chain(load_serial_chain(decoded, "c"), ref)


def test_read_urdf_text_is_utf8_throughout(tmp_path):
    # A declared encoding other than UTF-8 is rewritten: the text is handed on as UTF-8 (to MuJoCo,
    # to the URDF dynamics, in checkpoints), and a plain UTF-8 parse of it reads the same document.
    from lxml import etree

    path = tmp_path / "arm.urdf"
    path.write_bytes(_DOCUMENTS["latin-1 declaration"])
    text = read_urdf(path)
    assert text.startswith('<?xml version="1.0" encoding="UTF-8"?>') and "café" in text
    assert etree.fromstring(text.encode()).get("name") == "t"
    # UTF-8 files read back exactly as written.
    assert read_urdf(urdf_path("ur5")) == urdf_path("ur5").read_text()


def test_entities_stay_inside_the_document(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET")
    xxe = (
        f'<?xml version="1.0"?><!DOCTYPE robot [<!ENTITY s SYSTEM "file://{secret}">]>'
        "<robot name='&s;'><link name='a'/></robot>"
    )
    for urdf in (xxe, xxe.encode()):
        with pytest.raises(ValueError, match="malformed URDF: Entity 's' not defined") as e:
            load_serial_chain(urdf, "a")
        assert "TOP-SECRET" not in str(e.value)
    # An external DTD is not loaded; internal entities expand.
    chain = load_serial_chain(f'<!DOCTYPE robot SYSTEM "file://{secret}"><robot name="t"><link name="a"/></robot>', "a")
    assert chain.get_frame_names(exclude_fixed=False) == ["a"]
    internal = "<!DOCTYPE robot [<!ENTITY e 'b'>]>" + _urdf(_joint("j1", "a", "&e;"), ("a", "b"))
    assert load_serial_chain(internal, "b").get_joint_parameter_names() == ["j1"]
    lol = (
        "<!DOCTYPE robot [<!ENTITY a0 'ha'>"
        + "".join(f"<!ENTITY a{i} '{('&a' + str(i - 1) + ';') * 10}'>" for i in range(1, 10))
        + "]><robot name='&a9;'/>"
    )
    with pytest.raises(ValueError, match=r"malformed URDF: .*(amplification|loop|entit)"):
        load_serial_chain(lol, "a")


def test_a_string_is_text_and_a_path_a_regular_file(tmp_path):
    with pytest.raises(
        ValueError,
        match=r"URDF text: '/etc/hostname' is not URDF text; allowed: XML whose root element "
        r"is <robot> \(a string is never read as a file name: pass a pathlib\.Path",
    ):
        load_serial_chain("/etc/hostname", "a")
    with pytest.raises(TypeError, match=r"urdf=42 is a int; allowed: a pathlib\.Path, the URDF's text \(str\) or its"):
        load_serial_chain(42, "a")
    with pytest.raises(
        ValueError,
        match=r"URDF bytes: the URDF has 16777218 bytes or characters or more; allowed: at "
        r"most MAX_URDF_BYTES = 16777216",
    ):
        load_serial_chain(b"<" * (MAX_URDF_BYTES + 2), "a")
    with pytest.raises(FileNotFoundError, match=f"{tmp_path / 'none.urdf'}: no such file; allowed: a regular file"):
        load_serial_chain(tmp_path / "none.urdf", "a")
    with pytest.raises(ValueError, match=f"{tmp_path} is a directory, not a regular file; allowed: a regular file"):
        load_serial_chain(tmp_path, "a")
    big = tmp_path / "big.urdf"
    big.write_bytes(b"<robot name='t'><link name='a'/></robot>" + b" " * MAX_URDF_BYTES)
    with pytest.raises(ValueError, match=r"big\.urdf: the URDF has 16777217 bytes or characters or more"):
        load_serial_chain(big, "a")


@pytest.mark.parametrize("target", ["/dev/zero", "fifo"])
def test_devices_and_fifos_are_not_read(tmp_path, target):
    # /dev/zero never ends and a FIFO without a writer blocks: both are refused before any read.
    if target == "fifo":
        target = str(tmp_path / "arm.urdf")
        os.mkfifo(target)
    out = run_guarded(
        f"from pathlib import Path\nfrom rbfn.robots import load_serial_chain\nload_serial_chain(Path({target!r}), 'a')"
    )
    kind = "a FIFO" if target.endswith("arm.urdf") else "a character device"
    assert f"ValueError: {target} is {kind}, not a regular file; allowed: a regular file" in out, out


@pytest.mark.parametrize("target", ["/dev/zero", "fifo", "directory", "missing"])
def test_load_robot_says_what_the_urdf_path_is(tmp_path, target):
    # robot.urdf names no regular file: the message says what is there, the file never read.
    path = {
        "/dev/zero": "/dev/zero",
        "fifo": str(tmp_path / "arm.urdf"),
        "directory": str(tmp_path),
        "missing": str(tmp_path / "none.urdf"),
    }[target]
    what = {
        "/dev/zero": "ValueError: /dev/zero is a character device, not a regular file",
        "fifo": f"ValueError: {path} is a FIFO, not a regular file",
        "directory": f"ValueError: {path} is a directory, not a regular file",
        "missing": f"FileNotFoundError: {path}: no such file",
    }[target]
    if target == "fifo":
        os.mkfifo(path)
    out = run_guarded(
        "from rbfn.config import RobotConfig\nfrom rbfn.robots.robot import load_robot\n"
        f"load_robot(RobotConfig(name='t', urdf={path!r}, end_link='a'))"
    )
    error, message = what.split(": ", 1)
    assert f"{error}: robot.urdf={path!r}: {message}; allowed: a regular file" in out, out


def test_load_robot_records_the_decoded_text(tmp_path):
    from rbfn.config import RobotConfig
    from rbfn.robots.robot import load_robot, robot_from_record

    path = tmp_path / "arm.urdf"
    path.write_bytes(_DOCUMENTS["UTF-16 with BOM"])
    robot = load_robot(
        RobotConfig(name="t", urdf=str(path), end_link="c", joint_low=[-1.0, -1.0], joint_high=[1.0, 1.0])
    )
    again = robot_from_record(robot.record())
    assert again.urdf_text == read_urdf(path) and again.joint_names == ["j1", "j2"]


# --- Every URDF example-robot-data ships, against Pinocchio ---------------------------------------


def _erd_urdfs() -> dict[str, Path]:
    """example-robot-data's URDFs by path under its robots/ folder (empty without the package)."""
    from importlib import metadata

    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        return {}
    found = {}
    for f in dist.files or ():
        parts = Path(str(f)).parts
        if str(f).endswith(".urdf") and "robots" in parts:
            found["/".join(parts[parts.index("robots") + 1 :])] = Path(str(dist.locate_file(f)))
    return found


ERD_URDFS = _erd_urdfs()
# The serial arms among them (all must be there and match Pinocchio; the rest are checked alike).
ARMS = (
    "ur_description/urdf/ur3_robot.urdf",
    "ur_description/urdf/ur3_joint_limited_robot.urdf",
    "ur_description/urdf/ur3_gripper.urdf",
    "ur_description/urdf/ur5_robot.urdf",
    "ur_description/urdf/ur5_joint_limited_robot.urdf",
    "ur_description/urdf/ur5_gripper.urdf",
    "ur_description/urdf/ur10_robot.urdf",
    "ur_description/urdf/ur10_joint_limited_robot.urdf",
    "panda_description/urdf/panda.urdf",
    "panda_description/urdf/panda_collision.urdf",
    "kinova_description/robots/kinova.urdf",
    "xarm_description/urdf/xarm7.urdf",
    "z1_description/urdf/z1.urdf",
    "so_arm_description/urdf/so100.urdf",
    "so_arm_description/urdf/so101.urdf",
    "talos_data/robots/talos_left_arm.urdf",
    "finger_edu_description/robots/finger_edu.urdf",
    "asr_twodof_description/urdf/TwoDofs.urdf",
    "double_pendulum_description/urdf/double_pendulum.urdf",
    "double_pendulum_description/urdf/double_pendulum_continuous.urdf",
    "double_pendulum_description/urdf/double_pendulum_simple.urdf",
)
EMPTY = {"ur_description/urdf/ur3.urdf"}  # a <robot> without links: refused, not a robot


def _longest_chain_end(path: Path) -> str:
    """The link with the most moving joints (then joints) above it, read with lxml alone."""
    from lxml import etree

    root = etree.parse(str(path)).getroot()
    up = {
        j.find("child").get("link"): (j.find("parent").get("link"), j.get("type") != "fixed")
        for j in root.findall("joint")
    }

    def depth(link):
        moving = total = 0
        while link in up:
            link, move = up[link]
            moving, total = moving + move, total + 1
        return moving, total

    return max((link.get("name") for link in root.findall("link")), key=depth)


def test_every_arm_is_shipped():
    if not ERD_URDFS:
        pytest.skip("example-robot-data is not installed")
    assert sorted(set(ARMS) - set(ERD_URDFS)) == []


@pytest.mark.parametrize("rel", sorted(ERD_URDFS))
def test_example_robot_data_urdf_matches_pinocchio(rel):
    pin = pytest.importorskip("pinocchio")
    path = ERD_URDFS[rel]
    if rel in EMPTY:
        with pytest.raises(ValueError, match="malformed URDF: no <robot> with <link> elements"):
            load_serial_chain(path, "base_link")
        return
    end = _longest_chain_end(path)
    chain = load_serial_chain(path, end, torch.float64)
    names = chain.get_joint_parameter_names()
    if rel in ARMS:
        assert len(names) >= 2, (rel, end, names)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    low, high = joint_limits(chain)
    low, high = low.clamp(min=-math.pi), high.clamp(max=math.pi)  # continuous joints: one turn
    q = low + torch.rand(100, len(names), generator=torch.Generator().manual_seed(4), dtype=torch.float64) * (
        high - low
    )
    ours = forward_kinematics_pose(chain, q).numpy()
    ref = []
    for qi in q.numpy():
        pin.framesForwardKinematics(model, data, _pin_q(pin, model, names, qi))
        ref.append(data.oMf[model.getFrameId(end)].homogeneous.copy())
    pos, rot = _errors(pin, ours, np.stack(ref))
    assert pos < 1e-12 and rot < 1e-12, (rel, end, pos, rot)


@pytest.mark.parametrize(
    "old,new,message",
    [
        (
            '<origin xyz="1.0 0 0"',
            '<origin xyz="nan 0 0"',
            r'<origin xyz="nan 0 0"> of joint \'joint2\': allowed are finite',
        ),
        ('<origin xyz="1.0 0 0"', '<origin xyz="0 -inf 0"', r"of joint 'joint2': allowed are finite numbers"),
        ('<origin xyz="1.0 0 0"', '<origin xyz="1e300 0 0"', r"of joint 'joint2': allowed are offsets within 1000 m"),
    ],
)
def test_non_finite_or_absurd_urdf_numbers_are_named(old, new, message):
    from rbfn.robots.kinematics import urdf_tree

    text = urdf_path("scara").read_text()
    assert old in text
    with pytest.raises(ValueError, match=message):
        urdf_tree(text.replace(old, new, 1), "scara.urdf")


def test_inertial_numbers_are_checked_where_the_dynamics_read_them():
    """A negative mass is physics, not a number the kinematics need: the tree parses, and the
    dynamics name it (rbfn.robots.dynamics.Arm.problems; tests/robots/test_dynamics.py)."""
    import re

    from rbfn.robots.dynamics import load_arm
    from rbfn.robots.kinematics import urdf_tree

    text = re.sub(r'<mass value="[^"]*"', '<mass value="-2"', urdf_path("scara").read_text(), count=1)
    urdf_tree(text, "scara.urdf")  # kinematics drop the inertials
    urdf_tree(text, "scara.urdf", inertials=True)
    assert load_arm(text, "quill").problems[0] == (
        "link 'link1' (moved by joint 'joint1') has mass -2 kg; allowed: a mass in [0, 1e+06] kg"
    )
    with pytest.raises(ValueError, match=r"<inertia ixx=\"nan\".* of link 'link1': allowed are finite numbers"):
        urdf_tree(text.replace('ixx="0"', 'ixx="nan"', 1), "scara.urdf", inertials=True)


def test_the_parsers_notes_on_unknown_attributes_go_to_the_debug_log(capfd, caplog):
    """A real URDF's <robot version="1.0"> (or a vendor's extension) is no line on stderr a parse:
    the parser's note goes to the log's debug level."""
    import logging

    from rbfn.robots.kinematics import parse_urdf, read_urdf, urdf_path

    text = read_urdf(urdf_path("ur5")).replace('<robot name="ur5"', '<robot name="ur5" version="1.0"', 1)
    with caplog.at_level(logging.DEBUG, logger="rbfn.robots.kinematics"):
        robot = parse_urdf(text, "ur5.urdf")
    assert robot.name == "ur5"
    assert capfd.readouterr().err == ""
    assert 'Unknown attribute "version"' in caplog.text
