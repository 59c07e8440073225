"""IK queries per second at a large batch, float32: the RBF network (torch module, ONNX under
onnxruntime) against the closed-form SCARA IK and pytorch-kinematics' iterative IK, each with
its accuracy (median FK position error of its answers).

Positions are FK images of joints drawn uniformly in the trained branch (in the workspace).
pytorch-kinematics' damped least squares is position-only (orientation weight 0) with restarts
drawn uniformly within the URDF limits; of each query's restarts the one with the smallest
position error on the trained elbow (q2 > 0) is kept. It is slow, so it runs on a smaller batch
and its rate is per query.
"""
from __future__ import annotations

import copy
import tempfile
from pathlib import Path

import torch

from rbfn import RBFNetwork, load_model
from rbfn.config import RobotConfig
from rbfn.robots import joint_limits, load_serial_chain, scara

from .timing import median_seconds, timed

__all__ = ["BRANCH_LOW", "BRANCH_HIGH", "build_network", "workspace_positions", "ik_rows"]

# The trained joint box (rad, rad, m): the default robot config's, defined once there.
BRANCH_LOW, BRANCH_HIGH = tuple(RobotConfig().joint_low), tuple(RobotConfig().joint_high)


def build_network(checkpoint: Path | None = None, num_centers: int = 80, refine: bool = True,
                  threads: int = 1) -> RBFNetwork:
    """The network under test: a checkpoint's, or one trained here by train.py's pipeline
    (k-means centres with gradient refinement, `num_centers` centres, default data)."""
    if checkpoint is not None:
        return load_model(checkpoint)
    from rbfn.config import CentersConfig, Method, RefineConfig, TrainConfig
    from rbfn.data import make_dataset
    from rbfn.pipeline import train_ik
    from rbfn.robots.robot import load_robot

    cfg = TrainConfig(centers=CentersConfig(name="kmeans_refine", method=Method.kmeans,
                                            refine=RefineConfig(enabled=refine)),
                      num_threads=threads, progress=False, export=False)
    cfg.rbfn.num_centers = num_centers
    robot = load_robot(cfg.robot)
    data = make_dataset(robot, (cfg.data.n_train, cfg.data.n_val, cfg.data.n_test), cfg.seed)
    return train_ik(cfg, data).model.eval()


def workspace_positions(n: int, seed: int = 123) -> tuple[torch.Tensor, torch.Tensor]:
    """(joints (n, 3) float64 drawn in the trained branch, their positions (n, 3) float32 in m)."""
    g = torch.Generator().manual_seed(seed)
    low, high = torch.tensor(BRANCH_LOW, dtype=torch.float64), torch.tensor(BRANCH_HIGH, dtype=torch.float64)
    q = low + torch.rand(n, 3, dtype=torch.float64, generator=g) * (high - low)
    return q, scara.fk(q).float()


def _err_mm(q_hat: torch.Tensor, x: torch.Tensor) -> float:
    """Median FK position error (mm) of joints q_hat (B, 3) for targets x (B, 3)."""
    q_hat, x = q_hat.detach().cpu().double(), x.detach().cpu().double()
    return float((scara.fk(q_hat) - x).norm(dim=-1).median() * 1000)


def pk_iterative_ik(chain, x: torch.Tensor, retries: int, seed: int = 0) -> tuple[torch.Tensor, float]:
    """pytorch-kinematics' PseudoInverseIK, position only; (joints (B, 3), share on the q2 > 0 elbow)."""
    import pytorch_kinematics as pk

    low, high = joint_limits(chain)
    limits = torch.stack([low, high], -1).to(dtype=chain.dtype, device=x.device)
    torch.manual_seed(seed)   # the solver draws its restarts from the global generator
    ik = pk.PseudoInverseIK(chain, num_retries=retries, joint_limits=limits, max_iterations=50,
                            pos_tolerance=1e-4, rot_tolerance=1e9, orientation_weight=0.0)
    sol = ik.solve(pk.Transform3d(pos=x, dtype=chain.dtype, device=x.device))
    score = sol.err_pos + 1e3 * (sol.solutions[..., 1] <= 0)          # (B, retries): wrong elbow last
    best = sol.solutions[torch.arange(x.shape[0], device=x.device), score.argmin(1)]
    return best, float((best[:, 1] > 0).float().mean())


