"""`python -m rbfn.export` on bad inputs: one-line errors, and no good file destroyed or half written."""

import json
import os
import shutil

import pytest
import torch

import rbfn.export
from rbfn.checkpoint import read_checkpoint, save_checkpoint
from rbfn.export import main
from rbfn.layer import RBFNetwork

from .conftest import error_line


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
