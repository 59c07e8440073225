"""An entry point's refusal is one line on stderr (the traceback behind HYDRA_FULL_ERROR=1), and
leaves nothing behind."""

import os
import re
import subprocess
import sys

import pytest

from ..conftest import ROOT, TINY_TRAIN


def _run(*args, env=None):
    return subprocess.run(
        [sys.executable, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **(env or {})},
    )


@pytest.mark.parametrize(
    "script,override,message",
    [
        ("train.py", "data.n_val=0", "error: data.n_val=0 is not allowed: must be > 0"),
        ("evaluate.py", "n_test=0", "error: n_test=0 is not allowed: must be > 0"),
    ],
)
def test_a_refused_setting_is_one_line_and_writes_nothing(tmp_path, script, override, message):
    r = _run(script, override, f"hydra.run.dir={tmp_path / 'run'}", env={"HYDRA_FULL_ERROR": "0"})
    assert r.returncode == 1 and r.stderr.strip().splitlines() == [message], r.stderr
    assert not (tmp_path / "run").exists()
    full = _run(script, override, f"hydra.run.dir={tmp_path / 'run'}", env={"HYDRA_FULL_ERROR": "1"})
    assert full.returncode == 1 and "Traceback" in full.stderr and message[len("error: ") :] in full.stderr


def test_a_run_directory_below_a_file_is_named(tmp_path):
    # (On the command line Hydra makes the directory first and names the path in its own error.)
    from rbfn.studies.rundir import RunDir, RunDirInUse

    (tmp_path / "afile").write_text("keep")
    with (
        pytest.raises(RunDirInUse, match=r"hydra.run.dir=.*afile/run: .*afile is a file, not a directory"),
        RunDir(tmp_path / "afile" / "run"),
    ):
        pass
    assert (tmp_path / "afile").read_text() == "keep"


@pytest.mark.parametrize("progress,tty,beats", [(True, True, True), (False, True, False), (True, False, True)])
def test_a_part_says_what_it_does_how_long_it_took_and_that_it_runs(monkeypatch, caplog, progress, tty, beats):
    import logging
    import time

    from rbfn.studies import cli

    monkeypatch.setattr(cli, "HEARTBEAT_S", 0.02)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: tty)
    log = logging.getLogger("test_cli")
    with (
        caplog.at_level(logging.INFO, logger="test_cli"),
        cli.announced(log, "control", "6 controllers", progress) as t,
    ):
        time.sleep(0.15)
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "control: 6 controllers" and lines[-1] == f"control: done in {t['seconds']:.1f} s"
    assert t["seconds"] >= 0.15
    assert any(line.startswith("control: still running (") for line in lines[1:-1]) == beats
    assert len(lines) == 2 or beats


def test_a_running_part_says_where_its_loop_stands_in_the_log(monkeypatch, caplog):
    """Written to a file (no terminal), a long part still says what is done, what remains and about
    how long that takes, from the Progress its library loop advances."""
    import logging
    import time

    from rbfn.studies import cli

    monkeypatch.setattr(cli, "HEARTBEAT_S", 0.05)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False)
    log = logging.getLogger("test_cli")
    with caplog.at_level(logging.INFO, logger="test_cli"), cli.announced(log, "fit", "M = 80") as t:
        for step in range(4):
            t["progress"].at("refinement", step, 2000)
            time.sleep(0.06)
    beats = [r.getMessage() for r in caplog.records if "still running" in r.getMessage()]
    assert beats and all("; refinement: " in b and " / 2000 steps" in b for b in beats), beats
    assert any("s left" in b for b in beats), beats


def test_a_failed_part_logs_no_end_line(caplog):
    import logging

    from rbfn.studies.cli import announced

    log = logging.getLogger("test_cli")
    with caplog.at_level(logging.INFO, logger="test_cli"), pytest.raises(ValueError), announced(log, "ik", "x", False):
        raise ValueError("bad")
    assert [r.getMessage() for r in caplog.records] == ["ik: x"]


