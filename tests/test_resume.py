"""An interrupted training run resumes from last.pt and ends with the uninterrupted run's result,
wherever it was interrupted.

Interruptions are injected deterministically in this process: `Stopped` (what SIGTERM becomes in
train.py, rbfn.studies.stop) raised before or after the Nth call of a step, while a file is being
written (just before its temporary file would be renamed into place), or right after the state
file saved the running colony's snapshot of iteration K. The rerun must end with the
uninterrupted run's checkpoint weights and metrics bit for bit (wall-clock seconds aside), and no
temporary file may be left. One test stops a real `python train.py` with SIGTERM.
"""

import importlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

import rbfn.studies.training
import train
from rbfn.checkpoint import load_sealed
from rbfn.resume import StateFile
from rbfn.studies.stop import Stopped

from .conftest import ROOT, compose_config

OVERRIDES = [
    "data.n_train=400",
    "data.n_val=200",
    "data.n_test=200",
    "rbfn.num_centers=12",
    "rbfn.growth.start=6",
    "centers.aco.iterations=12",
    "centers.refine.full.steps=20",
    "progress=false",
    "num_threads=1",
    "export=false",
]
# Every step of training, small: two growth steps of a colony, refinement (and the exports where
# a point concerns them: they take most of such a run's time).
POINT_RUN = [
    "data.n_train=300",
    "data.n_val=200",
    "data.n_test=200",
    "rbfn.num_centers=10",
    "rbfn.growth.start=5",
    "centers.aco.iterations=5",
    "centers.refine.full.steps=10",
    "progress=false",
    "num_threads=1",
    "export=false",
]
RUN_FILES = {".hydra/config.yaml": "seed: 0\n"}


def _timeless(m):
    """Metrics without their wall-clock seconds."""
    if isinstance(m, dict):
        return {k: _timeless(v) for k, v in m.items() if "seconds" not in k}
    if isinstance(m, list):
        return [_timeless(v) for v in m]
    return m


def _outcome(run_dir: Path) -> tuple[dict, dict, dict]:
    """(checkpoint state_dict, checkpoint metrics, metrics.json), seconds aside."""
    ckpt = load_sealed(run_dir / "checkpoint.pt")
    return ckpt["state_dict"], _timeless(ckpt["metrics"]), _timeless(json.loads((run_dir / "metrics.json").read_text()))


def _assert_same_outcome(run_dir: Path, ref_dir: Path) -> None:
    sd, metrics, on_disk = _outcome(run_dir)
    ref_sd, ref_metrics, ref_on_disk = _outcome(ref_dir)
    assert sd.keys() == ref_sd.keys()
    for k in sd:
        assert sd[k].dtype == ref_sd[k].dtype and torch.equal(sd[k], ref_sd[k]), k
    assert metrics == ref_metrics and on_disk == ref_on_disk


def _stop(monkeypatch, how: str, target: str, when) -> None:
    """Raise Stopped(SIGTERM) `how` = "before" or "after" the `when`-th call of function `target`
    (module.name), or, `how` = "writing", when a file named `target` is about to replace its old
    version (`when`: the Nth such write, or a test of its path)."""
    calls = []

    def due(*args) -> bool:
        calls.append(args)
        return len(calls) == when if isinstance(when, int) else when(*args)

    if how == "writing":
        replace = os.replace

        def replacing(src, dst, *a, **kw):
            if Path(dst).name == target and due(Path(dst)):
                raise Stopped(signal.SIGTERM)
            return replace(src, dst, *a, **kw)

        monkeypatch.setattr(os, "replace", replacing)
        return
    module, name = target.rsplit(".", 1)
    real = getattr(importlib.import_module(module), name)

    def stopping(*args, **kwargs):
        if how == "before" and due():
            raise Stopped(signal.SIGTERM)
        out = real(*args, **kwargs)
        if how == "after" and due():
            raise Stopped(signal.SIGTERM)
        return out

    monkeypatch.setattr(target, stopping)


def _finished_state_write(path: Path) -> bool:
    return (path.parent / "metrics.json").exists()


EXPORTS = ["export=true"]
POINTS = [
    pytest.param("before", "rbfn.pipeline.select", 1, [], id="data made, nothing saved yet"),
    pytest.param("writing", "config.yaml", 1, [], id="writing .hydra"),
    pytest.param("writing", "last.pt", 1, [], id="writing the first colony snapshot"),
    pytest.param("before", "rbfn.pipeline.fit_weights", 1, [], id="colony ended, its step not saved"),
    pytest.param("before", "rbfn.pipeline.select", 2, [], id="between growth steps"),
    pytest.param("before", "rbfn.pipeline.refine", 1, [], id="growth done, before refinement"),
    pytest.param("after", "rbfn.pipeline.refine", 1, [], id="refined, before the final weights"),
    pytest.param("writing", "checkpoint.pt", 1, [], id="writing checkpoint.pt"),
    pytest.param("after", "rbfn.studies.ik.save_checkpoint", 1, EXPORTS, id="checkpoint written, before the exports"),
    pytest.param("writing", "ik.pt2", 1, EXPORTS, id="writing ik.pt2"),
    pytest.param("writing", "metrics.json", 1, [], id="writing metrics.json"),
    pytest.param("after", "rbfn.studies.ik.write_json", 1, [], id="metrics.json written, run not marked finished"),
    pytest.param("writing", "last.pt", _finished_state_write, [], id="writing the finished state"),
]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """reference(extra): the directory of the uninterrupted run with overrides `extra`."""
    made = {}

    def run_dir(extra: list[str]) -> Path:
        if tuple(extra) not in made:
            made[tuple(extra)] = out = tmp_path_factory.mktemp("reference")
            train.run(compose_config("train", *POINT_RUN, *extra), out, RUN_FILES)
        return made[tuple(extra)]

    return run_dir


