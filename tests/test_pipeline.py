"""Training's library path: the task Jacobians, the choice of output weights after mini-batch
refinement, and an arm with more free joints than its targets' degrees of freedom refused in every
refinement mode before any work."""

import json
import math

import pytest
import torch

import train
from rbfn import pipeline
from rbfn.data import input_scaling, make_dataset
from rbfn.fit import ROUND_TOL, design_matrix
from rbfn.pipeline import fit_weights, task_jacobians, train_ik
from rbfn.refine import Refined
from rbfn.robots.robot import load_robot
from rbfn.studies import training
from rbfn.targets import TargetFeatures

from .conftest import TINY_TRAIN, compose_config

UR5_SMALL = [
    "robot=ur5",
    "robot.workspace=box",
    "centers=kmeans_refine",
    "rbfn.num_centers=40",
    "data.n_train=800",
    "data.n_val=300",
    "data.n_test=200",
    "centers.refine.mode=minibatch",
    "centers.refine.minibatch.epochs=4",
    "progress=false",
    "export=false",
    "num_threads=1",
]


@pytest.fixture(scope="module")
def ur5():
    cfg = compose_config("train", *UR5_SMALL)
    robot = load_robot(cfg.robot)
    return cfg, robot, make_dataset(robot, (800, 300, 200), seed=0)


def test_task_jacobians_weigh_rotation_rows_by_the_rotation_scale(ur5):
    cfg, robot, data = ur5
    j_tr, j_val = task_jacobians(cfg, robot, data)
    assert j_tr.shape == (800, 6, 6) and j_val.shape == (300, 6, 6)
    raw = robot.chain.jacobian(robot.full_joints(data.val.q))
    assert torch.allclose(j_val[:, :3], raw[:, :3]) and torch.allclose(j_val[:, 3:], 0.3 * raw[:, 3:])
    # First order: J dq is the pose change of a small joint step.
    dq = 1e-6 * torch.ones_like(data.val.q[:5])
    p0, p1 = robot.pose(data.val.q[:5]), robot.pose(data.val.q[:5] + dq)
    assert torch.allclose((j_val[:5, :3] @ dq[..., None])[..., 0], p1[:, :3, 3] - p0[:, :3, 3], atol=1e-11)


def _fit_inputs(cfg, data, m=30):
    features = TargetFeatures(True, cfg.robot.rotation_scale)
    feats = (features(data.train.x), features(data.val.x))
    offset, scale = input_scaling(feats[0], "metres")
    z = (feats[0] - offset) / scale
    centers, widths = z[:m].clone(), torch.full((m,), 0.6, dtype=torch.float64)
    return feats, offset, scale, centers, widths


def test_trained_weights_are_kept_only_where_better_and_stable(ur5):
    cfg, _, data = ur5
    feats, offset, scale, centers, widths = _fit_inputs(cfg, data)
    gen = torch.Generator().manual_seed(0)
    ridge = fit_weights(cfg, data, feats, offset, scale, centers, widths, gen=gen)
    a_val = design_matrix((feats[1] - offset) / scale, centers, widths)
    other = ridge.weights + 1e-3 * torch.randn(ridge.weights.shape, dtype=torch.float64, generator=gen)
    # A loss that prefers `other`'s predictions: its weights are kept, with no ridge.
    target = a_val @ other

    def prefers_other(pred):
        return float((pred - target).abs().mean())

    kept = fit_weights(
        cfg,
        data,
        feats,
        offset,
        scale,
        centers,
        widths,
        gen=gen,
        refined=Refined(centers, widths, scale, 0.0, [], other, prefers_other),
    )
    assert torch.equal(kept.weights, other) and math.isnan(float(kept.ridge)) and kept.rounding <= 2e-6
    assert float(kept.val_mse) == pytest.approx(float(((a_val @ other - data.val.q) ** 2).sum(-1).mean()), rel=1e-4)
    # The plain validation MSE prefers the ridge fit: it stays.
    mse = Refined(centers, widths, scale, 0.0, [], other, lambda p: float(((p - data.val.q) ** 2).sum(-1).mean()))
    assert torch.equal(
        fit_weights(cfg, data, feats, offset, scale, centers, widths, gen=gen, refined=mse).weights, ridge.weights
    )
    # Weights that cancel in float32 (+-1e4 pairs on two equal columns) are refused however good.
    unstable = other.clone()
    unstable[0] += 1e4
    unstable[1] -= 1e4
    c2 = centers.clone()
    c2[1] = c2[0]
    calls = []

    def prefers_trained(pred):  # called with the trained weights' predictions first
        calls.append(1)
        return float(len(calls) > 1)

    kept = fit_weights(
        cfg,
        data,
        feats,
        offset,
        scale,
        c2,
        widths,
        gen=gen,
        refined=Refined(c2, widths, scale, 0.0, [], unstable, prefers_trained),
    )
    assert not torch.equal(kept.weights, unstable) and not math.isnan(float(kept.ridge))
    stable = fit_weights(
        cfg,
        data,
        feats,
        offset,
        scale,
        c2,
        widths,
        gen=gen,
        refined=Refined(c2, widths, scale, 0.0, [], other, prefers_trained),
    )
    assert torch.equal(stable.weights, other)


