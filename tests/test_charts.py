"""IK over the whole joint range (rbfn.charts): the charts' batched answers are each chart network's,
a small charted UR5 network solves poses drawn over the whole URDF range within its limits,
`solve_all` returns distinct solutions that reach the target, `near` keeps the answer on its branch,
and the charted checkpoint round-trips through `load_solver`."""

import math
from dataclasses import replace

import pytest
import torch

from rbfn.charts import GATE_CENTRES, ChartedIK, decode, embed, encode, save_charts, summarise, train_charts
from rbfn.checkpoint import check_charts, load_model, read_checkpoint
from rbfn.data import full_range_split
from rbfn.layer import RBFNetwork
from rbfn.robots.robot import load_robot
from rbfn.solver import IKSolver, load_solver
from rbfn.targets import TargetFeatures

from .conftest import compose_config

SMALL = [
    "robot=ur5",
    "robot.workspace=full",
    "robot.charts=8",
    "robot.chart_centers=60",
    "robot.chart_samples=400",
    "centers=kmeans",
    "progress=false",
]


@pytest.fixture(scope="module")
def charted():
    cfg = compose_config("train", *SMALL)
    robot = load_robot(cfg.robot)
    model = train_charts(cfg, robot).model
    return cfg, robot, model


def _solver(robot, model):
    return IKSolver(model, robot, error_damping=0.01)


def test_answers_are_each_chart_networks_answer_padded_or_not():
    g = torch.Generator().manual_seed(0)
    nets = []
    for m in (5, 9):  # charts of different sizes: the smaller padded
        net = RBFNetwork(
            torch.randn(m, 9, generator=g, dtype=torch.float64),
            0.5 + torch.rand(m, generator=g, dtype=torch.float64),
            12,
            inputs=TargetFeatures(pose=True, dtype=torch.float64),
        )
        torch.nn.init.normal_(net.head.weight, generator=g)
        nets.append(net.requires_grad_(False))
    revolute = torch.ones(6, dtype=torch.bool)
    low, high = torch.full((6,), -math.pi), torch.full((6,), math.pi)
    model = ChartedIK(nets, torch.zeros(2, 12), revolute, low, high).double()
    robot = load_robot(compose_config("train", "robot=ur5").robot)
    x = full_range_split(robot, 50, 0).x
    q, close = model.answers(x)
    for k, net in enumerate(nets):
        assert torch.allclose(q[:, k], decode(net(x), revolute), atol=1e-9)
        z = (net._feat(x) - net.offset) / net.scale
        assert torch.allclose(close[:, k], torch.cdist(z, net.centers).amin(-1) / net.cover_radius)


