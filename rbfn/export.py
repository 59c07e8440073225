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

Both files are built in memory first and written only when both are built, all or none (each to a
temporary file beside it, renamed over the old one once both are written): an export that fails
leaves the old ik.onnx and ik.pt2 as they were. A write-protected ik.onnx or ik.pt2 is not replaced,
nor a write-protected directory written into, unless --force is given (a replaced file keeps its
mode). A bad argument (no such checkpoint, a damaged or
foreign one, an --out-dir that is a file or write-protected) is a one-line error with exit status 2;
a failed export or write, one with exit status 1.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import helper, numpy_helper
from torch import nn

from .checkpoint import model_from_checkpoint, read_checkpoint
from .data import sample_joints
from .files import unwritable, write_files
from .layer import RBFNetwork
from .robots.robot import Robot, robot_from_record
from .scripts import fail
from .yaw import BaseYaw, answer as yaw_answer, base_yaw as yaw_of

__all__ = [
    "INPUTS",
    "DeployedIK",
    "DeployedPoseIK",
    "deployed",
    "export_all",
    "export_onnx",
    "export_pt2",
    "main",
    "metadata",
    "onnx_bytes",
    "pt2_bytes",
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
EXAMPLE_TARGETS = 4  # how many example joint vectors and their targets the metadata holds


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


def deployed(net: RBFNetwork, robot: Robot | None = None, base_yaw: bool = True) -> DeployedIK:
    """The exporters' module for `net`, in eval mode: its input named for the network's targets;
    given the network's `robot` and `base_yaw`, turning targets around the base where the arm
    allows it (`rbfn.yaw`)."""
    yaw = yaw_of(robot) if robot is not None and base_yaw else None
    return (DeployedPoseIK if net.target == "pose" else DeployedIK)(net, yaw).eval()


def _example(net: RBFNetwork) -> torch.Tensor:
    """Example inputs (4, 3) positions, or (4, 7) poses with the identity quaternion."""
    x = torch.zeros(4, net.in_features, dtype=torch.float32)
    if net.target == "pose":
        x[:, 3] = 1.0
    return x


def metadata(net: RBFNetwork, robot: Robot | None = None, base_yaw: bool = True) -> dict[str, str]:
    """What the exports say about themselves, as strings: "target" ("position" or "pose"), "input"
    (the input's name and layout) and, given the network's `robot`, "robot" (its name), "base_yaw"
    ("true" where the graph turns targets around the base into the trained range, else "false"),
    "joint_names" (a JSON list: the free joints, the outputs' order), "example_joints" (a JSON (4, n)
    list: joint vectors inside the robot's sampled box, rad or m, seeded) and "example_targets" (a
    JSON (4, 3) or (4, 7) list: the targets they reach, the robot's forward kinematics, float64)."""
    meta = {"target": net.target, "input": INPUTS[net.target][1]}
    if robot is None:
        return meta
    if robot.target != net.target or len(robot.joint_names) != net.out_features:
        raise ValueError(
            f"robot {robot.name!r} ({robot.target} targets, {len(robot.joint_names)} free joints) is not the "
            f"network's ({net.target} targets, {net.out_features} joints)"
        )
    low, high = robot.low.cpu(), robot.high.cpu()
    inner = 0.2 * (high - low)  # well inside the box, away from its edges
    q = sample_joints(low + inner, high - inner, EXAMPLE_TARGETS, torch.Generator().manual_seed(0))
    return {
        **meta,
        "robot": robot.name,
        "base_yaw": "true" if base_yaw and yaw_of(robot) is not None else "false",
        "joint_names": json.dumps(robot.joint_names),
        "example_joints": json.dumps(q.tolist()),
        "example_targets": json.dumps(robot.targets(q.to(robot.chain.device)).cpu().tolist()),
    }


def pt2_bytes(net: RBFNetwork, *, robot: Robot | None = None, base_yaw: bool = True) -> bytes:
    """A torch.export program with a dynamic batch dimension, as the bytes of a .pt2 file; its
    `metadata` in the extra file "rbfn.json"; `deployed(net, robot, base_yaw)`."""
    batch = torch.export.Dim("batch", min=1)
    name = INPUTS[net.target][0]
    buf = io.BytesIO()
    with _quiet_exporter():
        module = deployed(net, robot, base_yaw)
        prog = torch.export.export(module, (_example(net),), dynamic_shapes={name: {0: batch}})
        torch.export.save(prog, buf, extra_files={"rbfn.json": json.dumps(metadata(net, robot, base_yaw))})
    return buf.getvalue()


def export_pt2(net: RBFNetwork, path: str | Path, *, robot: Robot | None = None, base_yaw: bool = True) -> Path:
    """Write a torch.export program with a dynamic batch dimension to `path` (atomically)."""
    write_files({Path(path): pt2_bytes(net, robot=robot, base_yaw=base_yaw)})
    return Path(path)


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
    net: RBFNetwork,
    path: str | Path,
    block_rows: int | None = None,
    *,
    robot: Robot | None = None,
    base_yaw: bool = True,
) -> Path:
    """Write a single-file ONNX model (input "positions" (B, 3) or "poses" (B, 7), outputs "joints",
    "in_workspace") that runs the rows in blocks of `block_rows` (default `net.rows_per_block`),
    atomically; its `metadata(net, robot)` in the model's metadata_props."""
    write_files({Path(path): onnx_bytes(net, block_rows, robot=robot, base_yaw=base_yaw)})
    return Path(path)


