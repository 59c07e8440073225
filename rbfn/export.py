"""Exports that run without this package: single-file ONNX and a torch.export program (.pt2).

    python -m rbfn.export CHECKPOINT [--out-dir DIR]

Both take positions (B, 3) float32 in m (B dynamic) and return joints (B, 3) float32 (rad, rad,
m) and in_workspace (B,) bool. TorchScript is deprecated in current torch and is not used.
"""
from __future__ import annotations

import argparse
import copy
from pathlib import Path

import torch
from torch import nn

from .checkpoint import atomic_write_bytes, load_model
from .layer import RBFNetwork

__all__ = ["DeployedIK", "export_onnx", "export_pt2", "export_all", "main"]


class DeployedIK(nn.Module):
    """The IK network in float32 returning (joints (B, 3), in_workspace (B,))."""

    def __init__(self, net: RBFNetwork) -> None:
        super().__init__()
        self.net = copy.deepcopy(net).float().eval().requires_grad_(False)

    def forward(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.net.solve(positions)


def _example(net: RBFNetwork) -> torch.Tensor:
    return torch.zeros(4, net.centers.shape[1], dtype=torch.float32)


def export_pt2(net: RBFNetwork, path: str | Path) -> Path:
    """Write a torch.export program with a dynamic batch dimension to `path` (atomically)."""
    batch = torch.export.Dim("batch", min=1)
    prog = torch.export.export(DeployedIK(net), (_example(net),), dynamic_shapes={"positions": {0: batch}})
    atomic_write_bytes(Path(path), lambda f: torch.export.save(prog, f))
    return Path(path)


def export_onnx(net: RBFNetwork, path: str | Path) -> Path:
    """Write a single-file ONNX model (input "positions", outputs "joints", "in_workspace")."""
    import io
    import logging

    batch = torch.export.Dim("batch", min=1)
    quiet = [logging.getLogger(n) for n in ("onnx_ir", "onnxscript", "torch.onnx")]
    levels = [lg.level for lg in quiet]
    for lg in quiet:  # the exporter's per-pass INFO lines would flood a Hydra run's log
        lg.setLevel(logging.WARNING)
    try:
        prog = torch.onnx.export(DeployedIK(net), (_example(net),), dynamo=True, external_data=False,
                                 input_names=["positions"], output_names=["joints", "in_workspace"],
                                 dynamic_shapes={"positions": {0: batch}}, verbose=False)
    finally:
        for lg, level in zip(quiet, levels):
            lg.setLevel(level)
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
