"""Exports that run without this package: single-file ONNX and a torch.export program (.pt2).

    python -m rbfn.export CHECKPOINT [--out-dir DIR]

Both take positions (B, 3) float32 in m (B dynamic) and return joints (B, 3) float32 (rad, rad,
m) and in_workspace (B,) bool. The ONNX graph runs its rows in blocks, as the module's eager calls
do (one Scan over blocks of `RBFNetwork.rows_per_block` rows, so that a block's (rows, M)
intermediates stay in cache); the .pt2 program is one pass over all B rows. TorchScript is
deprecated in current torch and is not used.
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import io
import logging
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import helper, numpy_helper
from torch import nn

from .checkpoint import atomic_write_bytes, load_model
from .layer import RBFNetwork, cover_foldable

__all__ = ["DeployedIK", "export_onnx", "export_pt2", "export_all", "main"]


class DeployedIK(nn.Module):
    """The IK network in float32: positions (B, 3) in m -> (joints (B, 3), in_workspace (B,)).

    One graph for any B: the rows are not split into blocks as in the network's eager calls
    (`export_onnx` wraps the graph in a loop over blocks).
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


def export_onnx(net: RBFNetwork, path: str | Path, block_rows: int | None = None) -> Path:
    """Write a single-file ONNX model (input "positions", outputs "joints", "in_workspace") that
    runs the rows in blocks of `block_rows` (default `net.rows_per_block`)."""
    batch = torch.export.Dim("batch", min=1)
    with _quiet_exporter():
        prog = torch.onnx.export(DeployedIK(net).eval(), (_example(net),), dynamo=True, external_data=False,
                                 input_names=["positions"], output_names=["joints", "in_workspace"],
                                 dynamic_shapes={"positions": {0: batch}}, verbose=False)
    model = _in_row_blocks(prog.model_proto, block_rows or net.rows_per_block)
    onnx.checker.check_model(model)
    atomic_write_bytes(Path(path), lambda f: f.write(model.SerializeToString()))
    return Path(path)


def _in_row_blocks(model: onnx.ModelProto, rows: int) -> onnx.ModelProto:
    """`model` (one input (B, d); outputs (B, ...)) run by one Scan over blocks of `rows` rows:
    the input padded to whole blocks with copies of its last row, the outputs cut back to B rows.
    Row for row the same arithmetic as the one-pass graph."""
    graph = model.graph
    body = onnx.GraphProto()
    body.CopyFrom(graph)
    body.name = "row_block"
    del body.value_info[:]                      # shapes in the batch's symbol; ORT infers them again
    rename = {v.name: f"block_{v.name}" for v in (*body.input, *body.output)}
    for node in body.node:
        for names in (node.input, node.output):
            renamed = [rename.get(n, n) for n in names]
            del names[:]
            names.extend(renamed)
    for v in (*body.input, *body.output):
        v.name = rename[v.name]
        v.type.tensor_type.shape.dim[0].dim_param = "rows"

    x = graph.input[0]
    width = x.type.tensor_type.shape.dim[1].dim_value
    ints = lambda name, values: numpy_helper.from_array(np.array(values, dtype=np.int64), name)
    inits = [ints("rows", [rows]), ints("rows_less_1", [rows - 1]), ints("zero", [0]),
             ints("block_shape", [-1, rows, width])]
    nodes = [helper.make_node("Shape", [x.name], ["batch"], end=1),
             helper.make_node("Add", ["batch", "rows_less_1"], ["batch_up"]),
             helper.make_node("Div", ["batch_up", "rows"], ["blocks"]),          # ceil(B / rows)
             helper.make_node("Mul", ["blocks", "rows"], ["padded_batch"]),
             helper.make_node("Sub", ["padded_batch", "batch"], ["pad_rows"]),
             helper.make_node("Concat", ["zero", "zero", "pad_rows", "zero"], ["pads"], axis=0),
             helper.make_node("Pad", [x.name, "pads"], ["padded"], mode="edge"),
             helper.make_node("Reshape", ["padded", "block_shape"], ["in_blocks"]),
             helper.make_node("Scan", ["in_blocks"], [f"{y.name}_blocks" for y in graph.output],
                              num_scan_inputs=1, body=body)]
    for y in graph.output:
        trailing = [d.dim_value for d in y.type.tensor_type.shape.dim[1:]]
        inits.append(ints(f"{y.name}_shape", [-1, *trailing]))
        nodes += [helper.make_node("Reshape", [f"{y.name}_blocks", f"{y.name}_shape"], [f"{y.name}_padded"]),
                  helper.make_node("Slice", [f"{y.name}_padded", "zero", "batch"], [y.name])]
    blocked = onnx.ModelProto()
    blocked.CopyFrom(model)
    blocked.graph.CopyFrom(helper.make_graph(nodes, graph.name, [x], list(graph.output), initializer=inits))
    return blocked


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