def ik_rows(net: RBFNetwork, batch: int = 100_000, device: str = "cpu", repeats: int = 7,
            pk_batch: int = 1000, pk_retries: int = 10, pk_repeats: int = 3, threads: int = 1,
            onnx: bool = True, compiled: bool = False) -> list[dict]:
    """One row per IK method: queries/s, its ratio to the closed form and to pytorch-kinematics,
    and the median FK error (mm) of its answers. `compiled` adds the torch.compile'd module
    (its compile seconds in the note); `onnx` the ONNX model under onnxruntime, if installed."""
    _, x_cpu = workspace_positions(batch)
    x = x_cpu.to(device)
    net32 = copy.deepcopy(net).float().to(device).eval()
    rows = []

    def add(name: str, dev: str, n: int, seconds: float, answer: torch.Tensor, note: str = "") -> None:
        rows.append({"method": name, "device": dev, "batch": n, "queries_per_s": n / seconds,
                     "median_err_mm": _err_mm(answer, x_cpu[:n]), "note": note})

    with torch.inference_mode():
        t, _ = median_seconds(lambda: net32(x), repeats, device)
        add(f"RBF network, torch (M = {net.num_centers})", device, batch, t, net32(x))
        t, _ = median_seconds(lambda: net32.solve(x), repeats, device)
        add("RBF network + workspace flag, torch", device, batch, t, net32(x))
        if compiled:
            fast = torch.compile(net32)
            first = timed(lambda: fast(x), device)
            t, _ = median_seconds(lambda: fast(x), repeats, device)
            add("RBF network, torch.compile", device, batch, t, fast(x), f"compile {first - t:.1f} s")
        t, _ = median_seconds(lambda: scara.ik(x), repeats, device)
        add("closed-form SCARA IK, torch", device, batch, t, scara.ik(x))
    try:
        import onnxruntime as ort
    except ImportError:
        ort = None
        rows.append({"method": "RBF network + flag, ONNX (onnxruntime)", "device": "cpu", "batch": batch,
                     "queries_per_s": None, "median_err_mm": None, "note": "onnxruntime not installed"})
    if ort is not None and onnx:
        from rbfn.export import export_onnx

        with tempfile.TemporaryDirectory() as d:
            path = export_onnx(net, Path(d) / "ik.onnx")
            so = ort.SessionOptions()
            so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
            sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
        xn = x_cpu.numpy()
        t, _ = median_seconds(lambda: sess.run(None, {"positions": xn}), repeats)
        add("RBF network + flag, ONNX (onnxruntime)", "cpu", batch, t,
            torch.from_numpy(sess.run(None, {"positions": xn})[0]), f"onnxruntime {ort.__version__}")

    chain = load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float32, device)
    xs = x[:pk_batch]
    t, _ = median_seconds(lambda: pk_iterative_ik(chain, xs, pk_retries), pk_repeats, device, warmup=1)
    best, right = pk_iterative_ik(chain, xs, pk_retries)
    add(f"pytorch-kinematics PseudoInverseIK ({pk_retries} restarts)", device, pk_batch, t, best,
        f"position only, 50 iterations max, tol 0.1 mm; right elbow {100 * right:.1f} %")

    closed = next(r["queries_per_s"] for r in rows if r["method"].startswith("closed"))
    iterative = rows[-1]["queries_per_s"]
    for r in rows:
        qps = r["queries_per_s"]
        r["x_closed_form"] = qps / closed if qps else None
        r["x_pk_iterative"] = qps / iterative if qps else None
    return rows
