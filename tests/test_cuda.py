"""The device setting end to end: training on CUDA matches training on CPU (needs a GPU)."""

import pytest
import torch

import train

from .conftest import compose_config

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@cuda
@pytest.mark.parametrize("centers", ["aco", "aco_paper", "kmeans_refine", "random", "ols"])
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
