"""Hydra multiruns end to end: the joblib launcher, a failed job among others, the summary table,
a multirun stopped by SIGTERM, the Optuna search preset and TensorBoard's HParams view.

Each test runs `python train.py -m ...` as a user would, in a subprocess, with small data sets.
"""

import contextlib
import json
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from rbfn.config import SELECTORS

ROOT = Path(__file__).resolve().parents[1]
FAST = [
    "data.n_train=300",
    "data.n_val=150",
    "data.n_test=300",
    "rbfn.growth.start=0",
    "export=false",
    "progress=false",
    "num_threads=1",
]


def _python(*args: str, timeout: float = 120) -> str:
    """Run `python ARGS` in the repository root; return stdout, or fail showing stderr."""
    r = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"python {' '.join(args)} exited {r.returncode}:\n{r.stderr[-3000:]}"
    return r.stdout


@pytest.fixture(scope="module")
def joblib_sweep(tmp_path_factory):
    """A 2 x 2 multirun (k-means, random) x (M = 10, 20) on two joblib workers."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    sweep = tmp_path_factory.mktemp("sweep")
    _python(
        "train.py",
        "-m",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
        "centers=kmeans,random",
        "rbfn.num_centers=10,20",
        *FAST,
        f"hydra.sweep.dir={sweep}",
    )
    return sweep


def test_joblib_multirun_writes_every_job_and_summarizes(joblib_sweep):
    jobs = sorted(p for p in joblib_sweep.iterdir() if p.is_dir())
    assert [p.name for p in jobs] == ["0", "1", "2", "3"]
    for job in jobs:
        assert (job / "checkpoint.pt").is_file(), job
        assert list(job.glob("events.out.tfevents.*")), job
        assert json.loads((job / "metrics.json").read_text())["test_pos_err_mm_median"] > 0
    out = _python("-m", "rbfn.studies.summarize", str(joblib_sweep))
    rows = [line for line in out.splitlines() if line.startswith(("| kmeans |", "| random |"))]
    assert len(rows) == 4, out
    assert (joblib_sweep / "summary.md").is_file() and (joblib_sweep / "summary.png").is_file()


def test_a_failed_job_does_not_stop_the_others_and_is_summarized(tmp_path):
    """Job 1 fails validation; jobs 0 and 2 still complete, and the summary lists job 1's error."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    r = subprocess.run(
        [
            sys.executable,
            "train.py",
            "-m",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            "centers=kmeans",
            "rbfn.num_centers=10,100000,20",
            *FAST,
            f"hydra.sweep.dir={tmp_path}",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    bad = "rbfn.num_centers=100000 is not allowed: exceeds the training set size data.n_train=300"
    assert r.returncode != 0 and bad in r.stderr, r.stderr[-3000:]  # the multirun reports it
    for job in ("0", "2"):
        assert json.loads((tmp_path / job / "metrics.json").read_text())["test_pos_err_mm_median"] > 0
    failed = json.loads((tmp_path / "1" / "failed.json").read_text())
    assert failed["error"] == "ValueError" and bad in failed["message"]
    assert "rbfn.num_centers=100000" in failed["overrides"]
    assert f"job failed: ValueError: {bad}" in (tmp_path / "1" / "train.log").read_text()
    out = _python("-m", "rbfn.studies.summarize", str(tmp_path))
    assert f"| 1 | failed | rbfn.num_centers=100000 | ValueError: {bad}" in out, out
    assert "3 jobs: 2 completed, 1 failed, 0 unfinished" in out
    assert [line.split("|")[1].strip() for line in out.splitlines() if line.startswith(("| 10 |", "| 20 |"))] == [
        "10",
        "20",
    ]


def test_sigterm_to_a_joblib_multirun_stops_its_workers(tmp_path):
    """SIGTERM to the multirun's process, while both workers train: every worker ends within
    seconds, the exit status is 143, no temporary file is left and no job's file changes after."""
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    from .studies.test_stop import start, stop_and_check

    sweep = tmp_path / "sweep"
    proc = start(
        [
            "train.py",
            "-m",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            "centers=aco",
            "centers.aco.iterations=1000000",
            "rbfn.num_centers=10,12",
            *FAST,
            f"hydra.sweep.dir={sweep}",
        ],
        tmp_path / "out.log",
    )
    # Both jobs are in their colonies once each has saved a snapshot.
    stop_and_check(proc, tmp_path / "out.log", sweep, lambda: all((sweep / j / "last.pt").exists() for j in "01"))


def test_slurm_launcher_composes_on_the_command_line():
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    out = _python("train.py", "--cfg", "job", "hydra/launcher=slurm", "experiment=aco_vs_kmeans")
    assert "num_threads: 1" in out and "name: aco" in out


def test_hparams_search_preset_composes():
    pytest.importorskip("hydra_plugins.hydra_optuna_sweeper")
    from .conftest import compose_config

    cfg = compose_config("train", "experiment=hparams_search", hydra=True)
    sweeper = cfg.hydra.sweeper
    assert sweeper._target_.endswith("OptunaSweeper") and sweeper.direction == "minimize"
    assert sweeper.sampler._target_ == "optuna.samplers.TPESampler" and sweeper.sampler.seed == 0
    assert set(sweeper.params) == {
        "centers.width_scale",
        "rbfn.num_centers",
        "centers.aco.acor.q",
        "centers.aco.acor.xi",
    }
    assert cfg.rbfn.growth.start == 0 and cfg.num_threads == 1


def test_hparams_search_runs_two_trials_and_reports_the_best(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_optuna_sweeper")
    _python(
        "train.py",
        "-m",
        "experiment=hparams_search",
        "hydra.sweeper.n_trials=2",
        "hydra.sweeper.n_jobs=1",
        "centers.aco.iterations=3",
        "centers.refine.full.steps=5",
        *FAST,
        f"hydra.sweep.dir={tmp_path}",
    )
    from omegaconf import OmegaConf

    best = OmegaConf.load(tmp_path / "optimization_results.yaml")
    val_e = [json.loads((tmp_path / j / "metrics.json").read_text())["val_E"] for j in ("0", "1")]
    assert best.best_value == min(val_e)
    assert set(best.best_params) == {
        "centers.width_scale",
        "rbfn.num_centers",
        "centers.aco.acor.q",
        "centers.aco.acor.xi",
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(url: str, body: dict | None = None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read())


@pytest.mark.slow
def test_tensorboard_serves_scalars_and_one_hparams_session_per_job(joblib_sweep):
    metrics = {p.parent.name: json.loads(p.read_text()) for p in joblib_sweep.glob("*/metrics.json")}
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    tb = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tensorboard.main",
            "--logdir",
            str(joblib_sweep),
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--load_fast=false",
            "--reload_interval=1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        runs, deadline = [], time.monotonic() + 90
        while sorted(runs) != sorted(metrics) and time.monotonic() < deadline:
            assert tb.poll() is None, f"tensorboard exited: {tb.stderr.read()[-2000:]}"
            with contextlib.suppress(OSError):
                runs = _get(f"{url}/data/runs")
            time.sleep(0.5)
        assert sorted(runs) == sorted(metrics), runs

        # A scalar curve: the validation error at the job's only M (growth off).
        points = _get(f"{url}/data/plugin/scalars/scalars?run=0&tag=growth/val_E")
        assert [p[1] for p in points] == [metrics["0"]["num_centers"]]
        assert points[0][2] == pytest.approx(metrics["0"]["val_E"], rel=1e-5)

        # HParams: the hparams and metric columns, then one session per job with its final metrics.
        exp = _get(f"{url}/data/plugin/hparams/experiment", {"experimentName": ""})
        infos = {h["name"]: h for h in exp["hparamInfos"]}
        assert set(infos) == {"centers", "num_centers", "seed"}
        assert infos["centers"]["domainDiscrete"] == list(SELECTORS)
        assert {"tag": "hparam/test_pos_err_mm_median", "group": ""} in [m["name"] for m in exp["metricInfos"]]
        groups = _get(
            f"{url}/data/plugin/hparams/session_groups",
            {
                "experimentName": "",
                "startIndex": 0,
                "sliceSize": 100,
                "allowedStatuses": ["STATUS_UNKNOWN", "STATUS_SUCCESS", "STATUS_FAILURE", "STATUS_RUNNING"],
            },
        )
        assert groups["totalSize"] == len(metrics)
        for g in groups["sessionGroups"]:
            (session,) = g["sessions"]
            m = metrics[session["name"]]
            assert g["hparams"]["centers"] == m["selector"]
            assert g["hparams"]["num_centers"] == m["num_centers"]
            values = {v["name"]["tag"]: v["value"] for v in session["metricValues"]}
            assert values["hparam/test_pos_err_mm_median"] == pytest.approx(m["test_pos_err_mm_median"], rel=1e-5)
    finally:
        tb.terminate()
        try:
            tb.wait(timeout=10)
        except subprocess.TimeoutExpired:
            tb.kill()
            tb.wait()
