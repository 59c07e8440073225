"""Pose IK on the UR5 end to end at a small size: (B, 7) targets, q and -q alike, bad targets named,
the polish converging from the network's answer without leaving the joint box, the export."""

import pytest
import torch

import train
from rbfn import load_model, load_solver

from .conftest import compose_config

SMALL = [
    "robot=ur5",
    "centers=kmeans",
    "rbfn.num_centers=150",
    "data.n_train=3000",
    "data.n_val=1000",
    "data.n_test=500",
    "progress=false",
    "num_threads=1",
]


@pytest.fixture(scope="module")
def ur5_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ur5")
    return out, train.run(compose_config("train", *SMALL), out)


def _targets(n=200, seed=5):
    from rbfn.data import make_split
    from rbfn.robots.robot import load_robot

    robot = load_robot(compose_config("train", "robot=ur5").robot)
    return make_split(robot, n, seed), robot


def test_pose_metrics_are_reported(ur5_run):
    _, m = ur5_run
    for key in (
        "test_pos_err_mm_median",
        "test_rot_err_deg_median",
        "test_rot_err_deg_p95",
        "test_polished_success_rate",
        "test_polished_pos_err_mm_median",
    ):
        assert m[key] >= 0, key
    assert m["target"] == "pose" and m["test_polished_pos_err_mm_median"] < m["test_pos_err_mm_median"]


def test_pose_network_takes_poses_and_ignores_the_quaternion_sign(ur5_run):
    net = load_model(ur5_run[0] / "checkpoint.pt", dtype=torch.float64)
    split, _ = _targets()
    x = split.x
    flipped = torch.cat([x[:, :3], -x[:, 3:]], -1)
    q = net(x)
    assert q.shape == (x.shape[0], 6)
    assert torch.allclose(net(flipped), q, atol=1e-12)
    with pytest.raises(
        ValueError, match=r"poses must be \(B, 7\): position in m, then a unit quaternion.*got shape \(200, 3\)"
    ):
        net(x[:, :3])
    bad = x.clone()
    bad[3, 3:] *= 1.5
    with pytest.raises(ValueError, match=r"unit length.*row 3"):
        net(bad)


def test_polish_converges_and_stays_in_the_box(ur5_run):
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, robot = _targets()
    raw_pos, _ = robot.errors(solver.model(split.x), split.x)
    q, ok = solver.solve(split.x, iterations=8)
    assert ((q >= robot.low) & (q <= robot.high)).all()
    pos, rot = robot.errors(q, split.x)
    assert float(ok.double().mean()) >= 0.95
    assert (pos[ok] <= 0.1).all() and (rot[ok] <= 0.1).all()
    assert float(pos.median()) < 1e-3 * float(raw_pos.median())
    with pytest.raises(ValueError, match="iterations=-1"):
        solver.solve(split.x, iterations=-1)


def test_restarts_rescue_the_targets_the_polish_leaves(ur5_run):
    """One step from the network leaves many targets; restarts from random joints in the box
    reach them without leaving the box or touching the targets already solved."""
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, robot = _targets()
    q1, ok1 = solver.solve(split.x, iterations=1)
    q, ok = solver.solve(split.x, iterations=1, restarts=5)
    assert int(ok1.sum()) < 0.9 * len(ok1) and int(ok.sum()) > int(ok1.sum()) + 0.05 * len(ok1)
    assert torch.equal(q[ok1], q1[ok1]) and ok[ok1].all()
    pos, rot = robot.errors(q, split.x)
    assert (pos[ok] <= 0.1).all() and (rot[ok] <= 0.1).all()
    assert ((q >= robot.low) & (q <= robot.high)).all()
    assert torch.equal(solver.solve(split.x, iterations=1, restarts=5)[0], q)  # seeded
    with pytest.raises(ValueError, match="restarts=-2"):
        solver.solve(split.x, restarts=-2)


def test_pose_export_matches_the_module(ur5_run, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    out, _ = ur5_run
    split, _ = _targets(50)
    x = split.x.float()
    q, inside = load_model(out / "checkpoint.pt").solve(x)
    sess = ort.InferenceSession(str(out / "ik.onnx"), providers=["CPUExecutionProvider"])
    q_onnx, inside_onnx = sess.run(["joints", "in_workspace"], {"poses": x.numpy()})
    assert torch.allclose(torch.from_numpy(q_onnx), q, atol=1e-4)
    assert inside_onnx.tolist() == inside.tolist()


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"iterations": True}, r"iterations=True is not allowed: use an integer in \[0, 1000\]"),
        ({"iterations": 10**9}, r"iterations=1000000000 is not allowed"),
        ({"iterations": 2.0}, r"iterations=2.0 is not allowed"),
        ({"restarts": -1}, r"restarts=-1 is not allowed"),
        ({"restart_iterations": "5"}, r"restart_iterations='5' is not allowed"),
        ({"seed": -1}, r"seed=-1 is not allowed"),
    ],
)
def test_solve_checks_its_arguments(panda_ckpt, kwargs, message):
    from rbfn.checkpoint import model_from_checkpoint
    from rbfn.robots.robot import robot_from_record
    from rbfn.solver import IKSolver

    robot = robot_from_record(panda_ckpt["robot"])
    solver = IKSolver(model_from_checkpoint(panda_ckpt), robot)
    x = robot.targets(0.5 * (robot.low + robot.high)[None])
    with pytest.raises(ValueError, match=message):
        solver.solve(x, **kwargs)
    with pytest.raises(ValueError, match=r"poses must be finite|non-finite"):
        solver.solve(torch.full_like(x, float("nan")))


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"tol_mm": -1}, r"tol_mm=-1 is not allowed: use a finite number > 0"),
        ({"tol_deg": float("nan")}, r"tol_deg=nan is not allowed"),
        ({"damping": -1e-3}, r"damping=-0.001 is not allowed: use a finite number >= 0"),
    ],
)
def test_solver_settings_are_checked(panda_ckpt, kwargs, message):
    from rbfn.checkpoint import model_from_checkpoint
    from rbfn.robots.robot import robot_from_record
    from rbfn.solver import IKSolver

    with pytest.raises(ValueError, match=message):
        IKSolver(model_from_checkpoint(panda_ckpt), robot_from_record(panda_ckpt["robot"]), **kwargs)
