"""Deploy the IK network with onnxruntime and numpy only (no torch, no aco-rbfn).

    pip install onnxruntime numpy
    python examples/deploy_onnx.py outputs/train/DATE/TIME_ROBOT/ik.onnx

Works on any exported network, for any robot: the file says what it takes. Its input is
"positions" (B, 3) float32 in m for a position network, "poses" (B, 7) float32 for a pose network
(position in m, then a unit quaternion (w, x, y, z)), or (B, 8) for a 7-joint arm trained with a
redundant joint (metadata "redundancy" names it; its value is the 8th column); its metadata holds a few joint vectors
inside the trained box and the targets they reach (forward kinematics, computed at export). This
solves those targets and one 10 m away, and prints the joints, the largest joint error against
the joints that reached each target (rad, or m for a prismatic joint) and the workspace flag:
the network answers every query, the flag says when not to trust the answer. A network of the
whole joint range (metadata "workspace": "full": robot.workspace=full) answers each target once
per chart, polishes the best answers in its graph to 0.1 mm / 0.1 deg and outputs "joints" (B, n),
"in_workspace" (B,) (the polish converged), and every chart's raw answer "answers" (B, K, n) with
"closeness" (B, K); this prints the polished joints and the raw answer nearest the joints the
robot is at. Where the file turns
targets around the base (metadata "base_yaw": "true": arms whose first joint turns about the
base's vertical axis), it also solves the first example turned 2 rad about the base, far outside
the trained range of that joint, and prints the first joint's change (2 rad).

Before onnxruntime sees the file, it is checked (`checked_model`): a regular file, an ONNX model
rather than a checkpoint or .pt2 program, and its SHA-256 (the metadata entry "sha256", the
file's SHA-256 with that value blank: 64 zeros in its place) matching, so a changed byte stops it
with one line instead of giving other joints. rbfn.export.read_onnx does the same with the package.

The exported model is the network alone (no robot model, so no polish): to polish its answer to
0.1 mm / 0.1 deg or pick the solution nearest the robot's current joints (`near`), use the torch
solver, `rbfn.load_solver(checkpoint).solve(targets, near=q)` (docs/deployment.md).
"""

import hashlib
import json
import os
import re
import stat
import sys

import numpy as np
import onnxruntime as ort

# The metadata entry "sha256" as protobuf writes it (key, then a 64-byte value): the file's SHA-256,
# computed with that value blank (64 zeros).
CHECKSUM_ENTRY = b"\x0a\x06sha256\x12\x40"
BLANK = b"0" * 64
REEXPORT = "Export it again: python -m rbfn.export CHECKPOINT"


def checked_model(path: str) -> bytes:
    """The bytes of the exported ONNX model at `path`, checked; SystemExit with one line naming the
    file when it is no regular file, another kind of file, damaged or without its checksum."""
    if re.match(r"[A-Za-z][A-Za-z0-9+.-]*://", path):
        sys.exit(f"{path} is a URL; this example reads a local file: download it first")
    try:
        mode = os.stat(path).st_mode
    except OSError as e:
        sys.exit(f"{path}: {e.strerror}")
    if not stat.S_ISREG(mode):
        kinds = {stat.S_ISDIR: "a directory", stat.S_ISFIFO: "a FIFO (named pipe)", stat.S_ISCHR: "a character device"}
        kind = next((name for test, name in kinds.items() if test(mode)), "not a regular file")
        sys.exit(f"{path} is {kind}, not an ONNX model: give the ik.onnx file that train.py or rbfn.export wrote")
    if os.path.getsize(path) > 2 << 30:
        sys.exit(f"{path} holds more than 2 GiB, more than an ONNX model in one file can")
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] == b"PK\x03\x04":
        sys.exit(
            f"{path} is a zip archive (an aco-rbfn checkpoint.pt or ik.pt2 program), not an ONNX model: give the "
            "ik.onnx exported beside it"
        )
    i = data.rfind(CHECKSUM_ENTRY)
    at = i + len(CHECKSUM_ENTRY)
    if i < 0 or len(data) < at + len(BLANK):
        sys.exit(
            f"{path} holds no sha256 checksum in its metadata: not an ONNX model exported by aco-rbfn, damaged, "
            f"or exported before exports carried one. {REEXPORT}"
        )
    if hashlib.sha256(data[:at] + BLANK + data[at + len(BLANK) :]).hexdigest().encode() != data[at : at + len(BLANK)]:
        sys.exit(f"{path} is corrupted: its bytes do not match the SHA-256 in its metadata. {REEXPORT}")
    return data