def _unmakeable(tmp_path, kind: str) -> str:
    """A run directory that cannot be made, of `kind`."""
    if kind == "below a file":
        (tmp_path / "afile").write_text("keep")
        return str(tmp_path / "afile" / "run")
    if kind == "dangling symlink":
        (tmp_path / "link").symlink_to(tmp_path / "gone")
        return str(tmp_path / "link")
    if kind == "symlink loop":
        (tmp_path / "a").symlink_to(tmp_path / "b")
        (tmp_path / "b").symlink_to(tmp_path / "a")
        return str(tmp_path / "a" / "run")
    return str(tmp_path / ("x" * 300) / "run")  # a name too long for the file system


@pytest.mark.parametrize(
    "script,kind",
    [
        *(("train.py", k) for k in ("below a file", "dangling symlink", "symlink loop", "name too long")),
        ("evaluate.py", "dangling symlink"),
    ],
)
def test_a_run_directory_that_cannot_be_made_is_one_line(tmp_path, script, kind):
    key = "hydra.run.dir"
    """Hydra makes the run directory before the run starts: where it cannot, the command still ends
    with one line naming the key and why, and exit status 1."""
    before = sorted(os.listdir(tmp_path))
    value = _unmakeable(tmp_path, kind)
    made = sorted(os.listdir(tmp_path))
    r = _run(
        script, "data.n_val=0" if script == "train.py" else "n_test=0", f"{key}={value}", env={"HYDRA_FULL_ERROR": "0"}
    )
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert lines[0].startswith(f"error: {key}={value}: cannot make the run directory: "), r.stderr
    assert sorted(os.listdir(tmp_path)) == made and before == []


def test_a_sweep_directory_that_cannot_be_made_is_one_line(tmp_path):
    (tmp_path / "afile").write_text("keep")
    r = _run(
        "train.py", "-m", "seed=0,1", f"hydra.sweep.dir={tmp_path / 'afile' / 'sweep'}", env={"HYDRA_FULL_ERROR": "0"}
    )
    assert r.returncode == 1 and r.stderr.strip().splitlines() == [
        f"error: hydra.sweep.dir={tmp_path / 'afile' / 'sweep'}: cannot make the run directory: "
        f"{tmp_path / 'afile'} is a file, not a directory; give another hydra.sweep.dir"
    ], r.stderr


