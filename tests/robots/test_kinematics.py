"""URDF loading and FK: the SCARA against its closed form, loader errors, and the shipped UR5 and
Panda against Pinocchio on example-robot-data's descriptions (skipped without those packages)."""
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from rbfn.robots import (forward_kinematics, forward_kinematics_pose, joint_limits, load_serial_chain,
                         urdf_path)
from rbfn.robots import scara

joints = st.lists(st.tuples(st.floats(-3.1, 3.1), st.floats(-2.5, 2.5), st.floats(0.0, 2.0)),
                  min_size=1, max_size=16)


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
    q = torch.tensor([0.0, 0.3, 0.5]) + torch.rand(500, 3, generator=g, dtype=torch.float64) * torch.tensor([2.0, 1.7, 1.0])
    assert torch.allclose(scara.ik(scara.fk(q)), q, atol=1e-9)


def test_bad_end_link_names_links():
    with pytest.raises(ValueError, match=r"scara\.urdf: end_link 'gripper' is not a link of the URDF; "
                                         r"links: \['base', 'link1', 'link2', 'quill'\]"):
        load_serial_chain(scara.URDF_PATH, "gripper")


# --- Loader API and errors ------------------------------------------------------------------


def _urdf(joints: str, links=("a", "b", "c", "d")) -> str:
    return ("<robot name='t'>" + "".join(f"<link name='{n}'/>" for n in links) + joints
            + "</robot>")


def _joint(name, parent, child, kind="revolute", extra="<axis xyz='0 0 1'/>"
           "<limit lower='-1' upper='1' effort='1' velocity='1'/>"):
    return (f"<joint name='{name}' type='{kind}'><parent link='{parent}'/><child link='{child}'/>"
            f"<origin xyz='0.1 0 0'/>{extra}</joint>")


def test_pose_is_position_and_rotation(chain):
    q = torch.rand(5, 3, dtype=torch.float64)
    pose = forward_kinematics_pose(chain, q)
    assert pose.shape == (5, 4, 4)
    assert torch.equal(pose[:, :3, 3], forward_kinematics(chain, q))
    rot = pose[:, :3, :3]
    assert torch.allclose(rot @ rot.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(5, 3, 3),
                          atol=1e-15)
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
    assert forward_kinematics(chain, q)[0].tolist() == [1.8, 0.0, 0.0]   # 1.0 + 0.8, exactly


def test_malformed_urdf_file_named(tmp_path):
    path = tmp_path / "broken_arm.urdf"
    path.write_text(scara.URDF_PATH.read_text().replace("</robot>", ""))
    with pytest.raises(ValueError, match=r"broken_arm\.urdf: malformed URDF: .*line"):
        load_serial_chain(path, "quill")
    path.write_text(_urdf(_joint("j1", "a", "b").replace("<parent link='a'/>", "")))
    with pytest.raises(ValueError, match=r"broken_arm\.urdf: malformed URDF: .*parent"):
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
    text = _urdf(_joint("j1", "a", "b", "continuous", "<limit effort='1' velocity='2'/>")
                 + _joint("j2", "b", "c", "prismatic", "<limit lower='0' upper='0.5' effort='1' velocity='1'/>"),
                 links=("a", "b", "c"))
    chain = load_serial_chain(text, "c")
    low, high = joint_limits(chain)
    assert low.tolist() == [-math.inf, 0.0] and high.tolist() == [math.inf, 0.5]
    # No <axis>: URDF's default (1, 0, 0); the prismatic joint moves along x.
    assert torch.allclose(forward_kinematics(chain, torch.tensor([[0.0, 0.3]], dtype=torch.float64)),
                          torch.tensor([[0.5, 0.0, 0.0]], dtype=torch.float64), atol=1e-15)


def test_shipped_urdfs_load():
    for name, end, n in (("scara", "quill", 3), ("ur5", "ee_link", 6), ("ur5", "tool0", 6),
                         ("panda", "panda_link8", 7), ("panda", "panda_hand", 7)):
        chain = load_serial_chain(urdf_path(name), end)
        assert len(chain.get_joint_parameter_names()) == n
        low, high = joint_limits(chain)
        assert bool(torch.isfinite(low).all() and (low < high).all())
    with pytest.raises(ValueError, match="no URDF named 'kuka'"):
        urdf_path("kuka")


# --- UR5 and Panda against Pinocchio on example-robot-data's descriptions ---------------------
#
# Our ur5.urdf is written from UR's DH table (link frames are DH frames), example-robot-data's
# from ROS-Industrial's ur_description (other intermediate link frames); base_link, base, tool0
# and ee_link are the same frames in both, so no constant transform is needed. The Panda's
# link frames are Franka's modified-DH frames in both. example-robot-data's UR5 writes pi/2 to
# 11 digits: its frames are off by ~1e-11.

REFERENCE = {"ur5": ("ur_description/urdf/ur5_robot.urdf", ["ee_link", "tool0"],
                     ["base_link", "base", "tool0", "ee_link"]),
             "panda": ("panda_description/urdf/panda.urdf", ["panda_link8", "panda_hand"],
                       [f"panda_link{i}" for i in range(9)] + ["panda_hand", "panda_hand_tcp"])}


@pytest.fixture(scope="module", params=sorted(REFERENCE))
def reference(request):
    """(name, Pinocchio model and data of example-robot-data's URDF)."""
    pin = pytest.importorskip("pinocchio")
    from importlib import metadata

    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    suffix = REFERENCE[request.param][0]
    found = [f for f in dist.files or () if str(f).endswith(suffix)]
    if not found:
        pytest.skip(f"example-robot-data ships no {suffix}")
    model = pin.buildModelFromUrdf(str(dist.locate_file(found[0])))
    return request.param, pin, model, model.createData()


def _pin_q(pin, model, names, q):
    """Pinocchio configuration (nq,) for our joint values `q` (n,), other joints neutral."""
    qp = pin.neutral(model)
    for name, v in zip(names, q):
        qp[model.joints[model.getJointId(name)].idx_q] = v
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
        ours.append(forward_kinematics_pose(chain, torch.zeros(1, len(chain.get_joint_parameter_names()),
                                                                dtype=torch.float64))[0].numpy())
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
    q = low + torch.rand(50, len(names), generator=torch.Generator().manual_seed(2),
                         dtype=torch.float64) * (high - low)
    ours = chain.jacobian(q).numpy()
    cols = [model.joints[model.getJointId(n)].idx_v for n in names]
    for qi, ji in zip(q.numpy(), ours):
        ref = pin.computeFrameJacobian(model, data, _pin_q(pin, model, names, qi), model.getFrameId(end),
                                       pin.LOCAL_WORLD_ALIGNED)[:, cols]
        assert np.abs(ji - ref).max() < 1e-9
