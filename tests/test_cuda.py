"""The device setting end to end (needs a GPU): training on CUDA matches training on CPU, the
charted IK solver solves on CUDA what it solves on CPU, and the realistic closed loop on CUDA
follows the CPU's (its noise is drawn on the CPU: the same numbers on every device)."""

import pytest
import torch

import train

from .conftest import compose_config

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@cuda
@pytest.mark.parametrize("centers", ["aco", "aco_paper", "kmeans_refine", "random", "ols", "cmaes"])
def test_train_on_cuda_matches_cpu(tmp_path, centers):
    over = [
        "data.n_train=400",
        "data.n_val=200",
        "data.n_test=300",
        "rbfn.num_centers=12",
        "rbfn.growth.start=0",
        "centers.aco.iterations=5",
        "centers.refine.full.steps=20",
        "centers.aco.ant_system.candidates=100",
        "centers.ols.candidates=100",
        "progress=false",
        "export=false",
        f"centers={centers}",
    ]
    out = {dev: train.run(compose_config("train", *over, f"device={dev}"), tmp_path / dev) for dev in ("cpu", "cuda")}
    cpu, gpu = out["cpu"]["test_pos_err_mm_median"], out["cuda"]["test_pos_err_mm_median"]
    if centers in ("random", "ols"):  # no search to amplify rounding: the same network
        assert gpu == pytest.approx(cpu, rel=1e-6)
    else:  # a colony's ranking (or refinement) may amplify rounding
        assert gpu == pytest.approx(cpu, rel=0.15)


@cuda
def test_charted_solver_on_cuda_solves_what_it_solves_on_cpu():
    from rbfn.charts import train_charts
    from rbfn.data import full_range_split
    from rbfn.robots.robot import load_robot
    from rbfn.solver import CHARTED_ERROR_DAMPING, IKSolver

    from .test_charts import SMALL

    cfg = compose_config("train", *SMALL)
    model = train_charts(cfg, load_robot(cfg.robot)).model
    x = full_range_split(load_robot(cfg.robot), 2000, 0, evaluation=True).x
    ok, found = {}, {}
    for dev in ("cpu", "cuda"):
        solver = IKSolver(model.to(dev), load_robot(cfg.robot, dev), error_damping=CHARTED_ERROR_DAMPING)
        q, ok[dev] = solver.solve(x.to(dev))
        assert q.device.type == dev
        assert bool(((q >= solver.low) & (q <= solver.high)).all())
        _, converged = solver.solve_all(x[:200].to(dev))
        assert converged.device.type == dev
        found[dev] = converged.sum(-1).double().mean().item()
    assert ok["cuda"].double().mean().item() == pytest.approx(ok["cpu"].double().mean().item(), abs=0.005)
    assert found["cuda"] == pytest.approx(found["cpu"], rel=0.02)


@cuda
@pytest.mark.parametrize("robot", ["scara", "ur5"])
def test_the_realistic_loop_on_cuda_follows_the_cpu(robot):
    from bench.realistic_loop import setup
    from rbfn.control.simulator import simulate

    out = {dev: simulate(**setup(robot, 4, 0.2, dev)) for dev in ("cpu", "cuda")}
    assert out["cuda"].q.device.type == "cuda"
    assert torch.allclose(out["cuda"].q.cpu(), out["cpu"].q, rtol=0, atol=1e-6)
