"""Exports that run without this package: single-file ONNX and a torch.export program (.pt2).

    python -m rbfn.export CHECKPOINT [--out-dir DIR]

Both take positions (B, 3) float32 in m (B dynamic) and return joints (B, 3) float32 (rad, rad,
m) and in_workspace (B,) bool. The ONNX graph runs large batches in blocks, as the module's eager
calls do (above `RBFNetwork.rows_per_block` rows, one Scan over equal blocks, so that a block's
(rows, M) intermediates stay in cache); the .pt2 program is one pass over all B rows. TorchScript is
deprecated in current torch and is not used.
"""
from __future__ import annotations

import argparse
import contextlib
import copy
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
    """`model` (one input (B, d); outputs (B, ...)) with its rows in blocks: where B > `rows`, one
    Scan over ceil(B / rows) blocks of equal size (the input padded with copies of its last row,
    the outputs cut back to B rows); else the graph as it was, on all B rows (an If between the
    two, so small batches pay nothing for the blocks). Row for row the same arithmetic."""
    graph = model.graph
    x, outputs = graph.input[0], list(graph.output)

    def named(v: onnx.ValueInfoProto, name: str) -> onnx.ValueInfoProto:
        """A copy of the value's type and shape under another name."""
        out = onnx.ValueInfoProto()
        out.CopyFrom(v)
        out.name = name
        return out

    def copy(name: str, rename: dict[str, str], inputs: list) -> onnx.GraphProto:
        """graph's nodes with values renamed, as a subgraph named `name` (weights stay outside)."""
        sub = helper.make_graph([], name, inputs, [named(y, rename[y.name]) for y in outputs])
        for op in graph.node:
            new = sub.node.add()
            new.CopyFrom(op)
            for names in (new.input, new.output):
                renamed = [rename.get(n, n) for n in names]
                del names[:]
                names.extend(renamed)
        return sub

    block_in = named(x, f"block_{x.name}")
    block = copy("row_block", {x.name: block_in.name, **{y.name: f"block_{y.name}" for y in outputs}}, [block_in])
    for v in (*block.input, *block.output):
        v.type.tensor_type.shape.dim[0].dim_param = "rows"
    whole = copy("all_rows", {y.name: f"all_{y.name}" for y in outputs}, [])

    width = x.type.tensor_type.shape.dim[1].dim_value
    ints = lambda name, values: numpy_helper.from_array(np.array(values, dtype=np.int64), name)
    consts = [ints("rows", [rows]), ints("one", [1]), ints("zero", [0]), ints("block_shape_end", [width])]
    node = helper.make_node
    scan = [  # blocks = ceil(B / rows) of ceil(B / blocks) rows each: fewer than `blocks` rows of padding
        node("Sub", ["batch", "one"], ["batch_less_1"]),
        node("Div", ["batch_less_1", "rows"], ["blocks_less_1"]),
        node("Add", ["blocks_less_1", "one"], ["blocks"]),
        node("Div", ["batch_less_1", "blocks"], ["size_less_1"]),
        node("Add", ["size_less_1", "one"], ["size"]),
        node("Mul", ["blocks", "size"], ["padded_batch"]),
        node("Sub", ["padded_batch", "batch"], ["pad_rows"]),
        node("Concat", ["zero", "zero", "pad_rows", "zero"], ["pads"], axis=0),
        node("Pad", [x.name, "pads"], ["padded"], mode="edge"),
        node("Concat", ["blocks", "size", "block_shape_end"], ["block_shape"], axis=0),
        node("Reshape", ["padded", "block_shape"], ["in_blocks"]),
        node("Scan", ["in_blocks"], [f"{y.name}_blocks" for y in outputs], num_scan_inputs=1, body=block)]
    for y in outputs:
        trailing = [d.dim_value for d in y.type.tensor_type.shape.dim[1:]]
        consts.append(ints(f"{y.name}_shape", [-1, *trailing]))
        scan += [node("Reshape", [f"{y.name}_blocks", f"{y.name}_shape"], [f"{y.name}_padded"]),
                 node("Slice", [f"{y.name}_padded", "zero", "batch"], [f"blocked_{y.name}"])]
    in_blocks = helper.make_graph(scan, "in_blocks", [], [named(y, f"blocked_{y.name}") for y in outputs])
    nodes = [node("Shape", [x.name], ["batch"], end=1),
             node("Greater", ["batch", "rows"], ["many_rows"]),
             node("If", ["many_rows"], [y.name for y in outputs], then_branch=in_blocks, else_branch=whole)]
    result = onnx.ModelProto()
    result.CopyFrom(model)
    result.graph.CopyFrom(helper.make_graph(nodes, graph.name, [x], outputs,
                                            initializer=[*graph.initializer, *consts]))
    return result


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
