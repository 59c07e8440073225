"""Pose IK on the UR5 end to end at a small size: (B, 7) targets, q and -q alike, bad targets named,
the polish converging from the network's answer without leaving the joint box, the export."""

import pytest
import torch

import train
from rbfn import RBFNetwork, load_model, load_solver

from .conftest import PANDA_REDUNDANT, compose_config

SMALL = [
    "robot=ur5",
    "robot.workspace=box",
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
        "test_full_range_polished_success_rate",
        "test_full_range_in_workspace",
    ):
        assert m[key] >= 0, key
    assert m["target"] == "pose" and m["test_polished_pos_err_mm_median"] < m["test_pos_err_mm_median"]
    # one branch in a box: the whole joint range is mostly out of reach, and the figures say so
    assert m["test_full_range_polished_success_rate"] < 0.5 * m["test_polished_success_rate"]


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
    # The polish's range: the trained box widened by a tenth of its width, the base joint's URDF limits.
    wide = 0.1 * (robot.high - robot.low)
    assert ((q[:, 1:] >= (robot.low - wide)[1:]) & (q[:, 1:] <= (robot.high + wide)[1:])).all()
    assert torch.equal(solver.low[1:], (robot.low - wide)[1:]) and float(solver.high[0]) == 2 * torch.pi
    pos, rot = robot.errors(q, split.x)
    assert float(ok.double().mean()) >= 0.95
    assert (pos[ok] <= 0.1).all() and (rot[ok] <= 0.1).all()
    assert float(pos.median()) < 1e-3 * float(raw_pos.median())
    with pytest.raises(ValueError, match="iterations=-1"):
        solver.solve(split.x, iterations=-1)


def test_a_settling_polish_stops_each_target_once_it_converges(ur5_run):
    """`settle`: targets already within the tolerances come back as they were; the rest take the
    steps, and every one flagged converged is within the tolerances by forward kinematics."""
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, robot = _targets(100, seed=6)
    start = torch.cat([split.q[:50], solver.network(split.x[50:])[0]])
    q, ok = solver._polish(start, split.x, 5, settle=True)
    assert torch.equal(q[:50], start[:50]) and bool(ok[:50].all())
    assert not torch.equal(q[50:], start[50:])
    pos, rot = robot.errors(q[ok], split.x[ok])
    assert float(pos.max()) <= 0.1 and float(rot.max()) <= 0.1
    q_all, ok_all = solver._polish(start, split.x, 5)
    assert int(ok.sum()) >= int(ok_all.sum()) - 2 and not torch.equal(q_all[:50], start[:50])


def test_a_settling_polish_gives_up_on_answers_still_far_after_its_give_up_step(ur5_run, monkeypatch):
    """Targets far out of reach (positions 5 m away) stop stepping after `GIVE_UP_STEP` steps of a
    longer settling polish; a polish of no more steps than that, or one that does not settle, takes
    them all."""
    import rbfn.solver as solver_module

    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, _ = _targets(20, seed=7)
    far = split.x.clone()
    far[:, :3] += 5.0
    start = solver.network(split.x)[0]
    steps = []
    direction = solver._direction  # once a step, with or without a line search
    monkeypatch.setattr(solver, "_direction", lambda q, *a: steps.append(q.shape[0]) or direction(q, *a))
    _, ok = solver._polish(start, far, 10, settle=True)
    assert steps == [20] * solver_module.GIVE_UP_STEP and not bool(ok.any())
    steps.clear()
    solver._polish(start, far, solver_module.GIVE_UP_STEP, settle=True)
    solver._polish(start, far, 4)
    assert steps == [20] * (solver_module.GIVE_UP_STEP + 4)


