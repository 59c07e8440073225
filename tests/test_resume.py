"""A killed training run resumes from last.pt and ends with the uninterrupted run's result."""
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import train
from rbfn.checkpoint import load_sealed

from .test_config import CONF

ROOT = Path(__file__).resolve().parents[1]
OVERRIDES = ["data.n_train=400", "data.n_val=200", "data.n_test=200", "rbfn.num_centers=12",
             "rbfn.growth.start=6", "centers.aco.iterations=60", "centers.refine.steps=20", "progress=false",
             "num_threads=1"]


def _cfg(centers):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return OmegaConf.to_object(compose("train", overrides=OVERRIDES + [f"centers={centers}"]))


@pytest.mark.parametrize("centers", ["aco", "aco_paper"])
def test_killed_run_resumes_to_the_same_result(tmp_path, centers):
    reference = train.run(_cfg(centers), tmp_path / "ref")

    run_dir = tmp_path / "interrupted"
    proc = subprocess.Popen([sys.executable, "train.py", *OVERRIDES, f"centers={centers}",
                             f"hydra.run.dir={run_dir}"], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not (run_dir / "last.pt").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert (run_dir / "last.pt").exists(), "the run never wrote its training state"
    killed_state = load_sealed(run_dir / "last.pt")["state"]
    assert killed_state["finished"] is None
    # Killed inside a colony: the resumption continues from a colony snapshot.
    assert killed_state["current"]["colony"]["iteration"] >= 1
    assert not (run_dir / "checkpoint.pt").exists()

    resumed = train.run(_cfg(centers), run_dir)
    for key in ("test_pos_err_mm_median", "test_pos_err_mm_max", "test_joint_rmse", "val_E"):
        assert resumed[key] == reference[key], key
    assert resumed["growth"] == reference["growth"]
    # A finished run directory is left alone on a rerun.
    assert train.run(_cfg(centers), run_dir)["test_pos_err_mm_median"] == reference["test_pos_err_mm_median"]


def test_resume_refuses_a_different_config(tmp_path):
    train.run(_cfg("kmeans"), tmp_path)
    with pytest.raises(ValueError, match="different configuration"):
        train.run(_cfg("random"), tmp_path)
