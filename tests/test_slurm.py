"""A real SLURM cluster on localhost (examples/slurm_local_cluster.sh): a multirun through
hydra-submitit-launcher, and a job requeued mid-colony that resumes from its last.pt.

Skipped where SLURM or munge is not installed (.ci/run installs them on Debian) or where the
test does not run as root (slurmd starts the jobs). Every daemon is stopped at the end, also on
failure.
"""

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from rbfn.checkpoint import load_sealed
from rbfn.studies.rundir import RunDir, RunDirInUse

pytestmark = [pytest.mark.slurm, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "examples" / "slurm_local_cluster.sh"
TOOLS = ("slurmctld", "slurmd", "munged", "sbatch", "squeue", "sinfo", "scontrol", "scancel")
SMALL = [
    "data.n_train=300",
    "data.n_val=150",
    "data.n_test=150",
    "rbfn.growth.start=0",
    "export=false",
    "progress=false",
    "num_threads=1",
]
LAUNCHER = [
    "hydra/launcher=slurm",
    "hydra.launcher.partition=local",
    "hydra.launcher.timeout_min=5",
    "hydra.launcher.mem_gb=1",
]
# About 15-20 s of colony on one core: long enough to be requeued in the middle.
COLONY_ITERATIONS = 10000
LONG = ["centers=aco", f"centers.aco.iterations={COLONY_ITERATIONS}", "rbfn.num_centers=20", *SMALL]
REQUEUE_AFTER = 100  # colony iterations in last.pt before the job is requeued


def _missing() -> str | None:
    absent = [t for t in TOOLS if shutil.which(t) is None]
    if absent:
        return (
            f"SLURM is not installed ({', '.join(absent)} not found); on Debian: "
            "apt-get install slurmctld slurmd slurm-client munge (.ci/run does)"
        )
    if os.geteuid() != 0:
        return "the local SLURM cluster needs root (slurmd starts the jobs)"
    return None


def _logs(d: Path) -> str:
    return "\n".join(
        f"--- {p.name}\n" + "\n".join(p.read_text(errors="replace").splitlines()[-15:])
        for p in sorted((d / "log").glob("*.log"))
    )


@pytest.fixture(scope="module")
def cluster():
    """(cluster dir, environment with its SLURM_CONF); its daemons are stopped at the end, always."""
    why = _missing()
    if why:
        pytest.skip(why)
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    d = Path(tempfile.mkdtemp(prefix="slurm-", dir="/tmp"))  # short: munge and slurmd use unix sockets here
    try:
        r = subprocess.run(["bash", str(SCRIPT), "start", str(d)], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, f"cluster did not start:\n{r.stdout}{r.stderr}\n{_logs(d)}"
        env = {**os.environ, "SLURM_CONF": str(d / "slurm.conf")}
        state = subprocess.run(["sinfo", "-h", "-o", "%P %T %c"], env=env, capture_output=True, text=True).stdout
        assert state.split() == ["local*", "idle", "2"], state
        yield d, env
    finally:
        subprocess.run(["bash", str(SCRIPT), "stop", str(d)], capture_output=True, text=True, timeout=120)
        left = []
        for pidfile in (d / "slurmd.pid", d / "slurmctld.pid", d / "munge" / "munged.pid"):
            if pidfile.is_file():
                pid = int(pidfile.read_text())
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    continue
                os.kill(pid, 9)
                left.append(pidfile.name)
        shutil.rmtree(d, ignore_errors=True)
        assert not left, f"daemons still running after stop, killed: {left}"


def _squeue(env, fmt: str) -> list[str]:
    r = subprocess.run(["squeue", "-h", "-o", fmt], env=env, capture_output=True, text=True, timeout=30)
    return r.stdout.split("\n") if r.stdout.strip() else []


def _wait(what: str, ok, timeout: float, step: float = 0.5, on_fail=lambda: ""):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = ok()
        if value:
            return value
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}\n{on_fail()}")


def test_multirun_on_slurm_writes_every_job_and_summarizes(cluster, tmp_path):
    d, env = cluster
    sweep = tmp_path / "sweep"
    t0 = time.monotonic()
    r = subprocess.run(
        [
            sys.executable,
            "train.py",
            "-m",
            *LAUNCHER,
            "centers=kmeans,random",
            "rbfn.num_centers=10",
            *SMALL,
            f"hydra.sweep.dir={sweep}",
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    wall = time.monotonic() - t0
    assert r.returncode == 0, f"{r.stderr[-3000:]}\n{_logs(d)}"
    submitted = [line for line in r.stdout.splitlines() + r.stderr.splitlines() if "\t#" in line]
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert [p.name for p in jobs] == ["0", "1"]
    for job in jobs:
        assert (job / "checkpoint.pt").is_file(), job
        assert json.loads((job / "metrics.json").read_text())["test_pos_err_mm_median"] > 0
    results = list((sweep / ".submitit").glob("*/*_result.pkl"))
    out = subprocess.run(
        [sys.executable, "-m", "rbfn.studies.summarize", str(sweep)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    ).stdout
    assert len([line for line in out.splitlines() if line.startswith(("| kmeans |", "| random |"))]) == 2, out
    assert "2 jobs: 2 completed, 0 failed, 0 unfinished" in out
    print(
        f"\nSLURM sweep: {len(submitted)} jobs submitted, {len(results)} results from submitit, "
        f"{len(jobs)} completed with metrics.json; {wall:.1f} s"
    )


def test_requeued_job_resumes_from_last_pt_to_the_uninterrupted_result(cluster, tmp_path):
    d, env = cluster
    sweep, ref_dir = tmp_path / "sweep", tmp_path / "reference"
    t0 = time.monotonic()
    sub = subprocess.Popen(
        [sys.executable, "train.py", "-m", *LAUNCHER, *LONG, f"hydra.sweep.dir={sweep}"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    # The uninterrupted reference, as a plain run beside it (the node uses one of the two cores).
    ref = subprocess.Popen(
        [sys.executable, "train.py", *LONG, f"hydra.run.dir={ref_dir}"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        job = sweep / "0"
        job_id = _wait(
            "the job to run",
            lambda: [line.split()[0] for line in _squeue(env, "%i %T") if line.endswith("RUNNING")],
            60,
            on_fail=lambda: _logs(d),
        )[0]

        def colony_iteration():
            try:
                state = load_sealed(job / "last.pt")["state"]
            except Exception:  # noqa: BLE001 - not written yet, or half written
                return None
            it = ((state.get("current") or {}).get("colony") or {}).get("iteration", 0)
            return it if it >= REQUEUE_AFTER else None

        k = _wait(f"a colony snapshot with iteration >= {REQUEUE_AFTER} in {job}/last.pt", colony_iteration, 90)
        subprocess.run(["scontrol", "requeue", job_id], env=env, check=True, timeout=30)
        # The killed process must be gone (its lock on the run directory released) before the job
        # starts again: SLURM holds a requeued job back for a while, then it is released here.
        _wait(
            "the requeued job to be pending",
            lambda: any(line == f"{job_id} PENDING" for line in _squeue(env, "%i %T")),
            60,
            on_fail=lambda: _logs(d),
        )

        def lock_free():
            try:
                with RunDir(job):
                    return True
            except RunDirInUse:
                return False

        _wait("the interrupted process to release its run directory", lock_free, 60)
        subprocess.run(["scontrol", "update", f"JobId={job_id}", "StartTime=now"], env=env, check=True, timeout=30)
        out, _ = sub.communicate(timeout=300)
        assert sub.returncode == 0, f"{out[-3000:]}\n{_logs(d)}"
        wall = time.monotonic() - t0
        assert ref.wait(timeout=300) == 0, ref.stderr.read()[-3000:]
    finally:
        for p in (sub, ref):
            if p.poll() is None:
                p.kill()
                p.wait()

    log = (job / "train.log").read_text()
    resumed = [line for line in log.splitlines() if "resuming from" in line]
    assert resumed and f"resuming from {job / 'last.pt'}: 0 growth step(s) done" in resumed[0], log
    show = subprocess.run(["scontrol", "show", "job", job_id], env=env, capture_output=True, text=True).stdout
    assert "Restarts=1" in show, show
    got = json.loads((job / "metrics.json").read_text())
    want = json.loads((ref_dir / "metrics.json").read_text())
    for key in ("val_E", "test_pos_err_mm_median", "test_pos_err_mm_p95", "test_pos_err_mm_max", "growth"):
        assert got[key] == want[key], key
    assert k < COLONY_ITERATIONS and load_sealed(job / "last.pt")["state"]["finished"] is not None
    print(
        f"\nSLURM requeue: job {job_id} requeued at colony iteration {k}; "
        f"{resumed[0].split(' - ', 1)[-1]}; metrics equal the uninterrupted run's "
        f"(val_E {got['val_E']:.4g}, test median {got['test_pos_err_mm_median']:.3f} mm); {wall:.1f} s"
    )
