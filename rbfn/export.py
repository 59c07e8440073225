"""Exports that run without this package: single-file ONNX and a torch.export program (.pt2).

    python -m rbfn.export CHECKPOINT [--out-dir DIR]

Both take positions (B, 3) float32 in m (B dynamic) and return joints (B, 3) float32 (rad, rad,
m) and in_workspace (B,) bool. TorchScript is deprecated in current torch and is not used.
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import io
import logging
import warnings
from pathlib import Path

import torch
from torch import nn

from .checkpoint import atomic_write_bytes, load_model
from .layer import RBFNetwork, cover_foldable

__all__ = ["DeployedIK", "export_onnx", "export_pt2", "export_all", "main"]


class DeployedIK(nn.Module):
    """The IK network in float32: positions (B, 3) in m -> (joints (B, 3), in_workspace (B,)).

    One graph for any B: the rows are not split into blocks as in the network's eager calls.
    """

    def __init__(self, net: RBFNetwork) -> None:
        super().__init__()
        self.net = copy.deepcopy(net).float().eval().requires_grad_(False)
        self.net.traced_cover_fold = cover_foldable(self.net.widths, self.net.cover_radius)

    def forward(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.net._solve_rows(self.net._inputs(positions))


def _example(net: RBFNetwork) -> torch.Tensor:
    """Example inputs (4, 3) positions, or (4, 7) poses with the identity quaternion."""
    x = torch.zeros(4, net.in_features, dtype=torch.float32)
    if net.target == "pose":
        x[:, 3] = 1.0
    return x


def export_pt2(net: RBFNetwork, path: str | Path) -> Path:
    """Write a torch.export program with a dynamic batch dimension to `path` (atomically)."""
    batch = torch.export.Dim("batch", min=1)
    with _quiet_exporter():
        prog = torch.export.export(DeployedIK(net).eval(), (_example(net),), dynamic_shapes={"positions": {0: batch}})
        atomic_write_bytes(Path(path), lambda f: torch.export.save(prog, f))
    return Path(path)


@contextlib.contextmanager
def _quiet_exporter():
    """Silence, narrowly and only while exporting, what torch's exporters say about themselves:
    their per-pass INFO lines and the notice that torchvision's operators are not registered (this
    model has none), and torch 2.13's FutureWarning from its own use of the deprecated LeafSpec."""
    quiet = [logging.getLogger(n) for n in ("onnx_ir", "onnxscript", "torch.onnx",
                                            "torch.onnx._internal.exporter._registration")]
    levels = [lg.level for lg in quiet]
    for lg in quiet:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning, message=r".*isinstance\(treespec, LeafSpec\)")
            yield
    finally:
        for lg, level in zip(quiet, levels):
            lg.setLevel(level)


def export_onnx(net: RBFNetwork, path: str | Path) -> Path:
    """Write a single-file ONNX model (input "positions", outputs "joints", "in_workspace")."""
    batch = torch.export.Dim("batch", min=1)
    with _quiet_exporter():
        prog = torch.onnx.export(DeployedIK(net).eval(), (_example(net),), dynamo=True, external_data=False,
                                 input_names=["positions"], output_names=["joints", "in_workspace"],
                                 dynamic_shapes={"positions": {0: batch}}, verbose=False)
    buf = io.BytesIO()
    prog.save(buf)
    atomic_write_bytes(Path(path), lambda f: f.write(buf.getvalue()))
    return Path(path)


def export_all(net: RBFNetwork, out_dir: str | Path, stem: str = "ik") -> list[Path]:
    """Write `stem`.onnx and `stem`.pt2 into `out_dir`."""
    out_dir = Path(out_dir)
    return [export_onnx(net, out_dir / f"{stem}.onnx"), export_pt2(net, out_dir / f"{stem}.pt2")]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m rbfn.export", description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--out-dir", type=Path, default=None, help="default: the checkpoint's directory")
    a = p.parse_args(argv)
    for path in export_all(load_model(a.checkpoint), a.out_dir or a.checkpoint.parent):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
