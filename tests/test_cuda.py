"""The device setting end to end: training on CUDA matches training on CPU (needs a GPU)."""
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import train

from .test_config import CONF

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@cuda
@pytest.mark.parametrize("centers", ["aco", "aco_paper", "kmeans_refine", "random", "ols"])
def test_train_on_cuda_matches_cpu(tmp_path, centers):
    over = ["data.n_train=400", "data.n_val=200", "data.n_test=300", "rbfn.num_centers=12",
            "rbfn.growth.start=0", "centers.aco.iterations=5", "centers.refine.steps=20",
            "centers.aco.candidates=100", "progress=false", f"centers={centers}"]
    out = {}
    for dev in ("cpu", "cuda"):
        with initialize_config_dir(config_dir=CONF, version_base="1.3"):
            cfg = OmegaConf.to_object(compose("train", overrides=over + [f"device={dev}"]))
        out[dev] = train.run(cfg, tmp_path / dev)
    # Same seeds and float64 arithmetic: results agree up to reduction-order rounding, which
    # ACO's ranking may amplify; both must be accurate.
    assert out["cuda"]["test_pos_err_mm_median"] < 2 * out["cpu"]["test_pos_err_mm_median"] + 1.0