def test_a_settling_step_takes_back_a_step_that_makes_the_error_worse(ur5_run, monkeypatch):
    """`_trial`: a step that lowers the error is kept (its scale raised again, up to 1); one that
    raises it is taken back, joints, errors and cost as they were, and its scale cut to
    `REJECTED_SCALE` of itself."""
    import rbfn.solver as solver_module

    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, _ = _targets(20, seed=8)
    q = solver.network(split.x)[0]
    goal = solver_module.goals(split.x, True)
    state = solver._errors(q, goal)
    cost = solver._tolerances(state)
    scale = torch.full((20,), 0.5, dtype=q.dtype)
    q1, state1, cost1, scale1 = solver._trial(q, goal, state, cost, scale, None)
    kept = cost1 < cost
    assert int(kept.sum()) >= 15  # the network's answers are close: most first steps help
    assert torch.equal(scale1, torch.where(kept, 1.0, 0.5 * solver_module.REJECTED_SCALE).to(q.dtype))
    assert torch.equal(cost1[~kept], cost[~kept]) and torch.equal(q1[~kept], q[~kept])
    assert torch.allclose(cost1, solver._tolerances(solver._errors(q1, goal)))
    direction = solver._direction
    monkeypatch.setattr(solver, "_direction", lambda *a: -direction(*a))  # uphill
    q2, state2, cost2, scale2 = solver._trial(q1, goal, state1, cost1, scale1, None)
    assert torch.equal(q2, q1) and torch.equal(cost2, cost1)
    assert all(a is b or torch.equal(a, b) for a, b in zip(state2, state1))
    assert torch.equal(scale2, scale1 * solver_module.REJECTED_SCALE)


def test_the_last_round_tries_only_the_charts_not_yet_tried():
    from rbfn.solver import _untried

    tried = torch.tensor([[3, 1], [0, 4]])
    assert torch.equal(_untried(tried, 5), torch.tensor([[0, 2, 4], [1, 2, 3]]))
    assert torch.equal(_untried(tried[:, :0], 3), torch.tensor([[0, 1, 2], [0, 1, 2]]))


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
    assert ((q >= solver.low) & (q <= solver.high)).all()
    assert torch.equal(solver.solve(split.x, iterations=1, restarts=5)[0], q)  # seeded
    with pytest.raises(ValueError, match="restarts=-2"):
        solver.solve(split.x, restarts=-2)


def test_pose_export_matches_the_module(ur5_run, tmp_path):
    """Training's ik.onnx turns targets around the base as the torch module of the exporters does."""
    ort = pytest.importorskip("onnxruntime")
    from rbfn.export import deployed

    out, _ = ur5_run
    split, robot = _targets(50)
    x = split.x.float()
    with torch.no_grad():
        q, inside = deployed(load_model(out / "checkpoint.pt"), robot)(x)
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


def test_no_targets_and_a_bad_block_size(panda_ckpt):
    from rbfn.checkpoint import model_from_checkpoint
    from rbfn.robots.robot import robot_from_record
    from rbfn.solver import IKSolver

    robot = robot_from_record(panda_ckpt["robot"])
    solver = IKSolver(model_from_checkpoint(panda_ckpt), robot)
    x, n = robot.targets(0.5 * (robot.low + robot.high)[None])[:0], len(robot.joint_names)
    for near in (None, torch.zeros(0, n, dtype=torch.float64)):
        q, ok = solver.solve(x, near=near)
        assert q.shape == (0, n) and ok.shape == (0,)
    solver.block_rows = 0
    with pytest.raises(ValueError, match=r"IKSolver.block_rows=0 is not allowed: use a positive integer"):
        solver.solve(x)


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


def _turned(split, robot, seed=7):
    """The split's joints with the first joint drawn anywhere in [-pi, pi] (the rest in the box), and their targets."""
    g = torch.Generator().manual_seed(seed)
    q = split.q.clone()
    q[:, 0] = (2 * torch.rand(q.shape[0], generator=g, dtype=torch.float64) - 1) * torch.pi
    return q, robot.targets(q)


