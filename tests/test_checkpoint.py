"""Checkpoints: weights-only loadable, written atomically, and every broken file says what is wrong."""
import os
import re
import signal
import subprocess
import sys
import time

import pytest
import torch

from rbfn.checkpoint import (FORMAT_VERSION, atomic_write_bytes, load_model, load_sealed, model_from_checkpoint,
                             read_checkpoint, save_checkpoint, save_sealed, seal)
from rbfn.layer import RBFNetwork
from rbfn.resume import StateFile, TrainState

ROBOT = {"urdf": "<robot/>", "end_link": "tip", "joint_names": ["j1", "j2", "j3"],
         "joint_low": [-1.0, -1.0, 0.0], "joint_high": [1.0, 1.0, 0.5]}


def _resave(raw, path):
    """Write an edited checkpoint dict with a valid seal, as another writer would."""
    import io

    buf = io.BytesIO()
    torch.save(raw, buf)
    path.write_bytes(seal(buf.getvalue()))


@pytest.fixture()
def ckpt(tmp_path):
    net = RBFNetwork(torch.randn(5, 3, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 3)
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, net, ROBOT, {"seed": 0}, {"x": 1.0})
    return path, net


def test_round_trip_weights_only(ckpt):
    path, net = ckpt
    raw = torch.load(path, weights_only=True)
    assert raw["format_version"] == FORMAT_VERSION and raw["kind"] == "rbfn-ik"
    loaded = load_model(path, dtype=torch.float64)
    x = torch.randn(4, 3, dtype=torch.float64)
    assert torch.allclose(loaded(x), net(x).detach())


def test_load_model_dtype(ckpt):
    path, net = ckpt
    x = torch.randn(4, 3, dtype=torch.float64)
    model = load_model(path)                                # float32 for inference by default
    assert model.centers.dtype == torch.float32 and model(x).dtype == torch.float32
    assert all(t.dtype == torch.float32 for t in model.state_dict().values())
    assert (model(x).double() - net(x).detach()).abs().max() < 1e-5
    assert load_model(path, dtype=torch.float64).centers.dtype == torch.float64
    for bad in (torch.float16, torch.int64, "float32", 64):
        with pytest.raises(ValueError, match=rf"load_model\(dtype={re.escape(repr(bad))}\): allowed are torch.float32 "
                                             r"\(the default\) and torch.float64"):
            load_model(path, dtype=bad)


def test_truncated_file(ckpt):
    path, _ = ckpt
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="not a readable checkpoint .truncated or corrupted"):
        read_checkpoint(path)


def test_flipped_byte(ckpt):
    path, _ = ckpt
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0xFF
    path.write_bytes(bytes(data))
    # Wherever the byte is, reading fails clearly: the zip or pickle structure breaks, or a
    # payload byte changes and the checksum no longer matches.
    with pytest.raises(ValueError, match="not a readable checkpoint|is corrupted"):
        read_checkpoint(path)


@pytest.mark.parametrize("where", [0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 1.0])
def test_flipped_byte_anywhere(ckpt, where):
    path, _ = ckpt
    data = bytearray(path.read_bytes())
    data[min(int(len(data) * where), len(data) - 1)] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="not a readable checkpoint|is corrupted"):
        read_checkpoint(path)


