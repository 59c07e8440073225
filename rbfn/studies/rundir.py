"""A run directory's own bookkeeping: one process at a time, and files written whole.

`RunDir` holds an exclusive lock on the directory (flock on the directory itself, so no file is
added) for as long as a run uses it; a second process given the same directory stops with a
clear message instead of silently sharing or overwriting it. Locks are advisory and local:
processes on other hosts sharing the directory over NFS are not excluded.
"""
from __future__ import annotations

import fcntl
import io
import json
import os
import struct
from pathlib import Path

from tensorboard.compat.proto.summary_pb2 import Summary

from ..checkpoint import atomic_write_bytes

__all__ = ["RunDir", "RunDirInUse", "write_json", "write_text", "write_figure"]


class RunDirInUse(RuntimeError):
    """Another process holds the run directory."""


class RunDir:
    """Context manager: the exclusive lock on run directory `path` (created if missing)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fd: int | None = None

    def __enter__(self) -> "RunDir":
        self.path.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RunDirInUse(f"run directory {self.path} is in use by another process; wait for it to "
                              "finish, or give this run another hydra.run.dir") from None
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


def write_json(path: Path, obj) -> None:
    """`obj` as indented JSON at `path`, written atomically."""
    text = json.dumps(obj, indent=2).encode()
    atomic_write_bytes(Path(path), lambda f: f.write(text))


def write_text(path: Path, text: str) -> None:
    """`text` at `path`, written atomically."""
    data = text.encode()
    atomic_write_bytes(Path(path), lambda f: f.write(data))


def write_figure(fig, path: Path, dpi: int = 110, writer=None, tag: str = "") -> None:
    """A matplotlib figure as a PNG at `path`, written atomically, and the same PNG as
    TensorBoard's image `tag` when a `writer` is given: rendered and encoded once for both."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    data = buf.getvalue()
    atomic_write_bytes(Path(path), lambda f: f.write(data))
    if writer is not None:
        # The encoded PNG goes into the summary as it is (SummaryWriter.add_image would decode and
        # re-encode it: a quarter of a figure's cost). Width and height from its IHDR chunk.
        width, height = struct.unpack(">II", data[16:24])
        image = Summary.Image(height=height, width=width, colorspace=4, encoded_image_string=data)   # RGBA
        writer._get_file_writer().add_summary(Summary(value=[Summary.Value(tag=tag, image=image)]))