def test_near_picks_the_nearest_converged_answer(ur5_run):
    """Given the current joints, the answer is the converged one nearest them: the truth itself
    where the current joints are near it, and the whole turn of the base joint nearest them."""
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, _ = _targets(100)
    g = torch.Generator().manual_seed(3)
    near = split.q + 0.02 * torch.randn(split.q.shape, generator=g, dtype=torch.float64)
    q, ok = solver.solve(split.x, near=near)
    assert float(ok.double().mean()) >= 0.97
    assert float((q - split.q)[ok].abs().max()) < 1e-3  # the truth's branch, within the tolerance
    turned = near.clone()
    turned[:, 0] -= 2 * torch.pi  # the same pose one turn of the base joint away (UR5 limits +-2 pi)
    q2, ok2 = solver.solve(split.x, near=turned)
    both = ok & ok2
    assert float(both.double().mean()) >= 0.95
    one_turn_back = q[:, 0] - 2 * torch.pi
    expected = torch.where(one_turn_back >= -2 * torch.pi, one_turn_back, q[:, 0])  # inside the URDF limits
    assert torch.allclose(q2[both, 0], expected[both], atol=1e-3) and (one_turn_back[both] >= -2 * torch.pi).any()
    assert torch.allclose(q2[both, 1:], q[both, 1:], atol=1e-3)
    assert torch.equal(solver.solve(split.x, near=near)[0], q)  # deterministic


def test_near_keeps_a_dense_path_on_its_branch(ur5_run):
    """A dense path through the box (the poses of a straight joint-space line across half the box,
    away from singular poses, 200 points) solved point by point, each near the last answer:
    converged everywhere and no step jumps (every joint moves less than 0.1 rad a step; the
    path's own steps are below 0.01)."""
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    _, robot = _targets(1)
    mid, width = 0.5 * (robot.low + robot.high), robot.high - robot.low
    s = torch.linspace(0, 1, 200, dtype=torch.float64)[:, None]
    path = robot.targets(mid - 0.25 * width + 0.5 * s * width)
    q, ok = solver.solve(path[:1], near=(mid - 0.25 * width)[None])
    steps = []
    for x in path[1:]:
        q_next, ok_next = solver.solve(x[None], near=q)
        steps.append(float((q_next - q).abs().max()))
        q, ok = q_next, ok & ok_next
    assert bool(ok) and max(steps) < 0.1, max(steps)


@pytest.mark.parametrize(
    "near,error,message",
    [
        (
            "shape",
            ValueError,
            r"near must be \(10, 6\): the robot's current joints \['shoulder_pan_joint'.*got shape \(10, 5\)",
        ),
        ("nan", ValueError, r"near must be finite; row 2 is \[nan"),
        ("int", TypeError, r"near must be floating-point joints .*got dtype torch.int64"),
        ("list", TypeError, r"near must be a torch.Tensor or numpy.ndarray \(10, 6\).*got list"),
    ],
)
def test_bad_near_is_refused(ur5_run, near, error, message):
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, _ = _targets(10)
    bad = {
        "shape": split.q[:, :5],
        "nan": split.q.clone().index_fill_(0, torch.tensor([2]), float("nan")),
        "int": split.q.long(),
        "list": split.q.tolist(),
    }[near]
    with pytest.raises(error, match=message):
        solver.solve(split.x, near=bad)


def test_a_target_turned_around_the_base_is_solved_as_well_as_inside_the_box(ur5_run):
    """Targets whose base joint lies anywhere in [-pi, pi] (outside the trained [-1, 1]) are turned
    into the box: the same raw accuracy and the same polished success as inside it; without the
    turn (base_yaw=False) most of them are lost."""
    split, robot = _targets(300)
    _, x_turned = _turned(split, robot)
    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    raw_in, _ = robot.errors(solver.network(split.x)[0], split.x)
    raw_out, _ = robot.errors(solver.network(x_turned)[0], x_turned)
    # Inside the box the answer as trained is kept where it is close; outside, the best of the turns:
    # on this coarse network (median about 27 mm) within a quarter of each other.
    assert abs(float(raw_out.median()) / float(raw_in.median()) - 1) < 0.25
    _, ok_in = solver.solve(split.x)
    q, ok_out = solver.solve(x_turned)
    assert abs(float(ok_out.double().mean()) - float(ok_in.double().mean())) <= 0.01
    assert float(ok_out.double().mean()) >= 0.95
    assert (q[:, 0].abs() <= 2 * torch.pi).all()  # within the UR5's URDF limits
    _, ok_plain = load_solver(ur5_run[0] / "checkpoint.pt", base_yaw=False).solve(x_turned)
    assert float(ok_plain.double().mean()) < 0.8