def test_a_closed_standard_output_is_one_note_and_the_run_goes_on(tmp_path):
    """`python train.py | head -1`: the reader goes away after the first line; the run ends as usual,
    with one note on stderr instead of a BrokenPipeError block a message."""
    proc = subprocess.Popen(
        [sys.executable, "train.py", *TINY_TRAIN, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdout.readline()  # the first line, as head -1
    proc.stdout.close()
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "Error" not in err and err.strip().splitlines() == [
        "note: standard output was closed; the run goes on, its messages go to its log file only"
    ], err
    assert (tmp_path / "run" / "metrics.json").is_file()
    assert "test position error median" in (tmp_path / "run" / "train.log").read_text()


def test_ctrl_c_to_train_is_one_line_and_keeps_the_state_to_resume(tmp_path):
    import signal
    import time

    run_dir = tmp_path / "run"
    args = [
        sys.executable,
        "train.py",
        *TINY_TRAIN,
        "centers=aco",
        "centers.aco.iterations=400",
        f"hydra.run.dir={run_dir}",
    ]
    proc = subprocess.Popen(
        args, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 120
        while not (run_dir / "last.pt").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C: the whole foreground group
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == [
        f"stopped by SIGINT (exit status 130); {run_dir} keeps what this run wrote before it stopped (last.pt); "
        "run the same command again to resume it"
    ], err


@pytest.mark.parametrize(
    "override,message",
    [
        (
            "seed=abc",
            "error: Error merging override seed=abc: Value 'abc' of type 'str' could not be converted to Integer",
        ),
        (
            "foo=1",
            "error: Could not override 'foo'; To append to your config use +foo=1: Key 'foo' not in 'TrainConfig'",
        ),
        (
            "centers=nonexistent",
            "error: In 'train': Could not find 'centers/nonexistent'; Available options in 'centers': aco, aco_paper, "
            "cmaes, kmeans, kmeans_refine, ols, random",
        ),
        ("seed=[1", "error: cannot parse the override 'seed=[1'; quote a value holding spaces"),
        (
            "+rbfn.num_centres=40",
            "error: rbfn.num_centres is not a setting of this command (misspelt?); --help lists the config groups, "
            "--cfg job every key",
        ),
        ("hydra.run.dir=${foo}", "error: Interpolation key 'foo' not found; full_key: hydra.run.dir"),
    ],
    ids=["type", "unknown key", "unknown option", "unparsable", "added key", "interpolation"],
)
def test_hydras_own_errors_and_added_keys_are_one_line(tmp_path, override, message):
    """What Hydra refuses while composing (printed with a traceback by Hydra itself) is one line too,
    and a key the schema lacks, which Hydra adds with +, is refused instead of silently dropped."""
    r = _run("train.py", f"hydra.run.dir={tmp_path / 'run'}", override, env={"HYDRA_FULL_ERROR": "0"})
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and lines[0].startswith(message), r.stderr
    assert not (tmp_path / "run").exists()


def test_a_failed_multirun_job_ends_the_sweep_with_its_error_not_a_traceback(tmp_path):
    r = _run(
        "train.py",
        "-m",
        *TINY_TRAIN,
        "seed=0,-1",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
        env={"HYDRA_FULL_ERROR": "0"},
    )
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert "error: seed=-1 is not allowed: use an integer in [0, 4294967295]" in r.stderr.splitlines(), r.stderr
    assert (tmp_path / "sweep" / "0" / "metrics.json").is_file() and (
        tmp_path / "sweep" / "1" / "failed.json"
    ).is_file()


def _bool_keys(schema, prefix: str = "") -> list[str]:
    """Every bool key of a config schema, by its full name."""
    import dataclasses
    import typing

    hints, out = typing.get_type_hints(schema), []
    for f in dataclasses.fields(schema):
        if dataclasses.is_dataclass(hints[f.name]):
            out += _bool_keys(hints[f.name], f"{prefix}{f.name}.")
        elif hints[f.name] is bool:
            out.append(prefix + f.name)
    return out


@pytest.mark.parametrize("schema", ["TrainConfig", "EvalConfig"])
def test_a_bool_key_takes_only_true_or_false(schema):
    """OmegaConf takes export=2, export=yes or progress=1 for true: every bool key of either entry
    point refuses anything but true and false on the command line, naming the key and the value."""
    import rbfn.config as config
    from rbfn.studies.cli import check_overrides

    cls = getattr(config, schema)
    keys = _bool_keys(cls)
    some = {"TrainConfig": {"export", "progress"}, "EvalConfig": {"ik", "control.enabled", "loop.torque_limits"}}
    assert some[schema] <= set(keys)
    for key in keys:
        check_overrides(cls, [f"{key}=true", f"{key}=false", f"++{key}=True"])
        for bad in ("2", "0", "yes", "'no'", "1.0"):
            with pytest.raises(ValueError, match=re.escape(f"{key}={bad} is not allowed: must be true or false")):
                check_overrides(cls, [f"{key}={bad}"])


def test_overrides_of_other_types_are_checked_as_typed():
    from rbfn.config import TrainConfig
    from rbfn.studies.cli import check_overrides

    check_overrides(  # groups, lists, dicts, null, interpolations and keys outside the schema pass
        TrainConfig,
        ["robot=urdf", "centers=kmeans", "robot.home=[1,2,3]", "+robot.locked.j=1", "robot.target=null",
         "export=${progress}", "hydra.run.dir=x", "robot.end_link=7", "seed=3", "data.n_train=2,3"],
    )  # fmt: skip
    for bad, allowed in [
        ("robot.name=true", "must be a string"),
        ("robot.gravity=true", "must be a number"),
        ("robot.joint_low=[0,true,1]", "each entry must be a number"),
        ("seed=1.5", "must be an integer"),
    ]:
        with pytest.raises(ValueError, match=re.escape(f"{bad} is not allowed: {allowed}")):
            check_overrides(TrainConfig, [bad])


@pytest.mark.parametrize("script", ["train.py", "evaluate.py"])
def test_help_lists_what_a_user_may_set_and_no_internal_entry(script):
    out = subprocess.run([sys.executable, str(ROOT / script), "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "_schema" not in out.stdout
    assert f"python {script} [group=option ...]" in out.stdout
    assert "robot: panda, scara, ur5, urdf" in out.stdout and "loop: ideal, realistic" in out.stdout
