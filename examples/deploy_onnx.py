"""Deploy the IK network with onnxruntime and numpy only (no torch, no aco-rbfn).

    pip install onnxruntime numpy
    python examples/deploy_onnx.py outputs/train/DATE/TIME/ik.onnx

Solves IK for a few positions of the paper's SCARA and checks each answer by forward
kinematics (closed form, l1 = 1.0 m, l2 = 0.8 m); the last position lies outside the trained
workspace and is flagged.
"""
import sys

import numpy as np
import onnxruntime as ort

L1, L2 = 1.0, 0.8


def fk(q: np.ndarray) -> np.ndarray:
    """SCARA positions (B, 3) in m from joints (B, 3): rad, rad, m."""
    x = L1 * np.cos(q[:, 0]) + L2 * np.cos(q[:, 0] + q[:, 1])
    y = L1 * np.sin(q[:, 0]) + L2 * np.sin(q[:, 0] + q[:, 1])
    return np.stack([x, y, -q[:, 2]], axis=1)


def main(path: str) -> None:
    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    targets = np.array([[1.2, 0.8, -1.0],
                        [0.5, 1.4, -0.7],
                        [0.9, 0.9, -1.3],
                        [2.5, 0.0, -1.0]], dtype=np.float32)   # the last one is out of reach
    joints, inside = session.run(["joints", "in_workspace"], {"positions": targets})
    reached = fk(joints.astype(np.float64))
    print(f"{'target (m)':>24s} {'joints (rad, rad, m)':>28s} {'FK error (mm)':>14s}  in workspace")
    for t, q, r, ok in zip(targets, joints, reached, inside):
        err = np.linalg.norm(r - t) * 1000
        print(f"{np.array2string(t, precision=3):>24s} {np.array2string(q, precision=4):>28s} {err:14.3f}  {bool(ok)}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