def turned(x: np.ndarray, angle: float) -> np.ndarray:
    """Targets x (B, 3) or (B, 7) (position in m, then a unit quaternion (w, x, y, z)), or (B, 8)
    with a redundant joint's value after the pose, turned by
    `angle` rad about the base's vertical (z) axis."""
    c, s = np.cos(angle), np.sin(angle)
    out = x.copy()
    out[:, 0], out[:, 1] = c * x[:, 0] - s * x[:, 1], s * x[:, 0] + c * x[:, 1]
    if x.shape[1] >= 7:  # (cos(a/2), 0, 0, sin(a/2)) times the quaternion; a redundant joint's value stays
        ch, sh = np.cos(angle / 2), np.sin(angle / 2)
        w, qx, qy, qz = x[:, 3], x[:, 4], x[:, 5], x[:, 6]
        out[:, 3:7] = np.stack([ch * w - sh * qz, ch * qx - sh * qy, ch * qy + sh * qx, ch * qz + sh * w], -1)
    return out


def main(path: str) -> None:
    session = ort.InferenceSession(checked_model(path), providers=["CPUExecutionProvider"])
    (inp,) = session.get_inputs()  # "positions" ["batch", 3] or "poses" ["batch", 7]
    meta = session.get_modelmeta().custom_metadata_map
    if "example_targets" not in meta:
        sys.exit(f"{path} holds no example targets: export it again with python -m rbfn.export CHECKPOINT")
    targets = np.array(json.loads(meta["example_targets"]), dtype=np.float32)  # (4, inp.shape[1])
    truth = np.array(json.loads(meta["example_joints"]), dtype=np.float32)  # (4, n)
    far = targets[:1].copy()
    far[0, 0] += 10.0  # out of reach: flagged
    print(f"{meta['robot']}: input {inp.name!r} {inp.shape}, outputs the joints {json.loads(meta['joint_names'])}")
    if meta.get("workspace") == "full":  # charts: every chart's answer
        return charted(session, inp.name, np.concatenate([targets, far]), truth)
    joints, inside = session.run(["joints", "in_workspace"], {inp.name: np.concatenate([targets, far])})
    for i, (q, ok) in enumerate(zip(joints, inside)):
        error = f"{np.abs(q - truth[i]).max():.2e}" if i < len(truth) else "-- (10 m away)"
        print(f"target {i}: joints {np.array2string(q, precision=3)}  max joint error {error}  in workspace {bool(ok)}")
    if meta.get("base_yaw") == "true":
        (q_turned,), (ok,) = session.run(["joints", "in_workspace"], {inp.name: turned(targets[:1], 2.0)})
        change = (q_turned[0] - joints[0, 0] + np.pi) % (2 * np.pi) - np.pi  # within a whole turn
        print(f"target 0 turned 2 rad about the base: first joint changes by {change:.3f} rad  in workspace {bool(ok)}")


def wrapped(d: np.ndarray) -> np.ndarray:
    """Joint differences d within half a turn (whole turns reach the same pose; a prismatic joint's
    difference in m is far below pi, so it stays as it is)."""
    return (d + np.pi) % (2 * np.pi) - np.pi


def charted(session: ort.InferenceSession, name: str, x: np.ndarray, truth: np.ndarray) -> None:
    """A charted export (metadata "workspace": "full"): the polished answer (B, n) and its flag (the
    polish converged), every chart's raw answer (B, K, n). Prints, for each target, the polished
    joints with their largest error against the joints that reached it (another branch may reach
    the same pose: then the error is large and the flag still true), and the raw answer nearest
    the joints the robot is at (here: the reaching joints moved by 0.05 rad)."""
    joints, inside, answers = session.run(["joints", "in_workspace", "answers"], {name: x})
    print(f"{answers.shape[1]} charts answer each target; the best answers are polished in the graph")
    for i in range(x.shape[0]):
        line = f"target {i}: joints {np.array2string(joints[i], precision=3)}"
        if i < len(truth):
            current = truth[i] + 0.05
            k = int(np.abs(wrapped(answers[i] - current)).max(-1).argmin())
            error = np.abs(wrapped(answers[i, k] - truth[i])).max()
            line += f"  raw answer nearest the current joints: chart {k}, max joint error {error:.2e}"
        else:
            line += "  (10 m away)"
        print(f"{line}  in workspace {bool(inside[i])}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
