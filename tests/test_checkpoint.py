"""Checkpoints: weights-only loadable, written atomically, and every broken file says what is wrong."""
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from rbfn.checkpoint import FORMAT_VERSION, load_model, read_checkpoint, save_checkpoint, seal
from rbfn.layer import RBFNetwork


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
    save_checkpoint(path, net, {"urdf": "<robot/>", "end_link": "tip"}, {"seed": 0}, {"x": 1.0})
    return path, net


def test_round_trip_weights_only(ckpt):
    path, net = ckpt
    raw = torch.load(path, weights_only=True)
    assert raw["format_version"] == FORMAT_VERSION and raw["kind"] == "rbfn-ik"
    loaded = load_model(path)
    x = torch.randn(4, 3, dtype=torch.float64)
    assert torch.allclose(loaded(x), net(x).detach())


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
print("ready", flush=True)
while True:
    save_checkpoint({str(tmp_path / 'checkpoint.pt')!r}, net, {{}}, {{}}, {{}})
"""
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    path = tmp_path / "checkpoint.pt"
    if path.exists():
        assert load_model(path).num_centers == 20000
    leftovers = [p for p in os.listdir(tmp_path) if p != "checkpoint.pt"]
    # SIGKILL gives no chance to clean up: a temp file may remain, but never under the real name.
    assert all(p.endswith(".tmp") for p in leftovers)