def onnx_bytes(
    net: RBFNetwork, block_rows: int | None = None, *, robot: Robot | None = None, base_yaw: bool = True
) -> bytes:
    """The single-file ONNX model of `export_onnx`, as bytes."""
    batch = torch.export.Dim("batch", min=1)
    name, layout = INPUTS[net.target]
    with _quiet_exporter():
        prog = torch.onnx.export(
            deployed(net, robot, base_yaw),
            (_example(net),),
            dynamo=True,
            external_data=False,
            input_names=[name],
            output_names=["joints", "in_workspace"],
            dynamic_shapes={name: {0: batch}},
            verbose=False,
        )
    assert prog is not None  # dynamo=True: always an ONNXProgram
    model = _in_row_blocks(prog.model_proto, block_rows or net.rows_per_block)
    model.graph.input[0].doc_string = layout
    joints, inside = model.graph.output
    joints.doc_string = "joints (B, n) float32: the free joints in URDF order and units (rad, or m if prismatic)"
    inside.doc_string = "in_workspace (B,) bool: the target lies in the trained workspace"
    helper.set_model_props(model, metadata(net, robot, base_yaw))
    onnx.checker.check_model(model)
    return model.SerializeToString()


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
    net: RBFNetwork, out_dir: str | Path, stem: str = "ik", *, robot: Robot | None = None, base_yaw: bool = True
) -> list[Path]:
    """Write `stem`.onnx and `stem`.pt2 into `out_dir`, with `metadata(net, robot)` (pass the
    network's robot for the example targets and the base rotation, `base_yaw`): both are built
    before either is written, and written all or none, so a failure leaves the old files as they were."""
    out_dir = Path(out_dir)
    files = {
        out_dir / f"{stem}.onnx": onnx_bytes(net, robot=robot, base_yaw=base_yaw),
        out_dir / f"{stem}.pt2": pt2_bytes(net, robot=robot, base_yaw=base_yaw),
    }
    write_files(files)
    return list(files)


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return f"{type(e).__name__}: {text.splitlines()[0]}" if text else type(e).__name__


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m rbfn.export",
        description="Export a trained IK network (a checkpoint.pt written by train.py) as ik.onnx, an ONNX model "
        "in one file, and ik.pt2, a torch.export program, to run without this package.",
        epilog="Both files are written all or none: a failed export leaves the old ones as they were. An existing "
        "write-protected ik.onnx or ik.pt2 is refused unless --force. A bad argument is an error with exit "
        "status 2, a failed export or write one with exit status 1.",
    )
    p.add_argument("checkpoint", type=Path, metavar="CHECKPOINT", help="the checkpoint.pt that train.py wrote")
    p.add_argument(
        "--out-dir",
        type=Path,
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
    if not a.checkpoint.is_file():
        fail(
            p,
            f"CHECKPOINT {a.checkpoint}: "
            + ("is a directory, not a checkpoint file" if a.checkpoint.is_dir() else "no such file"),
        )
    out_dir = a.out_dir or a.checkpoint.parent
    where = (
        f"--out-dir {out_dir}"
        if a.out_dir
        else f"the output directory {out_dir} (the checkpoint's; --out-dir picks another)"
    )
    problem = unwritable([out_dir / "ik.onnx", out_dir / "ik.pt2"], a.force)
    if problem:
        fail(p, f"{where}: {problem}")
    try:
        ckpt = read_checkpoint(a.checkpoint)
        net, robot = model_from_checkpoint(ckpt), robot_from_record(ckpt["robot"])
    except (OSError, ValueError) as e:
        message = str(e) if isinstance(e, ValueError) else _first_line(e)
        fail(p, f"CHECKPOINT: {message}" if str(a.checkpoint) in message else f"CHECKPOINT {a.checkpoint}: {message}")
    except Exception as e:  # noqa: BLE001 (a checkpoint that passes its checks but does not build: a bug)
        fail(p, f"CHECKPOINT {a.checkpoint}: cannot rebuild its network ({_first_line(e)})", status=1)
    try:
        paths = export_all(net, out_dir, robot=robot, base_yaw=not a.no_base_yaw)
    except Exception as e:  # noqa: BLE001 (torch's and onnx's exporters raise many kinds; writing, OSError)
        fail(
            p,
            f"exporting {a.checkpoint} failed ({_first_line(e)}); ik.onnx and ik.pt2 were left as they were",
            status=1,
        )
    for path in paths:
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