# The UR5's six free joints for position targets (3 degrees of freedom): many joint vectors per target.
UR5_POSITION = ["robot=ur5", "robot.target=position", *(o for o in TINY_TRAIN if not o.startswith("centers="))]
REFINE_MODES = {
    "full": ["centers=kmeans_refine", "centers.refine.mode=full", "centers.refine.full.steps=5"],
    "minibatch": ["centers=kmeans_refine", "centers.refine.mode=minibatch", "centers.refine.minibatch.epochs=2"],
    "disabled": ["centers=kmeans"],
}
REDUNDANT = (
    r"^robot\.target=position has 3 degrees of freedom but the arm has 6 free joints \['shoulder_pan_joint', "
    r"'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint', 'wrist_2_joint', 'wrist_3_joint'\] "
    r"\(robot\.locked=\{\}\): .* not a function .*; lock 3 of them with robot\.locked "
    r"\(on the command line \+robot\.locked\.NAME=VALUE, one per joint\) and drop their entries from "
    r"robot\.joint_low/joint_high, or use robot\.target=pose \(position and orientation, 6 degrees of freedom\)$"
)


def _no_work(*args, **kwargs):
    raise AssertionError("work started before the check")


@pytest.mark.parametrize("mode", list(REFINE_MODES))
def test_more_free_joints_than_target_dof_is_refused_before_any_work(tmp_path, monkeypatch, mode):
    cfg = compose_config("train", *UR5_POSITION, *REFINE_MODES[mode])
    monkeypatch.setattr(training, "make_dataset", _no_work)
    out = tmp_path / "run"
    with pytest.raises(ValueError, match=REDUNDANT):
        train.run(cfg, out)
    assert not out.exists()  # not even the run directory
    # The library call refuses it too, with the robot or without, before selecting any centre.
    robot = load_robot(cfg.robot)
    data = make_dataset(robot, (20, 10, 10), seed=0)
    monkeypatch.setattr(pipeline, "select", _no_work)
    with pytest.raises(ValueError, match=REDUNDANT):
        train_ik(cfg, data, robot=robot)
    with pytest.raises(ValueError, match=r"has 6 free joints \['joint 1', .*'joint 6'\] .* lock 3 of them"):
        train_ik(cfg, data)


def test_locking_the_extra_joints_trains(tmp_path):
    """The way out: the UR5's wrist held at its home pose, three free joints for three coordinates."""
    wrist = ["+robot.locked.wrist_1_joint=-1.9", "+robot.locked.wrist_2_joint=-1.57", "+robot.locked.wrist_3_joint=0.0"]
    box = ["robot.joint_low=[-1.0,-2.2,0.5]", "robot.joint_high=[1.0,-0.2,2.5]", "robot.home=[]"]
    m = train.run(compose_config("train", *UR5_POSITION, *REFINE_MODES["minibatch"], *wrist, *box), tmp_path)
    assert (tmp_path / "checkpoint.pt").exists() and math.isfinite(m["test_pos_err_mm_median"])


def test_minibatch_run_reports_how_its_weights_were_found(tmp_path):
    m = train.run(compose_config("train", *UR5_SMALL), tmp_path)
    assert m["output_weights"] in ("trained", "ridge")
    assert (m["ridge"] is None) == (m["output_weights"] == "trained")
    joint = train.run(
        compose_config("train", *UR5_SMALL, "centers.refine.minibatch.loss=joint", "centers.refine.minibatch.huber=0"),
        tmp_path / "joint",
    )
    assert joint["test_pos_err_mm_median"] != m["test_pos_err_mm_median"]


def test_metrics_name_the_method_that_chose_the_centres(tmp_path, monkeypatch):
    """`selector` is the configured preset; where the `aco` colony skips itself (M d too large for
    it, the mini-batch refinement next) `centers_chosen_by` says k-means chose them, and why."""
    import rbfn.select

    monkeypatch.setattr(rbfn.select, "FULL_SEARCH_MAX", 0)  # the UR5's M = 2000 case, on a small problem
    m = train.run(compose_config("train", *UR5_SMALL, "centers=aco"), tmp_path)
    assert (m["selector"], m["centers_chosen_by"]) == ("aco", "kmeans")
    assert m["selection_note"].startswith("the colony skipped itself at M = 40 (M * d = 360 > 0)")
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert on_disk["centers_chosen_by"] == "kmeans" and on_disk["selection_note"] == m["selection_note"]
    km = train.run(compose_config("train", *UR5_SMALL), tmp_path / "kmeans")
    assert (km["selector"], km["centers_chosen_by"], km["selection_note"]) == ("kmeans_refine", "kmeans", None)


def test_full_refinement_optimises_the_weights_the_float32_rule_deploys(small_data):
    """The full way's ridge is the float32 rule's (rbfn.refine.refine_full, rbfn.pipeline.float32_rule):
    the network it keeps is the one whose stable fit is best on validation, and the final weights,
    re-solved by that rule from the deployed float32 design, are that fit (the same validation
    error to float32's rounding of the design) and pass the rule."""
    cfg = compose_config(
        "train",
        "centers=kmeans_refine",
        "centers.refine.mode=full",
        "centers.refine.full.steps=30",
        "rbfn.num_centers=20",
        "rbfn.growth.start=0",
        "progress=false",
        "export=false",
    )
    result = train_ik(cfg, small_data)
    assert result.fit.rounding is not None and float(result.fit.rounding) <= ROUND_TOL
    assert result.refine_history[-1] < result.refine_history[0]  # the refinement learned
    assert math.isclose(float(result.fit.val_mse), min(result.refine_history), rel_tol=1e-3)
    x = small_data.test.x
    with torch.no_grad():  # the deployed float32 module agrees with float64 as the exports must
        assert float((result.model.float()(x.float()).double() - result.model.double()(x)).abs().max()) < 1e-5


def test_every_fit_takes_the_float32_rule_with_its_round_rel():
    from rbfn.fit import RoundingRule

    assert pipeline.float32_rule(compose_config("train", "rbfn.round_rel=0.001")) == RoundingRule(
        torch.float32, ROUND_TOL, 0.001
    )
