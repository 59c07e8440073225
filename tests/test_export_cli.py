"""`python -m rbfn.export` on bad inputs: one-line errors, and no good file destroyed or half written."""

import json
import os
import shutil
import signal
import subprocess
import sys

import pytest
import torch

import rbfn.export
from rbfn.checkpoint import read_checkpoint, save_checkpoint
from rbfn.export import main
from rbfn.layer import RBFNetwork

from .conftest import ROOT, error_line


@pytest.fixture(autouse=True)
def _signals_as_python_sets_them(monkeypatch):
    """main() in this process leaves the process's signal handlers alone (rbfn.studies.stop's own
    handlers would stay for the rest of the session); SIGINT raises KeyboardInterrupt. The commands
    run as processes below use the real ones."""
    monkeypatch.setattr(rbfn.export, "stop_on_signals", lambda: None)
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    for s, handler in previous.items():
        signal.signal(s, handler)


@pytest.fixture()
def ckpt(tmp_path, scara_robot):
    """A checkpoint of a small SCARA network (random weights), alone in tmp_path/run."""
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    net = RBFNetwork(torch.randn(5, 3, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 3)
    save_checkpoint(path, net, scara_robot.record(), {"seed": 0}, {})
    return path


@pytest.fixture()
def pose_ckpt(tmp_path):
    """A checkpoint of a small UR5 pose network (random weights), alone in tmp_path/pose."""
    from rbfn.robots.robot import load_robot
    from rbfn.targets import TargetFeatures

    from .conftest import compose_config

    path = tmp_path / "pose" / "checkpoint.pt"
    path.parent.mkdir()
    net = RBFNetwork(
        torch.randn(5, 9, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 6, inputs=TargetFeatures(pose=True)
    )
    save_checkpoint(path, net, load_robot(compose_config("train", "robot=ur5").robot).record(), {"seed": 0}, {})
    return path


@pytest.fixture()
def fake_export(monkeypatch):
    """Exports that take no time: the files' bytes name their format."""
    monkeypatch.setattr(rbfn.export, "onnx_bytes", lambda net, robot, base_yaw=True: b"onnx")
    monkeypatch.setattr(rbfn.export, "pt2_bytes", lambda net, robot, base_yaw=True: b"pt2")


def _error_line(capsys, *argv, status=2):
    return error_line(capsys, main, "python -m rbfn.export", *argv, status=status)


def _files(folder):
    return {f.name: f.read_bytes() for f in sorted(folder.iterdir())}


def test_a_missing_or_bad_checkpoint_is_one_line(tmp_path, capsys, fake_export):
    assert f"CHECKPOINT {tmp_path / 'nope.pt'}: no such file" in _error_line(capsys, tmp_path / "nope.pt")
    assert f"CHECKPOINT: {tmp_path} is a directory, not a checkpoint" in _error_line(capsys, tmp_path)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    err = _error_line(capsys, tmp_path / "junk.pt")
    assert f"CHECKPOINT: {tmp_path / 'junk.pt'} is not a readable checkpoint (truncated or corrupted?)" in err
    torch.save({"a": 1}, tmp_path / "foreign.pt")
    assert "has no aco-rbfn seal" in _error_line(capsys, tmp_path / "foreign.pt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign.pt", "junk.pt"]


def test_a_bad_out_dir_is_one_line(ckpt, tmp_path, capsys, fake_export):
    (tmp_path / "file").write_text("x")
    assert f"--out-dir {tmp_path / 'file'}: {tmp_path / 'file'} is not a directory" in _error_line(
        capsys, ckpt, "--out-dir", tmp_path / "file"
    )
    assert f"{tmp_path / 'file'} is not a directory" in _error_line(
        capsys, ckpt, "--out-dir", tmp_path / "file" / "sub"
    )
    (tmp_path / "ro").mkdir(mode=0o555)
    assert f"{tmp_path / 'ro'} is a write-protected directory (mode 0o555)" in _error_line(
        capsys, ckpt, "--out-dir", tmp_path / "ro" / "sub"
    )
    if os.geteuid() == 0:  # root may write there: --force does
        main([str(ckpt), "--out-dir", str(tmp_path / "ro" / "sub"), "--force"])
        assert sorted(p.name for p in (tmp_path / "ro" / "sub").iterdir()) == ["ik.onnx", "ik.pt2"]
        shutil.rmtree(tmp_path / "ro" / "sub")
    (tmp_path / "out" / "ik.pt2").mkdir(parents=True)
    assert f"{tmp_path / 'out' / 'ik.pt2'} is a directory" in _error_line(capsys, ckpt, "--out-dir", tmp_path / "out")
    assert not any((tmp_path / "ro").iterdir()) and [p.name for p in (tmp_path / "out").iterdir()] == ["ik.pt2"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "out", "ro", "run"]


def test_a_write_protected_output_is_kept_unless_forced(ckpt, capsys, fake_export):
    onnx = ckpt.parent / "ik.onnx"
    onnx.write_bytes(b"good")
    onnx.chmod(0o444)
    err = _error_line(capsys, ckpt)
    assert (
        f"the output directory {ckpt.parent} (the checkpoint's; --out-dir picks another): {onnx} is "
        "write-protected (mode 0o444); not replacing it (--force replaces it)"
    ) in err
    assert onnx.read_bytes() == b"good" and not (ckpt.parent / "ik.pt2").exists()
    main([str(ckpt), "--force"])
    assert onnx.read_bytes() == b"onnx" and (onnx.stat().st_mode & 0o777) == 0o444
    assert (ckpt.parent / "ik.pt2").read_bytes() == b"pt2"
    assert f"wrote {onnx}" in capsys.readouterr().out


@pytest.mark.parametrize("failing", ["onnx_bytes", "pt2_bytes"])
def test_an_export_that_fails_writes_nothing(ckpt, capsys, monkeypatch, fake_export, failing):
    (ckpt.parent / "ik.onnx").write_bytes(b"old onnx")

    def fail(net, robot, base_yaw=True):
        raise RuntimeError("the exporter broke\nwith a long story")

    monkeypatch.setattr(rbfn.export, failing, fail)
    err = _error_line(capsys, ckpt, status=1)
    assert (
        f"exporting {ckpt} failed (RuntimeError: the exporter broke); ik.onnx and ik.pt2 were left as they were" in err
    )
    assert _files(ckpt.parent) == {"checkpoint.pt": ckpt.read_bytes(), "ik.onnx": b"old onnx"}


def test_a_failed_write_replaces_neither_file(ckpt, capsys, monkeypatch, fake_export):
    calls = []

    def fsync(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", fsync)
    assert "No space left on device" in _error_line(capsys, ckpt, "--out-dir", ckpt.parent / "new", status=1)
    assert not any((ckpt.parent / "new").iterdir())


@pytest.mark.parametrize("which,name,width", [("ckpt", "positions", 3), ("pose_ckpt", "poses", 7)])
def test_the_command_exports_for_real(request, which, name, width, tmp_path):
    """Both files take the input named for the network's targets ("positions" (B, 3) or "poses"
    (B, 7)), agree, and carry the checkpoint's robot and its example targets."""
    ort = pytest.importorskip("onnxruntime")
    path = request.getfixturevalue(which)
    main([str(path), "--out-dir", str(tmp_path / "deploy")])
    assert sorted(p.name for p in (tmp_path / "deploy").iterdir()) == ["ik.onnx", "ik.pt2"]
    sess = ort.InferenceSession(str(tmp_path / "deploy" / "ik.onnx"), providers=["CPUExecutionProvider"])
    assert [(i.name, i.shape) for i in sess.get_inputs()] == [(name, ["batch", width])]
    meta = sess.get_modelmeta().custom_metadata_map
    assert meta["robot"] == read_checkpoint(path)["robot"]["name"]
    x = torch.tensor(json.loads(meta["example_targets"]), dtype=torch.float32)
    assert x.shape == (4, width)
    joints = torch.export.load(str(tmp_path / "deploy" / "ik.pt2")).module()(x)[0]
    assert torch.allclose(torch.from_numpy(sess.run(None, {name: x.numpy()})[0]), joints, atol=1e-5)


def _no_work(*args, **kwargs):
    pytest.fail("the export started although an argument was bad")


def test_every_path_is_checked_before_any_work(ckpt, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(rbfn.export, "read_checkpoint", _no_work)
    os.mkfifo(tmp_path / "fifo")
    assert f"CHECKPOINT: {tmp_path / 'fifo'} is a FIFO (named pipe), not a checkpoint" in _error_line(
        capsys, tmp_path / "fifo"
    )
    url = "https://example.com/run/checkpoint.pt"
    assert f"CHECKPOINT: {url} is a URL; aco-rbfn reads and writes local files only" in _error_line(capsys, url)
    assert "CHECKPOINT: /dev/null is a character device, not a checkpoint" in _error_line(capsys, "/dev/null")
    (tmp_path / "gone").symlink_to(tmp_path / "nowhere")
    err = _error_line(capsys, ckpt, "--out-dir", tmp_path / "gone")
    assert (
        f"--out-dir {tmp_path / 'gone'}: {tmp_path / 'gone'} is not a directory: it is a dangling symbolic link" in err
    )
    assert "--out-dir s3://bucket/deploy is a URL" in _error_line(capsys, ckpt, "--out-dir", "s3://bucket/deploy")
    assert "--out-dir '' names no directory" in _error_line(capsys, ckpt, "--out-dir", "")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "gone", "run"]


def test_an_export_given_as_the_checkpoint_says_what_it_is(tmp_path, capsys):
    from onnx import helper

    (tmp_path / "ik.onnx").write_bytes(helper.make_model(helper.make_graph([], "g", [], [])).SerializeToString())
    err = _error_line(capsys, tmp_path / "ik.onnx")
    assert f"CHECKPOINT: {tmp_path / 'ik.onnx'} is an ONNX model (an export such as ik.onnx), not a checkpoint" in err


def _ctrl_c(then):
    """An onnx_bytes that gets Ctrl-C while it works, then does `then` with the KeyboardInterrupt,
    as torch's exporter may: swallow it and go on, or raise another error in its place."""

    def onnx_bytes(net, robot, base_yaw=True):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt as e:
            then(e)
        return b"onnx"

    return onnx_bytes


def _swallow(e):
    pass


def _replace(e):
    raise TypeError("incompatible function arguments") from e


def _reraise(e):
    raise e


@pytest.mark.parametrize("then", [_swallow, _replace, _reraise], ids=["swallowed", "replaced", "raised"])
def test_ctrl_c_writes_nothing_and_says_so_in_one_line(ckpt, capsys, monkeypatch, fake_export, then):
    """However the exporter treats the KeyboardInterrupt (it once swallowed it and the old files were
    replaced, exit status 0), nothing is written and the command ends with one line and status 130."""
    (ckpt.parent / "ik.onnx").write_bytes(b"old onnx")
    monkeypatch.setattr(rbfn.export, "onnx_bytes", _ctrl_c(then))
    with pytest.raises(SystemExit) as e:
        main([str(ckpt)])
    assert e.value.code == 130
    assert capsys.readouterr().err == (
        "python -m rbfn.export: stopped by SIGINT (exit status 130): nothing was written; ik.onnx and ik.pt2 "
        "were left as they were\n"
    )
    assert _files(ckpt.parent) == {"checkpoint.pt": ckpt.read_bytes(), "ik.onnx": b"old onnx"}
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # a second Ctrl-C cannot cut its exit short


def test_ctrl_c_as_the_files_are_renamed_writes_both_and_says_so(ckpt, capsys, monkeypatch, fake_export):
    replace = os.replace

    def interrupted(src, dst):
        signal.raise_signal(signal.SIGINT)
        replace(src, dst)

    monkeypatch.setattr(rbfn.files.os, "replace", interrupted)
    with pytest.raises(SystemExit) as e:
        main([str(ckpt)])
    onnx, pt2 = ckpt.parent / "ik.onnx", ckpt.parent / "ik.pt2"
    assert e.value.code == 130 and onnx.read_bytes() == b"onnx" and pt2.read_bytes() == b"pt2"
    assert capsys.readouterr().err == (
        f"python -m rbfn.export: stopped by SIGINT (exit status 130): {onnx} and {pt2} were written "
        "(the signal came as they were renamed)\n"
    )


# The command as a process, its exports replaced by a stand-in that gets a signal while it works.
_CHILD = """
import signal, sys
import rbfn.export
from rbfn.studies import stop

SIGNUM = int(sys.argv[1])
if SIGNUM == signal.SIGINT:  # as stop_on_signals does where rbfn.studies.stop handles SIGINT
    signal.signal(signal.SIGINT, stop._on_signal)

def onnx_bytes(net, robot, base_yaw=True):
    try:
        signal.raise_signal(SIGNUM)
    except BaseException:
        pass  # swallowed, as torch's exporter may
    return b"onnx"

rbfn.export.onnx_bytes = onnx_bytes
rbfn.export.pt2_bytes = lambda net, robot, base_yaw=True: b"pt2"
rbfn.export.main(sys.argv[2:])
"""


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stopped_export_is_one_line_with_its_signals_status(ckpt, signum):
    """Through rbfn.studies.stop's handler (Stopped): SIGTERM, and SIGINT where stop_on_signals
    handles it, end the command with one line and 128 + the signal's number, nothing written."""
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(int(signum)), str(ckpt)], cwd=ROOT, capture_output=True, text=True
    )
    name = signal.Signals(signum).name
    assert done.returncode == 128 + signum and done.stdout == ""
    assert done.stderr == (
        f"python -m rbfn.export: stopped by {name} (exit status {128 + signum}): nothing was written; ik.onnx and "
        "ik.pt2 were left as they were\n"
    )
    assert sorted(p.name for p in ckpt.parent.iterdir()) == ["checkpoint.pt"]


@pytest.mark.slow
def test_a_closed_stdout_is_no_traceback(ckpt):
    """`python -m rbfn.export ... | head -0`: the files are written and nothing but them is left."""
    child = _CHILD.replace("SIGNUM = int(sys.argv[1])", "SIGNUM = 0").replace(
        "        signal.raise_signal(SIGNUM)\n", "        pass\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", child, "0", str(ckpt)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    proc.stdout.close()  # the reader leaves before the command prints
    err = proc.stderr.read().decode()
    assert proc.wait() == 0 and err == "", err
    assert (ckpt.parent / "ik.onnx").read_bytes() == b"onnx" and (ckpt.parent / "ik.pt2").read_bytes() == b"pt2"


@pytest.mark.slow
def test_ctrl_c_while_the_imports_load_ends_at_once_without_a_traceback(ckpt):
    """Before the command's main runs, Python imports the package (torch: seconds); Ctrl-C there
    ends the process by SIGINT (status 130 in a shell), with nothing on stderr."""
    import time

    proc = subprocess.Popen(
        [sys.executable, "-m", "rbfn.export", str(ckpt)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a terminal starts it
    )
    time.sleep(0.5)  # inside `import torch`
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate()
    assert proc.returncode == -signal.SIGINT and err == b"", err.decode()
    assert sorted(p.name for p in ckpt.parent.iterdir()) == ["checkpoint.pt"]