def test_wrong_format_version(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["format_version"] = FORMAT_VERSION + 1
    _resave(raw, path)
    with pytest.raises(ValueError, match=f"format {FORMAT_VERSION + 1}.*reads format {FORMAT_VERSION}"):
        read_checkpoint(path)


def test_missing_key(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    del raw["state_dict"]
    _resave(raw, path)
    with pytest.raises(ValueError, match=r"missing checkpoint keys \['state_dict'\]"):
        read_checkpoint(path)


def test_other_model_kind(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["kind"] = "controller"
    _resave(raw, path)
    with pytest.raises(ValueError, match="holds a 'controller' model"):
        read_checkpoint(path)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint at"):
        read_checkpoint(tmp_path / "nope.pt")


def test_killed_writer_leaves_no_half_written_checkpoint(tmp_path):
    # A child process writes a large checkpoint over and over; kill it mid-write. The path holds
    # either nothing or a complete, loadable checkpoint, and no temporary file is left.
    script = f"""
import torch
from rbfn.checkpoint import save_checkpoint
from rbfn.layer import RBFNetwork
net = RBFNetwork(torch.randn(20000, 3, dtype=torch.float64), torch.ones(20000, dtype=torch.float64), 3)
while True:
    save_checkpoint({str(tmp_path / 'checkpoint.pt')!r}, net, {ROBOT!r}, {{}}, {{}})
    print("wrote", flush=True)
"""
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "wrote"     # one complete file, the next write under way
    time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    path = tmp_path / "checkpoint.pt"
    assert load_model(path).num_centers == 20000
    leftovers = [p for p in os.listdir(tmp_path) if p != "checkpoint.pt"]
    # SIGKILL gives no chance to clean up: a temp file may remain, but never under the real name.
    assert all(p.endswith(".tmp") for p in leftovers)


def test_flipped_byte_in_the_seal_region_is_damage_not_a_foreign_file(ckpt):
    # Every byte of the zip end record and the seal: a changed one reads as damage, never as
    # "not an aco-rbfn checkpoint".
    path, _ = ckpt
    good = path.read_bytes()
    for back in range(1, 22 + 80 + 1):
        data = bytearray(good)
        data[-back] ^= 0x01
        path.write_bytes(bytes(data))
        with pytest.raises(ValueError, match="not a readable checkpoint .truncated or corrupted|is corrupted"):
            read_checkpoint(path)


def test_plain_torch_save_is_not_an_aco_rbfn_checkpoint(ckpt):
    path, _ = ckpt
    torch.save(torch.load(path, weights_only=True), path)   # valid zip archive, no seal
    with pytest.raises(ValueError, match="is not an aco-rbfn checkpoint: it has no aco-rbfn seal") as e:
        read_checkpoint(path)
    assert str(path) in str(e.value) and "torch.save" in str(e.value) and "truncated" not in str(e.value)


class _Opaque:
    """A class weights-only unpickling refuses."""


def test_sealed_file_with_objects_is_refused_without_suggesting_unsafe_load(tmp_path):
    path = tmp_path / "checkpoint.pt"
    save_sealed(path, {"kind": "rbfn-ik", "blob": _Opaque()})
    with pytest.raises(ValueError, match="holds objects other than tensors and plain data") as e:
        read_checkpoint(path)
    msg = str(e.value)
    assert str(path) in msg and "for safety" in msg and "_Opaque" in msg
    assert "weights_only" not in msg
    assert e.value.__cause__ is None and e.value.__suppress_context__   # torch's advice not chained either


def test_training_state_is_not_a_checkpoint(tmp_path):
    StateFile(tmp_path).save(TrainState(config={"seed": 0}))
    for read in (read_checkpoint, load_model):
        with pytest.raises(ValueError, match="last.pt is a training state .*not a checkpoint.*checkpoint.pt"):
            read(tmp_path / "last.pt")


@pytest.mark.parametrize("key,value", [("head.weight", float("nan")), ("centers", float("inf")),
                                       ("in_low", float("inf")), ("cover_radius", float("nan"))])
def test_non_finite_weights_are_refused(ckpt, key, value):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["state_dict"][key].view(-1)[0] = value
    _resave(raw, path)
    with pytest.raises(ValueError, match=f"{path.name}: non-finite weights in {key}"):
        load_model(path)


def test_unbounded_domain_loads(ckpt):
    # An RBFNetwork without set_domain has infinite bounds meaning "unbounded": still loadable.
    path, _ = ckpt
    assert torch.isinf(torch.load(path, weights_only=True)["state_dict"]["in_low"]).all()
    assert torch.isinf(load_model(path).in_low).all()


def test_missing_robot(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    del raw["robot"]
    _resave(raw, path)
    with pytest.raises(ValueError, match=r"missing checkpoint keys \['robot'\]"):
        read_checkpoint(path)


def test_incomplete_robot(ckpt):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    del raw["robot"]["joint_low"], raw["robot"]["urdf"]
    _resave(raw, path)
    with pytest.raises(ValueError, match=r"robot entry is missing keys \['urdf', 'joint_low'\]"):
        read_checkpoint(path)


def test_corrupted_training_state_says_delete_it(tmp_path):
    states = StateFile(tmp_path)
    states.save(TrainState(config={"seed": 0}))
    data = states.path.read_bytes()
    states.path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="not a readable training state .truncated or corrupted") as e:
        StateFile(tmp_path).load({"seed": 0})
    assert f"Delete {states.path}" in str(e.value) and "Re-run training" not in str(e.value)


def test_load_sealed_advice(tmp_path):
    path = tmp_path / "x.pt"
    path.write_bytes(b"")
    with pytest.raises(ValueError, match="x.pt is not a readable thing .*: it is empty. Do this.$"):
        load_sealed(path, what="thing", advice="Do this.")


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_written_files_get_the_umask_mode(tmp_path, umask):
    old = os.umask(umask)
    try:
        atomic_write_bytes(tmp_path / "a.bin", lambda f: f.write(b"x"))
    finally:
        os.umask(old)
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o666 & ~umask


def test_rewritten_file_keeps_its_mode(tmp_path):
    path = tmp_path / "a.bin"
    path.write_bytes(b"x")
    path.chmod(0o640)
    atomic_write_bytes(path, lambda f: f.write(b"y"))
    assert path.stat().st_mode & 0o777 == 0o640 and path.read_bytes() == b"y"


@pytest.mark.parametrize("args,match", [
    ({"num_centers": 6}, r"centers has shape \(5, 3\), but model_args .* give \(6, 3\)"),
    ({"tail": False}, r"unexpected keys \['tail.weight'\]"),
    ({"out_features": "3"}, r"out_features='3'; expected a positive integer"),
])
def test_model_args_disagree_with_state_dict(ckpt, args, match):
    path, _ = ckpt
    raw = torch.load(path, weights_only=True)
    raw["model_args"].update(args)
    with pytest.raises(ValueError, match=match):
        model_from_checkpoint(raw)
    _resave(raw, path)
    with pytest.raises(ValueError, match=f"{path.name}: .*" + match):
        read_checkpoint(path)