def test_an_angle_whose_range_reaches_past_half_a_turn_decodes_onto_that_range():
    """A revolute joint's range may reach past +-pi (the KUKA KR10's second joint, -190 .. 45 deg; the
    Panda's sixth, -1 .. 215 deg): decoded within half a turn of its range's middle, every angle of
    the range comes back as itself; decoded in (-pi, pi], the part past it lands on the other end."""
    low = torch.tensor([-3.316, -0.0175, -1.0], dtype=torch.float64)
    high = torch.tensor([0.785, 3.7525, 1.0], dtype=torch.float64)
    revolute = torch.tensor([True, True, False])
    q = low + (high - low) * torch.rand(2000, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    y = encode(q, revolute)
    assert torch.allclose(decode(y, revolute, (0.5 * (low + high)).tolist()), q, atol=1e-12)
    past = (q[:, :2] < -math.pi) | (q[:, :2] > math.pi)
    assert past.any() and not torch.isclose(decode(y, revolute)[:, :2], q[:, :2])[past].any()
    # a chart that answers one joint vector whatever the pose (its head's bias): it comes back as itself
    net = RBFNetwork(torch.zeros(1, 9, dtype=torch.float64), torch.ones(1, dtype=torch.float64), 5,
                     inputs=TargetFeatures(pose=True, dtype=torch.float64), tail=False)  # fmt: skip
    three = torch.tensor([[-3.2, 3.6, 0.5]], dtype=torch.float64)  # past -pi, past pi, a slide
    with torch.no_grad():
        net.head.weight.zero_()
        net.head.bias.copy_(encode(three, revolute)[0])
    model = ChartedIK([net.requires_grad_(False)], torch.zeros(1, 5), revolute, low, high).double()
    x = full_range_split(load_robot(compose_config("train", "robot=ur5").robot), 4, 0).x
    assert torch.allclose(model.answers(x)[0][:, 0], three.expand(4, 3), atol=1e-9)


def test_charted_network_solves_whole_range_poses_within_the_limits(charted):
    _, robot, model = charted
    solver = _solver(robot, model)
    split = full_range_split(robot, 200, 3)
    q, ok = solver.solve(split.x)
    assert ok.double().mean() > 0.5  # 8 small charts: most poses anywhere, against ~5 % for one box
    assert bool(((q >= solver.low) & (q <= solver.high)).all())
    pos, rot = robot.errors(q[ok], split.x[ok])
    assert float(pos.max()) <= 0.1 and float(rot.max()) <= 0.1  # converged means reached


def test_a_charted_solve_in_small_blocks_answers_as_in_one(charted):
    """The charts' rounds polish in blocks of `block_rows` answers; each target's answer is its own
    (to the float32 chart answers' rounding, which differs with the block's shape: a polish stops where
    its path enters the tolerances, so the same answer may stop a few 1e-4 rad apart)."""
    _, robot, model = charted
    x = full_range_split(robot, 120, 7).x
    solver = _solver(robot, model)
    q, ok = solver.solve(x)
    solver.block_rows = 7
    q7, ok7 = solver.solve(x)
    assert torch.equal(ok, ok7) and torch.allclose(q, q7, atol=1e-3)


def test_solve_all_returns_distinct_solutions_that_reach_the_target(charted):
    _, robot, model = charted
    split = full_range_split(robot, 40, 4)
    q, ok = _solver(robot, model).solve_all(split.x)
    assert q.shape == (40, 8, 6) and ok.shape == (40, 8)
    assert float(ok.sum(1).double().mean()) > 1.5  # several branches a pose
    assert bool(torch.isnan(q[~ok]).all()) and bool((ok[:, :-1] >= ok[:, 1:]).all())  # found ones first
    rows, cols = ok.nonzero(as_tuple=True)
    pos, rot = robot.errors(q[rows, cols], split.x[rows])
    assert float(pos.max()) <= 0.1 and float(rot.max()) <= 0.1
    for b in range(40):
        e = embed(q[b, ok[b]], model.revolute, model.low, model.high)
        d = torch.cdist(e, e) + 10 * torch.eye(e.shape[0])
        assert e.shape[0] < 2 or float(d.min()) > 1e-3


def test_near_keeps_the_answer_on_the_current_branch_and_turn(charted):
    _, robot, model = charted
    split = full_range_split(robot, 100, 5)
    near = split.q + 2 * math.pi * (split.q < -2.0)  # some joints a whole turn up, still within +-2 pi
    q, ok = _solver(robot, model).solve(split.x, near=near)
    assert bool(ok.all())  # `near` itself is a solution, polished from where it is
    assert float((q - near).abs().max()) < 1e-3


def test_where_near_does_not_converge_the_answer_is_the_converged_one_nearest_it(charted):
    """The targets `near` itself does not reach try every chart: the answer is no farther from
    `near` than the one `solve` without it gives, brought its whole turns nearest `near`."""
    _, robot, model = charted
    split = full_range_split(robot, 100, 11)
    solver = _solver(robot, model)
    far = full_range_split(robot, 100, 12).q  # joints of other poses: mostly too far to polish
    q, ok = solver.solve(split.x, near=far)
    alone, ok_alone = solver.solve(split.x)
    _, near_ok = solver._polish(far.clamp(solver.low, solver.high), split.x, solver.default_iterations, settle=True)
    rows = (~near_ok & ok_alone).nonzero().squeeze(-1)
    assert rows.numel() > 20 and bool(ok[rows].all())
    width = solver.box_high - solver.box_low
    d = ((q[rows] - far[rows]) / width).norm(dim=-1)
    d_alone = ((solver._turned(alone[rows], far[rows]) - far[rows]) / width).norm(dim=-1)
    # (to the polish's stopping point: each stops once within the tolerances, where its batch left it)
    assert bool((d <= d_alone + 5e-3).all()) and float(d.mean()) < float(d_alone.mean())


def test_charted_checkpoint_round_trips_through_load_solver(charted, tmp_path):
    _, robot, model = charted
    path = tmp_path / "charts.pt"
    save_charts(path, model, robot.record(), {"seed": 0}, {"m": 1.0})
    ckpt = read_checkpoint(path)
    assert ckpt["kind"] == "rbfn-ik-charts" and len(ckpt["networks"]) == 8
    with pytest.raises(ValueError, match=r"charted network \(robot\.workspace=full\): rbfn\.load_solver"):
        load_model(path)
    solver = load_solver(path)
    assert solver.charted and solver.error_damping > 0
    x = full_range_split(robot, 30, 6).x
    assert torch.allclose(solver.model.answers(x)[0], model.double().answers(x)[0], atol=1e-9)
    broken = {**ckpt, "networks": ckpt["networks"][:3]}
    with pytest.raises(ValueError, match="one network per chart"):
        check_charts(broken, path)


def test_frozen_copy_answers_as_the_model_does(charted):
    """`ChartedIK.frozen` (the solver's and the exporters' form: parameters stacked once) answers
    as the model in the same dtype, and `answer_rows` (one piece) as `answers` (blocks)."""
    _, robot, model = charted
    x = full_range_split(robot, 40, 8).x
    frozen = model.frozen(torch.float64)
    q, close = model.double().answers(x)
    q2, close2 = frozen.answers(x)
    assert torch.equal(q, q2) and torch.equal(close, close2)
    q3, _ = frozen.answer_rows(x)
    assert torch.allclose(q3, q, atol=1e-12)


def test_ranked_orders_the_charts_by_their_summarised_centres_and_chart_answers_are_theirs(charted):
    """`ranked`'s one product gives each chart's distance to its summary centres over its cover
    radius, as computed directly; `chart_answers` is the asked chart's column of `answers`."""
    _, robot, model = charted
    x = full_range_split(robot, 60, 9).x
    frozen = model.frozen(torch.float64)
    summary = frozen._gate_centres()
    direct = []
    for k, net in enumerate(frozen.nets):
        z = (net._feat(x) - net.offset) / net.scale
        direct.append(torch.cdist(z, summary[k]).amin(-1) / net.cover_radius)
    want = torch.stack(direct, -1).argsort(1)
    assert torch.equal(frozen.ranked(x, 8), want) and torch.equal(frozen.ranked(x, 3), want[:, :3])
    assert frozen.ranked(x[:0], 3).shape == (0, 3)
    charts = torch.arange(60) % 8
    q, _ = frozen.answers(x)
    assert torch.allclose(frozen.chart_answers(x, charts), q[torch.arange(60), charts], atol=1e-12)
    with pytest.raises(RuntimeError, match="frozen copy"):
        model.ranked(x, 3)


def test_summarise_covers_the_points_better_than_a_random_subset():
    g = torch.Generator().manual_seed(0)
    points = torch.cat([torch.randn(100, 3, generator=g, dtype=torch.float64) + 10 * i for i in range(4)])
    c = summarise(points, GATE_CENTRES)
    assert c.shape == (GATE_CENTRES, 3) and torch.equal(c, summarise(points, GATE_CENTRES))
    inertia = lambda centres: float(torch.cdist(points, centres).amin(1).square().mean())  # noqa: E731
    subsets = [points[torch.randperm(400, generator=g)[:GATE_CENTRES]] for _ in range(20)]
    assert inertia(c) < 0.8 * min(inertia(s) for s in subsets)
    assert set(torch.cdist(c, points).argmin(1).div(100, rounding_mode="floor").tolist()) == {0, 1, 2, 3}


def test_the_export_command_reads_a_charted_checkpoint(charted, tmp_path):
    """`python -m rbfn.export` rebuilds a charted checkpoint's network and robot (the exports
    themselves: tests/studies/test_charted_runs.py)."""
    import argparse

    from rbfn.export import _network

    _, robot, model = charted
    path = tmp_path / "charts.pt"
    save_charts(path, model, robot.record(), {"seed": 0}, {"m": 1.0})
    net, again = _network(argparse.ArgumentParser(), str(path))
    assert isinstance(net, ChartedIK) and net.num_charts == 8 and again.joint_names == robot.joint_names


def test_train_charts_refuses_bad_chart_settings(charted):
    _, robot, _ = charted
    for key, value in (("robot.charts", 0), ("robot.chart_centers", 0), ("robot.chart_samples", 5)):
        bad = compose_config("train", *SMALL, f"{key}={value}")
        with pytest.raises(ValueError, match=rf"{key}.*must be an integer"):
            train_charts(bad, robot)


def test_charts_skip_the_refinement_unless_asked_and_never_take_the_task_loss(caplog):
    from rbfn.charts import chart_config
    from rbfn.config import RefineLoss

    refined = compose_config("train", *SMALL, "centers.refine.enabled=true", "centers.refine.minibatch.loss=task")
    with caplog.at_level("INFO"):
        cfg = chart_config(refined)
    assert not cfg.centers.refine.enabled and "refine.enabled = false" in caplog.text  # robot.chart_refine=false
    assert cfg.rbfn.num_centers == 60 and cfg.rbfn.growth.start == 0
    with caplog.at_level("INFO"):
        cfg = chart_config(replace(refined, robot=replace(refined.robot, chart_refine=True)))
    assert cfg.centers.refine.enabled and cfg.centers.refine.minibatch.loss == RefineLoss.joint
    assert "loss = joint" in caplog.text
