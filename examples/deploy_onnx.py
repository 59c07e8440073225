"""Deploy the IK network with onnxruntime and numpy only (no torch, no aco-rbfn).

    pip install onnxruntime numpy
    python examples/deploy_onnx.py outputs/train/DATE/TIME/ik.onnx

Works on any exported network, for any robot: the file says what it takes. Its input is
"positions" (B, 3) float32 in m for a position network, "poses" (B, 7) float32 for a pose network
(position in m, then a unit quaternion (w, x, y, z)); its metadata holds a few joint vectors
inside the trained box and the targets they reach (forward kinematics, computed at export). This
solves those targets and one 10 m away, and prints the joints, the largest joint error against
the joints that reached each target (rad, or m for a prismatic joint) and the workspace flag:
the network answers every query, the flag says when not to trust the answer.
"""

import json
import sys

import numpy as np
import onnxruntime as ort


def main(path: str) -> None:
    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    (inp,) = session.get_inputs()  # "positions" ["batch", 3] or "poses" ["batch", 7]
    meta = session.get_modelmeta().custom_metadata_map
    if "example_targets" not in meta:
        sys.exit(f"{path} holds no example targets: export it again with python -m rbfn.export CHECKPOINT")
    targets = np.array(json.loads(meta["example_targets"]), dtype=np.float32)  # (4, inp.shape[1])
    truth = np.array(json.loads(meta["example_joints"]), dtype=np.float32)  # (4, n)
    far = targets[:1].copy()
    far[0, 0] += 10.0  # out of reach: flagged
    joints, inside = session.run(["joints", "in_workspace"], {inp.name: np.concatenate([targets, far])})

    print(f"{meta['robot']}: input {inp.name!r} {inp.shape}, outputs the joints {json.loads(meta['joint_names'])}")
    for i, (q, ok) in enumerate(zip(joints, inside)):
        error = f"{np.abs(q - truth[i]).max():.2e}" if i < len(truth) else "-- (10 m away)"
        print(f"target {i}: joints {np.array2string(q, precision=3)}  max joint error {error}  in workspace {bool(ok)}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
