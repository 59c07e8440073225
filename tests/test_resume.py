"""An interrupted training run resumes from last.pt and ends with the uninterrupted run's result.

The interruption is injected deterministically: the state file raises right after it has saved
the running colony's snapshot of iteration K, as if the process had been killed there.
"""
import pytest

import train
from rbfn.checkpoint import load_sealed
from rbfn.resume import StateFile

from .conftest import compose_config

OVERRIDES = ["data.n_train=400", "data.n_val=200", "data.n_test=200", "rbfn.num_centers=12",
             "rbfn.growth.start=6", "centers.aco.iterations=12", "centers.refine.steps=20", "progress=false",
             "num_threads=1", "export=false"]


class Interrupted(Exception):
    pass


def _interrupt_at(num_centers: int, iteration: int):
    class Interrupting(StateFile):
        def __init__(self, run_dir):
            super().__init__(run_dir, every=0.0)          # save every snapshot

        def save(self, state, force=True):
            super().save(state, force)
            colony = (state.current or {}).get("colony")
            if state.current and state.current["num_centers"] == num_centers and colony \
                    and colony["iteration"] >= iteration:
                raise Interrupted
    return Interrupting


@pytest.mark.parametrize("centers", ["aco", "aco_paper"])
@pytest.mark.parametrize("m", [6, 12])
def test_interrupted_run_resumes_to_the_same_result(tmp_path, monkeypatch, centers, m):
    cfg = compose_config("train", *OVERRIDES, f"centers={centers}")
    reference = train.run(cfg, tmp_path / "ref")

    run_dir = tmp_path / "interrupted"
    with monkeypatch.context() as mp:
        mp.setattr(train, "StateFile", _interrupt_at(m, 4))
        with pytest.raises(Interrupted):
            train.run(compose_config("train", *OVERRIDES, f"centers={centers}"), run_dir)
    state = load_sealed(run_dir / "last.pt")["state"]
    assert state["finished"] is None and not (run_dir / "checkpoint.pt").exists()
    assert state["current"]["num_centers"] == m and state["current"]["colony"]["iteration"] == 4
    assert [d["num_centers"] for d in state["done"]] == ([6] if m == 12 else [])

    resumed = train.run(compose_config("train", *OVERRIDES, f"centers={centers}"), run_dir)
    for key in ("test_pos_err_mm_median", "test_pos_err_mm_max", "test_joint_rmse", "val_E"):
        assert resumed[key] == reference[key], key
    assert resumed["growth"] == reference["growth"]
    # Time is counted over both processes.
    assert resumed["train_seconds"] >= resumed["select_seconds"] > 0
    # A finished run directory is left alone on a rerun.
    assert train.run(cfg, run_dir) == resumed


def test_resume_refuses_a_different_config(tmp_path):
    train.run(compose_config("train", *OVERRIDES, "centers=kmeans"), tmp_path)
    with pytest.raises(ValueError, match="different configuration"):
        train.run(compose_config("train", *OVERRIDES, "centers=random"), tmp_path)