@pytest.mark.parametrize("how,target,when,extra", POINTS)
def test_a_rerun_after_any_interruption_ends_as_an_uninterrupted_run(
    reference, tmp_path, monkeypatch, how, target, when, extra
):
    with monkeypatch.context() as mp:
        _stop(mp, how, target, when)
        with pytest.raises(Stopped):
            train.run(compose_config("train", *POINT_RUN, *extra), tmp_path, RUN_FILES)
    assert not list(tmp_path.rglob("*.tmp"))
    state = load_sealed(tmp_path / "last.pt")["state"] if (tmp_path / "last.pt").exists() else None
    assert state is None or state["finished"] is None  # interrupted before the end
    train.run(compose_config("train", *POINT_RUN, *extra), tmp_path, RUN_FILES)
    _assert_same_outcome(tmp_path, reference(extra))


def test_a_run_interrupted_again_and_again_ends_as_an_uninterrupted_run(reference, tmp_path, monkeypatch):
    """Each rerun interrupted at a later point than the one before (resuming, then stopped again)."""
    for how, target, when in [
        ("writing", "last.pt", 1),
        ("before", "rbfn.pipeline.select", 1),
        ("after", "rbfn.pipeline.fit_weights", 1),
        ("after", "rbfn.pipeline.refine", 1),
        ("after", "rbfn.studies.ik.write_json", 1),
    ]:
        with monkeypatch.context() as mp:
            _stop(mp, how, target, when)
            with pytest.raises(Stopped):
                train.run(compose_config("train", *POINT_RUN), tmp_path, RUN_FILES)
    train.run(compose_config("train", *POINT_RUN), tmp_path, RUN_FILES)
    _assert_same_outcome(tmp_path, reference([]))
    assert not list(tmp_path.rglob("*.tmp"))


class Interrupted(Exception):
    pass


def _interrupt_at(num_centers: int, iteration: int):
    class Interrupting(StateFile):
        def __init__(self, run_dir):
            super().__init__(run_dir, every=0.0)  # save every snapshot

        def save(self, state, force=True):
            super().save(state, force)
            colony = (state.current or {}).get("colony")
            if (
                state.current
                and state.current["num_centers"] == num_centers
                and colony
                and colony["iteration"] >= iteration
            ):
                raise Interrupted

    return Interrupting


# (centres, M, colony iteration): mid-colony, and the colony's last snapshot (it had ended, its
# growth step not yet saved).
@pytest.mark.parametrize(
    "centers,m,k", [("aco", 6, 4), ("aco", 12, 4), ("aco_paper", 6, 4), ("aco_paper", 12, 4), ("aco", 12, 12)]
)
def test_interrupted_run_resumes_to_the_same_result(tmp_path, monkeypatch, centers, m, k):
    cfg = compose_config("train", *OVERRIDES, f"centers={centers}")
    reference = train.run(cfg, tmp_path / "ref")

    run_dir = tmp_path / "interrupted"
    with monkeypatch.context() as mp:
        mp.setattr(rbfn.studies.training, "StateFile", _interrupt_at(m, k))
        with pytest.raises(Interrupted):
            train.run(compose_config("train", *OVERRIDES, f"centers={centers}"), run_dir)
    state = load_sealed(run_dir / "last.pt")["state"]
    assert state["finished"] is None and not (run_dir / "checkpoint.pt").exists()
    assert state["current"]["num_centers"] == m and state["current"]["colony"]["iteration"] == k
    assert [d["num_centers"] for d in state["done"]] == ([6] if m == 12 else [])

    resumed = train.run(compose_config("train", *OVERRIDES, f"centers={centers}"), run_dir)
    assert _timeless(resumed) == _timeless(reference)
    _assert_same_outcome(run_dir, tmp_path / "ref")
    # Time is counted over both processes.
    assert resumed["train_seconds"] >= resumed["select_seconds"] > 0
    # A finished run directory is left alone on a rerun.
    assert train.run(cfg, run_dir) == resumed