@pytest.mark.parametrize("name", ["scara", "ur5", "panda"])
def test_the_shipped_arms_turn_about_the_base(name):
    from rbfn.robots.robot import load_robot
    from rbfn.yaw import base_yaw

    robot = load_robot(compose_config("train", f"robot={name}").robot)
    assert robot.base_yaw_sign() == 1
    yaw = base_yaw(robot)
    assert (
        yaw is not None and yaw.candidates >= 2 and (yaw.low, yaw.high) == (float(robot.low[0]), float(robot.high[0]))
    )


@pytest.mark.parametrize(
    "old,new",
    [
        (
            '<origin xyz="0 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>',
            '<origin xyz="0.1 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>',
        ),
        (
            '<origin xyz="0 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>',
            '<origin xyz="0 0 0" rpy="0 0 0"/>\n    <axis xyz="0 1 0"/>',
        ),
        (
            '<origin xyz="0 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>',
            '<origin xyz="0 0 0" rpy="0.3 0 0"/>\n    <axis xyz="0 0 1"/>',
        ),
    ],
    ids=["offset-off-the-axis", "axis-not-vertical", "tilted-origin"],
)
def test_an_arm_without_the_symmetry_is_not_turned(old, new):
    """A first joint off the base's vertical axis, about another axis or tilted: detected as such,
    so its targets are solved as trained."""
    from rbfn.robots import scara
    from rbfn.robots.kinematics import load_serial_chain, read_urdf
    from rbfn.robots.robot import Robot
    from rbfn.yaw import base_yaw

    text = read_urdf(scara.URDF_PATH)
    assert text.count(old) == 1
    text = text.replace(old, new)
    chain = load_serial_chain(text, scara.END_LINK, torch.float64)
    box = torch.tensor([0.0, 0.3, 0.5], dtype=torch.float64), torch.tensor([2.0, 2.0, 1.5], dtype=torch.float64)
    robot = Robot(chain, text, scara.END_LINK, *box)
    assert robot.base_yaw_sign() == 0 and base_yaw(robot) is None


