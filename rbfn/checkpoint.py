"""Checkpoints: a plain dict that `torch.load(weights_only=True)` reads, written atomically.

Keys: format_version, kind, package_version, model_args, state_dict, robot (URDF text, end
link, joint names and sampled range), config (plain data), metrics. The zip archive's comment
holds the SHA-256 of the archive, so any changed byte is caught before unpickling; the file is
still a plain torch.save archive that `torch.load(path, weights_only=True)` reads.
"""
from __future__ import annotations

import hashlib
import io
import os
import tempfile
from pathlib import Path
from typing import Any

import torch

from .layer import RBFNetwork

__all__ = ["FORMAT_VERSION", "KIND", "save_checkpoint", "save_sealed", "load_sealed", "read_checkpoint", "load_model", "model_from_checkpoint"]

FORMAT_VERSION = 1
KIND = "rbfn-ik"
_REQUIRED = ("format_version", "kind", "model_args", "state_dict")


def atomic_write_bytes(path: Path, write) -> None:
    """Call write(file) on a temporary file beside `path`, then rename it over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


_SEAL = b"aco-rbfn-sha256:"
_SEAL_LEN = len(_SEAL) + 64


def seal(data: bytes) -> bytes:
    """Put the SHA-256 of a zip archive `data` (no comment) into its end-of-directory comment."""
    if len(data) < 22 or data[-22:-18] != b"PK\x05\x06" or data[-2:] != b"\x00\x00":
        raise ValueError("expected a zip archive without a comment")
    comment = _SEAL + hashlib.sha256(data).hexdigest().encode()
    return data[:-2] + len(comment).to_bytes(2, "little") + comment


def unseal(data: bytes, path: Path) -> bytes:
    """The archive as written before sealing; ValueError if any byte of `data` changed."""
    tail = data[-_SEAL_LEN:]
    if len(data) < 22 + _SEAL_LEN or not tail.startswith(_SEAL):
        raise ValueError(f"{path} is not a readable checkpoint (truncated or corrupted?): its "
                         "checksum seal is missing. Re-run training or restore the file from a copy.")
    original = data[:-_SEAL_LEN - 2] + b"\x00\x00"
    if hashlib.sha256(original).hexdigest().encode() != tail[len(_SEAL):]:
        raise ValueError(f"{path} is corrupted: its bytes do not match its SHA-256 checksum. "
                         "Re-run training or restore the file from a copy.")
    return original


def save_checkpoint(path: str | Path, model: RBFNetwork, robot: dict[str, Any], config: dict[str, Any],
                    metrics: dict[str, Any]) -> None:
    """Write the checkpoint dict for `model` to `path` atomically."""
    from . import __version__

    ckpt = {
        "format_version": FORMAT_VERSION,
        "kind": KIND,
        "package_version": __version__,
        "model_args": {"num_centers": model.num_centers, "in_features": model.centers.shape[1],
                       "out_features": model.head.out_features, "tail": model.tail is not None},
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "robot": robot,
        "config": config,
        "metrics": metrics,
    }
    save_sealed(path, ckpt)


def save_sealed(path: str | Path, obj: Any) -> None:
    """torch.save `obj` (plain data and tensors) to `path`, sealed and atomically."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    sealed = seal(buf.getvalue())
    atomic_write_bytes(Path(path), lambda f: f.write(sealed))


def load_sealed(path: str | Path) -> Any:
    """What `save_sealed` wrote at `path` (weights-only unpickling); clear errors when damaged."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    data = unseal(path.read_bytes(), path)
    try:
        return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as e:  # truncated or corrupted archives raise various errors
        raise ValueError(f"{path} is not a readable checkpoint (truncated or corrupted?): {e}. "
                         "Re-run training or restore the file from a copy.") from e


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict at `path`, checked for format and kind; clear errors otherwise."""
    path = Path(path)
    ckpt = load_sealed(path)
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in _REQUIRED):
        missing = [k for k in _REQUIRED if not isinstance(ckpt, dict) or k not in ckpt]
        raise ValueError(f"{path} is missing checkpoint keys {missing}; it was not written by aco-rbfn")
    if ckpt["kind"] != KIND:
        raise ValueError(f"{path} holds a {ckpt['kind']!r} model, not an IK network ({KIND!r})")
    if ckpt["format_version"] != FORMAT_VERSION:
        raise ValueError(f"{path} has checkpoint format {ckpt['format_version']}, this aco-rbfn reads "
                         f"format {FORMAT_VERSION}; use the aco-rbfn version "
                         f"{ckpt.get('package_version', '?')} that wrote it, or retrain")
    return ckpt


def model_from_checkpoint(ckpt: dict[str, Any]) -> RBFNetwork:
    """Rebuild the RBFNetwork of a checkpoint dict, in eval mode."""
    sd, a = ckpt["state_dict"], ckpt["model_args"]
    model = RBFNetwork(sd["centers"], sd["widths"], a["out_features"], tail=a["tail"])
    model.load_state_dict(sd)
    return model.eval().requires_grad_(False)


def load_model(path: str | Path) -> RBFNetwork:
    """The IK network saved at `path`, in eval mode (float64; `.float()` for float32).

    Input: positions (B, 3) in m (float32 or float64). Output: joints (B, 3) (rad, rad, m).
    `model.in_workspace(x)` / `model.solve(x)` flag positions outside the trained workspace.
    """
    return model_from_checkpoint(read_checkpoint(path))
