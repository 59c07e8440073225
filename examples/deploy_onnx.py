"""Deploy the IK network with onnxruntime and numpy only (no torch, no aco-rbfn).

    pip install onnxruntime numpy
    python examples/deploy_onnx.py outputs/train/DATE/TIME/ik.onnx

Solves IK for a few positions of the paper's SCARA with the exported network and prints the
joints and the workspace flag; the last position lies outside the trained workspace and is
flagged. (The network answers every query; the flag says when not to trust the answer.)
"""

import sys

import numpy as np
import onnxruntime as ort


def main(path: str) -> None:
    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    targets = np.array(
        [[1.2, 0.8, -1.0], [0.5, 1.4, -0.7], [0.9, 0.9, -1.3], [2.5, 0.0, -1.0]], dtype=np.float32
    )  # the last one is out of reach
    joints, inside = session.run(["joints", "in_workspace"], {"positions": targets})
    print(f"{'target (m)':>24s} {'joints (rad, rad, m)':>28s}  in workspace")
    for t, q, ok in zip(targets, joints, inside):
        print(f"{np.array2string(t, precision=3):>24s} {np.array2string(q, precision=4):>28s}  {bool(ok)}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