def test_any_batch_is_solved_in_blocks_as_one_batch_is(ur5_run, monkeypatch):
    """`solve` and `network` run their targets in blocks of `block_rows`, so any batch takes bounded
    memory: no polish sees more than a block (twice it with `near`), and blocks of 7 give one whole
    batch's answers (turned around the base, near given joints, restarted) up to the network's
    rounding: its float64 products round by batch size, 1e-15 rad here; the polish itself is row by row."""
    from rbfn.solver import IKSolver

    solver = load_solver(ur5_run[0] / "checkpoint.pt")
    split, robot = _targets(60)
    q_true, x = _turned(split, robot)
    near = q_true + 0.05 * torch.randn(q_true.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    calls = (
        lambda: solver.solve(x, iterations=2, restarts=2, restart_iterations=5),
        lambda: solver.solve(x, iterations=2, near=near),
        lambda: solver.network(x),
    )
    whole = [c() for c in calls]
    seen = []
    polish = IKSolver._polish
    monkeypatch.setattr(IKSolver, "_polish", lambda self, q, *a: seen.append(q.shape[0]) or polish(self, q, *a))
    solver.block_rows = 7
    for c, (a, b) in zip(calls, whole):
        got_a, got_b = c()
        assert torch.allclose(got_a, a, rtol=0, atol=1e-12)
        assert torch.equal(got_b, b) if b.dtype == torch.bool else torch.allclose(got_b, b, rtol=0, atol=1e-12)
    assert max(seen) == 14 and 7 in seen
    assert not whole[0][1].all() and whole[0][1].any()  # some targets restarted, some converged


def test_a_batch_beyond_the_memory_available_is_refused_before_any_work(panda_ckpt, monkeypatch):
    import rbfn.memory
    from rbfn.checkpoint import model_from_checkpoint
    from rbfn.robots.robot import robot_from_record
    from rbfn.solver import IKSolver

    robot = robot_from_record(panda_ckpt["robot"])
    solver = IKSolver(model_from_checkpoint(panda_ckpt), robot)
    x = robot.targets((0.5 * (robot.low + robot.high))[None].repeat(20, 1))
    monkeypatch.setattr(rbfn.memory, "available_bytes", lambda device="cpu": 1000)
    monkeypatch.setattr(IKSolver, "_polish", lambda *a: pytest.fail("no work before the memory check"))
    solver.block_rows = 8
    with pytest.raises(
        ValueError,
        match=r"targets=\(20, 7\) needs at least .* KiB .*more than this machine's "
        r"available memory \(1000 B\); solve fewer targets a call",
    ):
        solver.solve(x)


def test_an_arm_with_fewer_joints_than_the_pose_has_dof_polishes_the_poses_it_reaches(tmp_path):
    """The UR5 with its last joint held (5 free joints): reachable poses are a 5-D set of the 6-D
    ones, and the damped step converges on them although its 6 x 6 J J^T is singular (the damping
    keeps it solvable; the joint-space form (J^T J + lambda I) dq = J^T e converged on exactly the
    same share of 5000 such poses, so the polish keeps one form)."""
    over = ["+robot.locked.wrist_3_joint=0.0", "robot.joint_low=[-1.0,-2.2,0.5,-2.9,-2.57]",
            "robot.joint_high=[1.0,-0.2,2.5,-0.9,-0.57]", "robot.home=[0.0,-1.2,1.5,-1.9,-1.57]"]  # fmt: skip
    cfg = compose_config("train", *SMALL, *over, "export=false")
    train.run(cfg, tmp_path)
    solver = load_solver(tmp_path / "checkpoint.pt")
    from rbfn.data import make_split
    from rbfn.robots.robot import load_robot

    split = make_split(load_robot(cfg.robot), 200, 5)
    q, ok = solver.solve(split.x, iterations=5)
    assert q.shape == (200, 5) and float(ok.double().mean()) >= 0.97
    pos, rot = solver.robot.errors(q, split.x)
    assert (pos[ok] <= 0.1).all() and (rot[ok] <= 0.1).all()


PANDA_7 = [*PANDA_REDUNDANT, *SMALL[1:]]  # the UR5's sizes


@pytest.fixture(scope="module")
def panda7_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("panda7")
    from rbfn.robots.derive import derive_train

    cfg = derive_train(compose_config("train", *PANDA_7))
    return out, cfg, train.run(cfg, out)


def test_a_7_joint_arm_keeps_its_redundant_joint_as_an_input(panda7_run):
    """The Panda with all 7 joints free and joint 3 an input beside the pose: the network takes
    (B, 8), the solver takes poses (B, 7) and the joint's value from `redundancy` or `near`, and
    its answers keep that joint near the value asked (the least-norm polish)."""
    from rbfn.data import make_split
    from rbfn.robots.robot import load_robot

    out, cfg, m = panda7_run
    assert m["test_polished_success_rate"] >= 0.9  # 3 steps from a small network
    solver = load_solver(out / "checkpoint.pt")
    assert solver.model.in_features == 8 and solver.robot.redundancy == "panda_joint3"
    split = make_split(load_robot(cfg.robot), 300, 5)
    poses, truth = split.x[:, :7], split.q
    q, ok = solver.solve(poses, iterations=8, redundancy=truth[:, 2])
    assert q.shape == (300, 7) and float(ok.double().mean()) >= 0.95  # a small network
    assert float((q[ok, 2] - truth[ok, 2]).abs().median()) < 0.05
    pos, rot = solver.robot.errors(q, poses)
    assert (pos[ok] <= 0.1).all() and (rot[ok] <= 0.1).all()
    near = truth + 0.02  # the current joints, a little off the exact answer
    q_near, ok_near = solver.solve(poses, iterations=8, near=near)
    assert float(ok_near.double().mean()) >= 0.95
    assert float((q_near[ok_near] - near[ok_near]).abs().amax(-1).median()) < 0.1
    _, ok_default = solver.solve(poses, iterations=8)  # the joint at the middle of its range
    assert float(ok_default.double().mean()) >= 0.8
    with pytest.raises(ValueError, match=r"poses \(B, 7\).*got shape \(300, 8\).*near= or redundancy="):
        solver.solve(split.x)
    with pytest.raises(ValueError, match=r"redundancy must be a floating-point tensor or array \(300,\)"):
        solver.solve(poses, redundancy=truth[:5, 2])
    with pytest.raises(ValueError, match=r"the 8th column; IKSolver\.solve takes it"):
        solver.model(poses)


def test_the_posture_pull_moves_joints_from_their_limits_in_the_null_space(panda7_run):
    """`_direction(..., posture=True)` at joints that reach their pose already (no error): the step
    is `_posture`'s pull less what would move the end link, so the end link stays (to first order)
    while the joints near a limit move away from it, the others hardly."""
    from rbfn.solver import POSTURE

    out, _, _ = panda7_run
    solver = load_solver(out / "checkpoint.pt")
    low, high = solver.low, solver.high
    q = (low + 0.5 * (high - low)).repeat(3, 1)
    q[0, 0], q[1, 2], q[2, 4] = high[0] - 0.02, low[2] + 0.02, high[4] - 0.05  # near a limit each
    goal = solver._goals(solver.robot.targets(q))
    state = solver._errors(q, goal)
    assert float(state[0].abs().max()) < 1e-9
    assert float(solver._direction(q, state, None).abs().max()) < 1e-12  # no error, no pull: no step
    dq = solver._direction(q, state, None, posture=True)
    moved = (state[1] @ dq.unsqueeze(-1)).squeeze(-1)  # the end link's velocity J dq
    assert float(moved.abs().max()) < 1e-3 * float(dq.abs().max())
    for row, joint, sign in ((0, 0, -1.0), (1, 2, 1.0), (2, 4, -1.0)):
        assert sign * float(dq[row, joint]) > 1e-3 * POSTURE * float(high[joint] - low[joint])  # back from it
    assert float(solver._posture(0.5 * (low + high)[None]).abs().max()) < 1e-12  # none in the middle


def test_a_network_without_a_redundant_joint_refuses_a_value_for_one(panda_ckpt):
    from rbfn.checkpoint import model_from_checkpoint
    from rbfn.robots.robot import robot_from_record
    from rbfn.solver import IKSolver

    solver = IKSolver(model_from_checkpoint(panda_ckpt), robot_from_record(panda_ckpt["robot"]))
    x = torch.tensor([[0.3, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    with pytest.raises(ValueError, match=r"redundancy= is not allowed: this network was trained without"):
        solver.solve(x, redundancy=torch.zeros(1, dtype=torch.float64))


def test_the_redundant_export_takes_the_joint_as_its_8th_input(panda7_run):
    ort = pytest.importorskip("onnxruntime")
    import json

    import onnx

    from rbfn.checkpoint import read_checkpoint

    out, _, _ = panda7_run
    meta = {p.key: p.value for p in onnx.load(str(out / "ik.onnx")).metadata_props}
    assert meta["redundancy"] == "panda_joint3" and "poses (B, 8)" in meta["input"]
    x = torch.tensor(json.loads(meta["example_targets"]), dtype=torch.float32)
    assert x.shape == (4, 8)
    from rbfn.export import deployed
    from rbfn.robots.robot import robot_from_record

    robot = robot_from_record(read_checkpoint(out / "checkpoint.pt")["robot"])
    with torch.no_grad():
        q, inside = deployed(load_model(out / "checkpoint.pt"), robot)(x)  # turned about the base, as exported
        plain = load_model(out / "checkpoint.pt")(x)
    sess = ort.InferenceSession(str(out / "ik.onnx"), providers=["CPUExecutionProvider"])
    q_onnx, inside_onnx = sess.run(["joints", "in_workspace"], {"poses": x.numpy()})
    assert torch.allclose(torch.from_numpy(q_onnx), q, atol=1e-4) and inside_onnx.tolist() == inside.tolist()
    assert torch.allclose(q[:, 2], plain[:, 2], atol=0.05)  # the turn about the base leaves joint 3 as given


def test_error_damping_converges_near_the_wrist_singularity_where_gauss_newton_stalls():
    """UR5 poses over the whole joint range, each polished from its exact joints moved by up to
    0.2 rad a joint: the error-dependent damping converges more of them in 5 steps, and is checked."""
    from rbfn.data import full_range_split
    from rbfn.robots.kinematics import joint_limits
    from rbfn.robots.robot import load_robot
    from rbfn.solver import IKSolver
    from rbfn.targets import TargetFeatures

    robot = load_robot(compose_config("train", "robot=ur5").robot)
    low, high = (t[robot.free] for t in joint_limits(robot.chain))
    robot.low, robot.high = low.clone(), high.clone()  # the polish ranges over the URDF limits
    net = RBFNetwork(torch.zeros(1, 9, dtype=torch.float64), torch.ones(1, dtype=torch.float64), 6,
                     inputs=TargetFeatures(True))  # fmt: skip
    split = full_range_split(robot, 1000, 0)
    g = torch.Generator().manual_seed(1)
    start = (split.q + 0.2 * (2 * torch.rand(split.q.shape, generator=g, dtype=torch.float64) - 1)).clamp(low, high)
    rates = {}
    for c in (0.0, 0.01):
        solver = IKSolver(net, robot, base_yaw=False, margin=0.0, error_damping=c)
        rates[c] = float(solver._polish(start, split.x, 5)[1].double().mean())
    assert rates[0.01] >= 0.99 and rates[0.01] > rates[0.0] + 0.01, rates
    with pytest.raises(ValueError, match=r"error_damping=-1 is not allowed"):
        IKSolver(net, robot, error_damping=-1)


@pytest.mark.parametrize("rows", [7, 1500])  # below and from CHOLESKY_ROWS
def test_the_least_norm_step_is_the_damped_pseudo_inverse_step_either_way(rows):
    """`_least_norm` gives J^T (J J^T + lambda I)^-1 e as `torch.linalg.solve` does, below
    `CHOLESKY_ROWS` rows by it and from them by the written-out Cholesky, also where J J^T is
    singular (a 6 x 5 J) and lambda small."""
    from rbfn.solver import CHOLESKY_ROWS, _least_norm

    assert 7 < CHOLESKY_ROWS <= 1500
    g = torch.Generator().manual_seed(0)
    for n in (5, 6, 7):
        jac = torch.randn(rows, 6, n, generator=g, dtype=torch.float64)
        lam = 10.0 ** (-6 * torch.rand(rows, generator=g, dtype=torch.float64) - 2)  # 1e-8 .. 1e-2
        e = torch.randn(rows, 6, generator=g, dtype=torch.float64)
        a = jac @ jac.transpose(1, 2) + lam[:, None, None] * torch.eye(6, dtype=torch.float64)
        want = (jac.transpose(1, 2) @ torch.linalg.solve(a, e.unsqueeze(-1))).squeeze(-1)
        got = _least_norm(jac.permute(1, 2, 0), lam, e)
        assert torch.allclose(got, want, rtol=1e-6, atol=1e-6 * float(want.abs().max()))
