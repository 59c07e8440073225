"""Exports that run without this package: single-file ONNX and a torch.export program (.pt2).

    python -m rbfn.export CHECKPOINT [--out-dir DIR] [--force]

Both take the network's targets, B dynamic: a position network's input is named "positions", (B, 3)
float32 in m; a pose network's "poses", (B, 7) float32: position in m, then the end link's
orientation in the root frame as a unit quaternion (w, x, y, z) (q and -q give the same answer).
Both return joints (B, n) float32 (the free joints in URDF order and units: rad, or m for a
prismatic joint) and in_workspace (B,) bool. For an arm whose first joint turns about the base's
vertical axis (the SCARA, the UR5, the Panda) both turn a target anywhere around the base into
the trained range of that joint and turn the joint back, in their graph (`rbfn.yaw`, as the
solver does; metadata "base_yaw": "true"; --no-base-yaw exports the network as trained).
Both carry the same metadata (`metadata`: the target
kind, the input's layout and, given the robot, its joint names and a few example joint vectors
inside the trained box with the targets they reach): the ONNX model's metadata_props, and the
.pt2 file's extra file "rbfn.json". The ONNX graph runs large batches in blocks, as the module's eager
calls do (above `RBFNetwork.rows_per_block` rows, one Scan over equal blocks, so that a block's
(rows, M) intermediates stay in cache); the .pt2 program is one pass over all B rows. TorchScript is
deprecated in current torch and is not used.

Both files carry a SHA-256 their readers check (`read_onnx`, `load_pt2`, examples/deploy_onnx.py),
so a changed byte is an error instead of other joints: the ONNX model in its metadata entry
"sha256", the SHA-256 of the file with that entry's value blank (64 zeros; the value replaces the
zeros in place, so the check needs no ONNX parser: `onnx_checksum`); the .pt2 file in its zip
archive's comment, as a checkpoint's (rbfn.checkpoint.seal: torch.export.load reads it as it is).

Both files are built in memory first and written only when both are built, all or none (each to a
temporary file beside it, renamed over the old one once both are written): an export that fails
or is interrupted leaves the old ik.onnx and ik.pt2 as they were. A write-protected ik.onnx or
ik.pt2 is not replaced, nor a write-protected directory written into, unless --force is given (a
replaced file keeps its mode). Every path is checked before any work: a bad argument (a checkpoint
that is missing, no regular file, a URL, damaged, foreign or an export; an --out-dir that is a file,
a dangling link or write-protected) is a one-line error with exit status 2; a failed export or write,
one with exit status 1. A stop signal (Ctrl-C's SIGINT, SIGTERM, SIGHUP) ends it with one line saying
what was written (nothing, unless the signal came while the finished files were being renamed) and
exit status 128 + the signal's number (130 for SIGINT), even where torch's exporter swallowed the
KeyboardInterrupt (`rbfn.files.signals_raised`).

Why one module of over 500 lines: the ONNX and .pt2 exports share their metadata, checksums,
base-yaw handling and polish graph, and each is written and read back by the same code.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import logging
import os
import signal
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxscript
import torch
from onnx import helper, numpy_helper
from onnx_ir.passes.common import RemoveUnusedNodesPass
from torch import nn

from .charts import ChartedIK, charts_from_checkpoint
from .checkpoint import (
    CHARTS_KIND,
    MAX_SEALED_BYTES,
    ONNX_MODEL,
    PT2_PROGRAM,
    file_format,
    local_file,
    model_from_checkpoint,
    read_checkpoint,
    refuse_url,
    seal,
    unseal,
)
from .data import sample_joints
from .files import discard, signals_raised, unwritable, write_files
from .layer import RBFNetwork
from .robots.robot import Robot, robot_from_record
from .scripts import fail
from .studies.stop import Stopped, stop_on_signals
from .yaw import BaseYaw, answer as yaw_answer, base_yaw as yaw_of

__all__ = [
    "CHECKSUM_KEY",
    "INPUTS",
    "DeployedCharts",
    "DeployedIK",
    "DeployedPoseIK",
    "deployed",
    "export_all",
    "export_onnx",
    "export_pt2",
    "load_pt2",
    "main",
    "metadata",
    "onnx_bytes",
    "onnx_checksum",
    "pt2_bytes",
    "read_onnx",
]

# The exported input's name and layout by the network's target kind ("positions": the name since the first export).
INPUTS = {
    "position": ("positions", "positions (B, 3) float32 in m"),
    "pose": (
        "poses",
        "poses (B, 7) float32: position in m, then the end link's orientation in the root frame "
        "as a unit quaternion (w, x, y, z)",
    ),
}
CHART_BLOCK_ROWS = 512  # a charted ONNX graph's rows a block (UR5, 4 000 poses, one thread: 13 % faster than 54)
EXAMPLE_TARGETS = 4  # how many example joint vectors and their targets the metadata holds
CHECKSUM_KEY = "sha256"  # the ONNX model's metadata entry holding the file's SHA-256 (hex)
# That entry as protobuf writes it (a StringStringEntryProto: field 1 the key, then field 2, 64
# bytes): the hex digest follows, in place of 64 zeros while it is computed.
_CHECKSUM_ENTRY = b"\x0a\x06" + CHECKSUM_KEY.encode() + b"\x12\x40"
_BLANK = b"0" * 64
_REEXPORT = "Export it again: python -m rbfn.export CHECKPOINT"


class DeployedIK(nn.Module):
    """The IK network in float32: positions (B, 3) in m -> (joints (B, n), in_workspace (B,)).

    One graph for any B: the rows are not split into blocks as in the network's eager calls
    (`export_onnx` wraps the graph in a loop over blocks). What it takes of the network is its
    documented export interface: `RBFNetwork.for_export`, `solve_rows`, `rows_per_block`,
    `in_features` and `target`. With `yaw` (the robot's `rbfn.yaw.BaseYaw`), targets anywhere
    around the base are turned into the trained range and the first joint turned back, in the
    graph (`rbfn.yaw.answer`, as the solver does); in_workspace is then also False where no whole
    turn brings the first joint inside its URDF limits.
    """

    def __init__(self, net: RBFNetwork, yaw: BaseYaw | None = None) -> None:
        super().__init__()
        self.net = net.for_export()
        self.yaw = yaw

    def _solve(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.yaw is None:
            return self.net.solve_rows(x)
        q, inside, _ = yaw_answer(self.yaw, self.net.solve_rows, x)
        return q, inside

    def forward(self, positions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self._solve(positions)


class DeployedPoseIK(DeployedIK):
    """`DeployedIK` of a pose network: poses (B, 7) (position in m, then a unit quaternion (w, x,
    y, z)) -> (joints (B, n), in_workspace (B,)). Its own class so the exported input is named
    "poses" (torch.export names it after `forward`'s argument)."""

    def forward(self, poses: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self._solve(poses)


class DeployedCharts(nn.Module):
    """A charted network (`rbfn.charts.ChartedIK`, robot.workspace=full) with its polish, in float32:
    positions (B, 3) -> (joints (B, n): the best answer polished (`rbfn.graph_polish.GraphPolish`,
    a fixed set of answers polished on every row), within the URDF limits; in_workspace (B,): that
    polish converged within the tolerances (0.1 mm, 0.1 deg); answers (B, K, n): every chart's raw
    answer, for a caller who picks another (the one nearest its current joints, say) and polishes
    it; closeness (B, K): each chart's nearest centre's distance over its cover radius, below 1
    inside the region it learned). What it takes of the model: `ChartedIK.frozen` and `answer_rows`."""

    def __init__(self, model: ChartedIK, robot: Robot) -> None:
        super().__init__()
        from .graph_polish import graph_polish

        self.charts = model.frozen(torch.float32)
        self.charts.nets = nn.ModuleList([self.charts.first])  # the rest are stacked: not carried twice
        self.polish = graph_polish(robot, model).float()

    def _answer(self, x: torch.Tensor):
        answers, close = self.charts.answer_rows(x)
        q, converged = self.polish(answers, close, x.to(answers.dtype))
        return q, converged, answers, close

    def forward(self, positions: torch.Tensor):
        return self._answer(positions)


class DeployedPoseCharts(DeployedCharts):
    """`DeployedCharts` of a pose network: poses (B, 7), or (B, 8) with the redundant joint's value."""

    def forward(self, poses: torch.Tensor):
        return self._answer(poses)


Exportable = RBFNetwork | ChartedIK  # what the exporters take: one box network or a charted one


def _net(model: Exportable) -> RBFNetwork:
    """The network whose inputs and target kind the export takes (a charted model's first chart)."""
    return model.first if isinstance(model, ChartedIK) else model


def deployed(net: Exportable, robot: Robot | None = None, base_yaw: bool = True) -> nn.Module:
    """The exporters' module for `net`, in eval mode: its input named for the network's targets;
    given a box network's `robot` and `base_yaw`, turning targets around the base where the arm
    allows it (`rbfn.yaw`); a charted network's every chart (`DeployedCharts`)."""
    if isinstance(net, ChartedIK):
        if robot is None:
            raise ValueError("a charted network's export polishes its answers: pass its robot (robot=)")
        return (DeployedPoseCharts if net.first.target == "pose" else DeployedCharts)(net, robot).eval()
    yaw = yaw_of(robot) if robot is not None and base_yaw else None
    return (DeployedPoseIK if net.target == "pose" else DeployedIK)(net, yaw).eval()


def _outputs(model: Exportable) -> dict[str, str]:
    """The exported outputs' names and what they hold, in order."""
    joints = "the free joints in URDF order and units (rad, or m if prismatic)"
    if not isinstance(model, ChartedIK):
        return {
            "joints": f"joints (B, n) float32: {joints}",
            "in_workspace": "in_workspace (B,) bool: the target lies in the trained workspace",
        }
    return {
        "joints": f"joints (B, n) float32: the best chart's answer polished, {joints}, within the URDF limits",
        "in_workspace": "in_workspace (B,) bool: the polish converged (within 0.1 mm and 0.1 deg of the target)",
        "answers": f"answers (B, K, n) float32: every chart's raw answer, {joints}, within the URDF limits",
        "closeness": "closeness (B, K) float32: each chart's nearest centre's distance over its cover radius "
        "(below 1: inside the region the chart learned)",
    }


def _example(net: Exportable) -> torch.Tensor:
    """Example inputs (4, 3) positions, or (4, 7) (or (4, 8)) poses with the identity quaternion."""
    net = _net(net)
    x = torch.zeros(4, net.in_features, dtype=torch.float32)
    if net.target == "pose":
        x[:, 3] = 1.0
    return x


def metadata(model: Exportable, robot: Robot | None = None, base_yaw: bool = True) -> dict[str, str]:
    """What the exports say about themselves, as strings: "target" ("position" or "pose"), "input"
    (the input's name and layout), "workspace" ("box": one network; "full": charts, every chart's
    answer), "charts" (how many; 1 for a box network), "outputs" (a JSON object: each output's name
    and layout) and, given the network's `robot`, "robot" (its name), "base_yaw" ("true" where the
    graph turns targets around the base into the trained range, else "false"), "joint_names" (a
    JSON list: the free joints, the outputs' order), "example_joints" (a JSON (4, n) list: joint
    vectors inside the robot's sampled box (a charted network: its URDF range), rad or m, seeded),
    "example_targets" (a JSON (4, 3) or (4, 7) list: the targets they reach, the robot's forward
    kinematics, float64) and, for a 7-joint arm, "redundancy" (the joint whose value is the input's
    last column)."""
    charted = isinstance(model, ChartedIK)
    net = _net(model)
    layout = INPUTS[net.target][1]
    if net.inputs is not None and net.inputs.redundancy:
        layout = layout.replace("poses (B, 7)", "poses (B, 8)") + (
            ", then the redundant joint's value (rad, or m if prismatic; metadata redundancy names it)"
        )
    meta = {
        "target": net.target,
        "input": layout,
        "workspace": "full" if charted else "box",
        "charts": str(model.num_charts if isinstance(model, ChartedIK) else 1),
        "outputs": json.dumps(_outputs(model)),
    }
    if robot is None:
        return meta
    joints = model.out_features
    if robot.target != net.target or len(robot.joint_names) != joints:
        raise ValueError(
            f"robot {robot.name!r} ({robot.target} targets, {len(robot.joint_names)} free joints) is not the "
            f"network's ({net.target} targets, {joints} joints)"
        )
    low, high = (model.low, model.high) if isinstance(model, ChartedIK) else (robot.low, robot.high)
    low, high = low.cpu().to(robot.low.dtype), high.cpu().to(robot.low.dtype)
    inner = 0.2 * (high - low)  # well inside the box, away from its edges
    q = sample_joints(low + inner, high - inner, EXAMPLE_TARGETS, torch.Generator().manual_seed(0))
    return {
        **meta,
        "robot": robot.name,
        "base_yaw": "true" if base_yaw and not charted and yaw_of(robot) is not None else "false",
        "joint_names": json.dumps(robot.joint_names),
        "example_joints": json.dumps(q.tolist()),
        "example_targets": json.dumps(robot.inputs(q.to(robot.chain.device)).cpu().tolist()),
        **({"redundancy": robot.redundancy} if robot.redundancy else {}),
    }


def pt2_bytes(net: Exportable, *, robot: Robot | None = None, base_yaw: bool = True) -> bytes:
    """A torch.export program with a dynamic batch dimension, as the bytes of a .pt2 file; its
    `metadata` in the extra file "rbfn.json"; `deployed(net, robot, base_yaw)`."""
    batch = torch.export.Dim("batch", min=1)
    name = INPUTS[_net(net).target][0]
    buf = io.BytesIO()
    with _quiet_exporter():
        module = deployed(net, robot, base_yaw)
        prog = torch.export.export(module, (_example(net),), dynamic_shapes={name: {0: batch}})
        torch.export.save(prog, buf, extra_files={"rbfn.json": json.dumps(metadata(net, robot, base_yaw))})
    return seal(buf.getvalue())


def _read_export(path: str | os.PathLike[str], what: str, expected: str, bound: str) -> tuple[Path, bytes, str | None]:
    """(the local path, its bytes, the kind of file they are (file_format)) of export `path`, read
    only when it is a regular file of at most MAX_SEALED_BYTES (`bound` says why in the error) and
    not another known kind of file than `expected`."""
    local = local_file(path, what)
    size = local.stat().st_size
    if size > MAX_SEALED_BYTES:
        raise ValueError(f"{local} holds {size / 2**30:.3g} GiB; {bound}")
    data = local.read_bytes()
    kind = file_format(data)
    if kind not in (None, expected):
        raise ValueError(f"{local} is {kind}, not {expected}")
    return local, data, kind


def load_pt2(path: str | os.PathLike[str], extra_files: dict[str, Any] | None = None) -> torch.export.ExportedProgram:
    """The torch.export program of the .pt2 file at `path` (`torch.export.load(path, extra_files)`:
    `extra_files={"rbfn.json": ""}` is filled with its metadata), after checking its SHA-256:
    ValueError naming the file when it is damaged, not a .pt2 export of aco-rbfn, or no regular file."""
    path, data, kind = _read_export(
        path, "torch.export program", PT2_PROGRAM, "a .pt2 program aco-rbfn exports is far smaller"
    )
    original = unseal(data, path, "torch.export program", advice=_REEXPORT)
    if kind is None:  # sealed, so as written: but by something else than torch.export.save
        raise ValueError(f"{path} is not {PT2_PROGRAM}: it names no archive_format pt2")
    with _quiet_exporter():
        return torch.export.load(io.BytesIO(original), extra_files=extra_files)


def _local(path: str | os.PathLike[str], name: str) -> Path:
    """`path` as a Path, refused where it is a URL (as a path, its "//" would fold into a local name)."""
    refuse_url(path, f"{name}={path}")
    return Path(path)


def export_pt2(net: Exportable, path: str | Path, *, robot: Robot | None = None, base_yaw: bool = True) -> Path:
    """Write a torch.export program with a dynamic batch dimension to `path` (atomically)."""
    path = _local(path, "path")
    write_files({path: pt2_bytes(net, robot=robot, base_yaw=base_yaw)})
    return path


@contextlib.contextmanager
def _quiet_exporter():
    """Silence, narrowly and only while exporting, what torch's exporters say about themselves:
    their per-pass INFO lines and the notice that torchvision's operators are not registered (this
    model has none), and torch 2.13's FutureWarning from its own use of the deprecated LeafSpec."""
    quiet = [
        logging.getLogger(n)
        for n in ("onnx_ir", "onnxscript", "torch.onnx", "torch.onnx._internal.exporter._registration")
    ]
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


def export_onnx(
    net: Exportable,
    path: str | Path,
    block_rows: int | None = None,
    *,
    robot: Robot | None = None,
    base_yaw: bool = True,
) -> Path:
    """Write a single-file ONNX model (input "positions" (B, 3) or "poses" (B, 7), outputs "joints",
    "in_workspace"; a charted network's "joints", "closeness", "in_workspace") that runs the rows in
    blocks of `block_rows` (default `net.rows_per_block`), atomically; its `metadata(net, robot)` in
    the model's metadata_props."""
    path = _local(path, "path")
    write_files({path: onnx_bytes(net, block_rows, robot=robot, base_yaw=base_yaw)})
    return path


def onnx_bytes(
    net: Exportable, block_rows: int | None = None, *, robot: Robot | None = None, base_yaw: bool = True
) -> bytes:
    """The single-file ONNX model of `export_onnx`, as bytes."""
    batch = torch.export.Dim("batch", min=1)
    name = INPUTS[_net(net).target][0]
    layout = metadata(net)["input"]
    charted = isinstance(net, ChartedIK)
    outputs = _outputs(net)
    with _quiet_exporter():
        prog = torch.onnx.export(
            deployed(net, robot, base_yaw),
            (_example(net),),
            dynamo=True,
            external_data=False,
            input_names=[name],
            output_names=list(outputs),
            dynamic_shapes={name: {0: batch}},
            verbose=False,
            # The charts' polish unrolls into thousands of small operations, over which the exporter's
            # optimizer takes many minutes: its constants are folded alone (seconds), unused nodes removed.
            optimize=not charted,
        )
        assert prog is not None  # dynamo=True: always an ONNXProgram
        if charted:
            onnxscript.optimizer.fold_constants(prog.model)
            RemoveUnusedNodesPass()(prog.model)
    rows = block_rows or (CHART_BLOCK_ROWS if charted else net.rows_per_block)
    model = _in_row_blocks(_bare(prog.model_proto), rows)
    model.graph.input[0].doc_string = layout
    for out in model.graph.output:
        out.doc_string = outputs[out.name]
    helper.set_model_props(model, {**metadata(net, robot, base_yaw), CHECKSUM_KEY: _BLANK.decode()})
    onnx.checker.check_model(model)
    data = model.SerializeToString()
    at = data.rfind(_CHECKSUM_ENTRY + _BLANK) + len(_CHECKSUM_ENTRY)
    return data[:at] + hashlib.sha256(data).hexdigest().encode() + data[at + len(_BLANK) :]


def _bare(model: onnx.ModelProto) -> onnx.ModelProto:
    """`model` without the exporter's notes on each node (its FX node, stack trace, module path:
    a kilobyte a node, most of a charted model's bytes), in place."""
    for node in model.graph.node:
        del node.metadata_props[:]
        node.doc_string = ""
    return model


def onnx_checksum(data: bytes) -> tuple[bytes, bytes] | None:
    """(the SHA-256 (hex) an exported ONNX model `data` holds, the SHA-256 its bytes have with that
    value blank); None when it holds none. Equal for a file as `onnx_bytes` wrote it."""
    i = data.rfind(_CHECKSUM_ENTRY)
    if i < 0 or len(data) < i + len(_CHECKSUM_ENTRY) + len(_BLANK):
        return None
    at = i + len(_CHECKSUM_ENTRY)
    blank = data[:at] + _BLANK + data[at + len(_BLANK) :]
    return data[at : at + len(_BLANK)], hashlib.sha256(blank).hexdigest().encode()


def read_onnx(path: str | os.PathLike[str]) -> bytes:
    """The bytes of the exported ONNX model at `path`, its SHA-256 checked (give them to
    `onnxruntime.InferenceSession`): ValueError naming the file when it is damaged, holds no
    checksum (exported before exports had one, or by another program), is another kind of file
    (a checkpoint, a .pt2 program) or no regular file."""
    path, data, _ = _read_export(path, "ONNX model", ONNX_MODEL, "an ONNX model in one file is at most 2 GiB")
    sums = onnx_checksum(data)
    if sums is None:
        raise ValueError(
            f"{path} holds no {CHECKSUM_KEY} checksum in its metadata: damaged, exported before exports carried "
            f"one, or not exported by aco-rbfn. {_REEXPORT}"
        )
    if sums[0] != sums[1]:
        raise ValueError(f"{path} is corrupted: its bytes do not match the SHA-256 in its metadata. {_REEXPORT}")
    return data


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

    def ints(name: str, values: list[int]):
        return numpy_helper.from_array(np.array(values, dtype=np.int64), name)

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
        node("Scan", ["in_blocks"], [f"{y.name}_blocks" for y in outputs], num_scan_inputs=1, body=block),
    ]
    for y in outputs:
        trailing = [d.dim_value for d in y.type.tensor_type.shape.dim[1:]]
        consts.append(ints(f"{y.name}_shape", [-1, *trailing]))
        scan += [
            node("Reshape", [f"{y.name}_blocks", f"{y.name}_shape"], [f"{y.name}_padded"]),
            node("Slice", [f"{y.name}_padded", "zero", "batch"], [f"blocked_{y.name}"]),
        ]
    in_blocks = helper.make_graph(scan, "in_blocks", [], [named(y, f"blocked_{y.name}") for y in outputs])
    nodes = [
        node("Shape", [x.name], ["batch"], end=1),
        node("Greater", ["batch", "rows"], ["many_rows"]),
        node("If", ["many_rows"], [y.name for y in outputs], then_branch=in_blocks, else_branch=whole),
    ]
    result = onnx.ModelProto()
    result.CopyFrom(model)
    result.graph.CopyFrom(helper.make_graph(nodes, graph.name, [x], outputs, initializer=[*graph.initializer, *consts]))
    return result


def export_all(
    net: Exportable, out_dir: str | Path, stem: str = "ik", *, robot: Robot | None = None, base_yaw: bool = True
) -> list[Path]:
    """Write `stem`.onnx and `stem`.pt2 into `out_dir`, with `metadata(net, robot)` (pass the
    network's robot for the example targets and the base rotation, `base_yaw`): both are built
    before either is written, and written all or none, so a failure leaves the old files as they were.
    A stop signal while they are built (Ctrl-C: KeyboardInterrupt) writes nothing, even where torch's
    exporter swallowed its exception (`rbfn.files.signals_raised`)."""
    out_dir = _local(out_dir, "out_dir")
    with signals_raised():
        files = {
            out_dir / f"{stem}.onnx": onnx_bytes(net, robot=robot, base_yaw=base_yaw),
            out_dir / f"{stem}.pt2": pt2_bytes(net, robot=robot, base_yaw=base_yaw),
        }
    write_files(files)
    return list(files)


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return f"{type(e).__name__}: {text.splitlines()[0]}" if text else type(e).__name__


def _identity(path: Path) -> tuple[int, int] | None:
    """Which file is at `path` now (device, inode; None for none): a renamed-over file is another."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_dev, st.st_ino


def main(argv: list[str] | None = None) -> None:
    if signal.getsignal(signal.SIGINT) == signal.SIG_DFL:  # as rbfn/__init__.py set it for the imports
        signal.signal(signal.SIGINT, signal.default_int_handler)
    stop_on_signals()  # SIGTERM, SIGHUP (and SIGINT where rbfn.studies.stop handles it) raise Stopped
    p = argparse.ArgumentParser(
        prog="python -m rbfn.export",
        description="Export a trained IK network (a checkpoint.pt written by train.py) as ik.onnx, an ONNX model "
        "in one file, and ik.pt2, a torch.export program, to run without this package.",
        epilog="Both files are written all or none: a failed or interrupted export leaves the old ones as they "
        "were. An existing write-protected ik.onnx or ik.pt2 is refused unless --force. A bad argument is an "
        "error with exit status 2, a failed export or write one with exit status 1, a stop by a signal one "
        "with 128 + its number (130 for Ctrl-C).",
    )
    p.add_argument("checkpoint", metavar="CHECKPOINT", help="the checkpoint.pt that train.py wrote")
    p.add_argument(
        "--out-dir",
        default=None,
        metavar="DIR",
        help="where to write ik.onnx and ik.pt2, created if missing (default: the checkpoint's directory)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write even over a write-protected ik.onnx or ik.pt2 or into a write-protected directory "
        "(replaced files keep their mode)",
    )
    p.add_argument(
        "--no-base-yaw",
        action="store_true",
        help="export the network as trained, without turning targets around the base into its trained range "
        "(the default does, for arms whose first joint turns about the base's vertical axis)",
    )
    a = p.parse_args(argv)
    targets: list[Path] = []
    before: list[tuple[int, int] | None] = []
    try:
        with signals_raised():  # a signal's exception that torch swallowed or replaced: raised here
            targets = _checked_outputs(p, a)
            before = [_identity(t) for t in targets]
            net, robot = _network(p, a.checkpoint)
            try:
                export_all(net, targets[0].parent, robot=robot, base_yaw=not a.no_base_yaw)
            except Exception as e:  # noqa: BLE001 (torch's and onnx's exporters raise many kinds; writing, OSError)
                fail(
                    p,
                    f"exporting {a.checkpoint} failed ({_first_line(e)}); ik.onnx and ik.pt2 were left as they were",
                    status=1,
                )
    except (KeyboardInterrupt, Stopped) as e:
        signum = e.signum if isinstance(e, Stopped) else signal.SIGINT
        signal.signal(signum, signal.SIG_IGN)  # ending now: a second Ctrl-C would cut the exit short (as stop's)
        written = bool(targets) and all(_identity(t) != b for t, b in zip(targets, before))
        what = (
            f"{targets[0]} and {targets[1]} were written (the signal came as they were renamed)"
            if written
            else "nothing was written; ik.onnx and ik.pt2 were left as they were"
        )
        status = 128 + signum
        p.exit(status, f"{p.prog}: stopped by {signal.Signals(signum).name} (exit status {status}): {what}\n")
    try:
        for path in targets:
            print(f"wrote {path}", flush=True)
    except BrokenPipeError:  # the reader left (| head -1): the files are written; the rest goes nowhere
        discard(sys.stdout)


def _checked_outputs(p: argparse.ArgumentParser, a: argparse.Namespace) -> list[Path]:
    """ik.onnx and ik.pt2 in the output directory, after checking every path given, before any work:
    a one-line error (status 2) for a checkpoint that is no regular file or a URL, and an --out-dir
    that is a URL, empty, or cannot or must not be written (`rbfn.files.unwritable`)."""
    try:
        checkpoint = local_file(a.checkpoint)
    except FileNotFoundError:
        fail(p, f"CHECKPOINT {a.checkpoint}: no such file")
    except ValueError as e:
        fail(p, f"CHECKPOINT: {e}")
    if a.out_dir is not None:
        try:
            refuse_url(a.out_dir, f"--out-dir {a.out_dir}")
        except ValueError as e:
            fail(p, str(e))
        if not a.out_dir:
            fail(p, "--out-dir '' names no directory; give one, or leave --out-dir out for the checkpoint's")
    out_dir = Path(a.out_dir) if a.out_dir else checkpoint.parent
    where = (
        f"--out-dir {out_dir}"
        if a.out_dir
        else f"the output directory {out_dir} (the checkpoint's; --out-dir picks another)"
    )
    targets = [out_dir / "ik.onnx", out_dir / "ik.pt2"]
    problem = unwritable(targets, a.force)
    if problem:
        fail(p, f"{where}: {problem}")
    return targets


def _network(p: argparse.ArgumentParser, checkpoint: str) -> tuple[Exportable, Robot]:
    """The checkpoint's network (box or charted) and robot; a one-line error when it cannot be read (status 2) or
    passes its checks and still does not build (status 1: a bug)."""
    try:
        ckpt = read_checkpoint(checkpoint)
        model = charts_from_checkpoint(ckpt) if ckpt["kind"] == CHARTS_KIND else model_from_checkpoint(ckpt)
        return model, robot_from_record(ckpt["robot"])
    except (OSError, ValueError) as e:
        message = str(e) if isinstance(e, ValueError) else _first_line(e)
        fail(p, f"CHECKPOINT: {message}" if str(checkpoint) in message else f"CHECKPOINT {checkpoint}: {message}")
    except Exception as e:  # noqa: BLE001 (a checkpoint that passes its checks but does not build: a bug)
        fail(p, f"CHECKPOINT {checkpoint}: cannot rebuild its network ({_first_line(e)})", status=1)


if __name__ == "__main__":
    main()