def test_resume_refuses_a_different_config(tmp_path):
    train.run(compose_config("train", *OVERRIDES, "centers=kmeans"), tmp_path)
    with pytest.raises(ValueError, match="different configuration"):
        train.run(compose_config("train", *OVERRIDES, "centers=random"), tmp_path)


def test_train_stopped_by_sigterm_mid_colony_resumes_to_the_same_result(tmp_path):
    """SIGTERM to `python train.py` once its colony saved a snapshot: exit status 143, no temporary
    file, and the rerun ends as the uninterrupted run (here in this process) does."""
    over = [*OVERRIDES, "centers.aco.iterations=400", "rbfn.growth.start=0"]
    args = [sys.executable, "train.py", *over, f"hydra.run.dir={tmp_path / 'run'}"]
    with open(tmp_path / "out.log", "w") as out:
        proc = subprocess.Popen(args, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while not (tmp_path / "run" / "last.pt").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 128 + signal.SIGTERM, (tmp_path / "out.log").read_text()[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    state = load_sealed(tmp_path / "run" / "last.pt")["state"]
    assert state["finished"] is None and state["current"]["colony"] is not None
    assert not list((tmp_path / "run").rglob("*.tmp"))
    r = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0 and "resuming from" in r.stdout + r.stderr, r.stderr[-3000:]
    train.run(compose_config("train", *over), tmp_path / "ref")
    _assert_same_outcome(tmp_path / "run", tmp_path / "ref")


def _finished_run(tmp_path) -> Path:
    run_dir = tmp_path / "finished"
    train.run(compose_config("train", *OVERRIDES, "centers=kmeans"), run_dir, RUN_FILES)
    return run_dir


def _files(run_dir: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run_dir)): p.read_bytes() for p in sorted(run_dir.rglob("*")) if p.is_file()}


@pytest.mark.parametrize(
    "remove,copy",
    [
        pytest.param(["last.pt"], [], id="finished run without its last.pt"),
        pytest.param(["last.pt", "metrics.json"], [], id="a checkpoint alone"),
        pytest.param(["last.pt", "checkpoint.pt"], [], id="a training metrics.json alone"),
        pytest.param([], ["checkpoint.pt"], id="a copied checkpoint in a new folder"),
    ],
)
def test_results_without_their_state_are_never_written_over(tmp_path, remove, copy):
    """Every file a finished run wrote decides ownership, not last.pt alone: a directory holding
    results without the state saying whose they are is refused, and left exactly as it was."""
    finished = _finished_run(tmp_path)
    run_dir = tmp_path / "target"
    if copy:
        run_dir.mkdir()
        for name in copy:
            (run_dir / name).write_bytes((finished / name).read_bytes())
    else:
        finished.rename(run_dir)
        for name in remove:
            (run_dir / name).unlink()
    before = _files(run_dir)
    with pytest.raises(ValueError, match="no training state"):
        train.run(compose_config("train", *OVERRIDES, "centers=kmeans", "seed=1"), run_dir, RUN_FILES)
    assert _files(run_dir) == before


def test_a_finished_run_missing_an_output_is_neither_done_nor_refilled(tmp_path):
    run_dir = _finished_run(tmp_path)
    (run_dir / "checkpoint.pt").unlink()
    before = _files(run_dir)
    with pytest.raises(ValueError, match=r"finished run with this config whose checkpoint.pt is missing"):
        train.run(compose_config("train", *OVERRIDES, "centers=kmeans"), run_dir, RUN_FILES)
    assert _files(run_dir) == before


def test_another_configs_composed_config_is_not_written_over(tmp_path):
    """A run stopped before its first result leaves its .hydra/config.yaml only: the same config
    starts again there, another is refused."""
    run_dir = tmp_path / "run"
    (run_dir / ".hydra").mkdir(parents=True)
    (run_dir / ".hydra" / "config.yaml").write_text("seed: 1\nnum_threads: 2\n")
    with pytest.raises(ValueError, match="different configuration"):
        train.run(compose_config("train", *OVERRIDES, "centers=kmeans"), run_dir, RUN_FILES)
    assert (run_dir / ".hydra" / "config.yaml").read_text() == "seed: 1\nnum_threads: 2\n"
    (run_dir / ".hydra" / "config.yaml").write_text("seed: 0\nnum_threads: 2\n")  # differs in a free key only
    train.run(compose_config("train", *OVERRIDES, "centers=kmeans"), run_dir, RUN_FILES)
    assert (run_dir / "checkpoint.pt").is_file()


def test_the_working_directory_is_not_a_run_directory(tmp_path):
    """`hydra.run.dir=''` names the working directory: it holds files no run wrote, so it is refused
    with one line and nothing is written into it."""
    (tmp_path / "README.md").write_text("mine\n")
    r = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), *OVERRIDES, "hydra.run.dir=''"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert r.returncode == 1 and r.stderr.strip().count("\n") == 0, r.stderr[-3000:]
    assert "no training state (last.pt)" in r.stderr
    assert sorted(os.listdir(tmp_path)) == ["README.md"]
