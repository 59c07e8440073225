"""IK queries per second at a large batch, float32: the RBF network (torch module as
`rbfn.load_model` gives it, ONNX under onnxruntime) against the closed-form SCARA IK and
pytorch-kinematics' iterative IK, each with its accuracy (median FK position error of its answers)
and its ratio to the closed form. Rates are medians of repeated runs after warm-up, with torch
and onnxruntime on `threads` threads (set here, and reported in every row).

    python -m bench.ik_throughput [--checkpoint PATH] [--batch 100000] [--threads 1] [--repeats 7]

(without a checkpoint, a network of M = 80 centres is trained first, about a minute).

Positions are FK images of joints drawn uniformly in the trained branch (in the workspace).
pytorch-kinematics' damped least squares is position-only (orientation weight 0) with restarts
drawn uniformly within the URDF limits; of each query's restarts the one with the smallest
position error on the trained elbow (q2 > 0) is kept. It is slow, so it runs on a smaller batch
and its rate is per query.
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
from pathlib import Path

import torch

from rbfn import RBFNetwork, load_model
from rbfn.config import RobotConfig
from rbfn.robots import joint_limits, load_serial_chain, scara

from .timing import interleaved_medians, machine_info, median_seconds, timed

__all__ = ["BRANCH_LOW", "BRANCH_HIGH", "build_network", "workspace_positions", "ik_rows", "main"]

# The trained joint box (rad, rad, m): the default robot config's, defined once there.
BRANCH_LOW, BRANCH_HIGH = tuple(RobotConfig().joint_low), tuple(RobotConfig().joint_high)


def build_network(
    checkpoint: Path | None = None, num_centers: int = 80, refine: bool = True, threads: int = 1
) -> RBFNetwork:
    """The network under test: a checkpoint's (as `rbfn.load_model` gives it: float32), or one
    trained here by train.py's pipeline (k-means centres with gradient refinement, `num_centers`
    centres, default data; float64 as fitted)."""
    if checkpoint is not None:
        return load_model(checkpoint)
    from rbfn.config import CentersConfig, Method, RefineConfig, TrainConfig
    from rbfn.data import make_dataset
    from rbfn.pipeline import train_ik
    from rbfn.robots.robot import load_robot

    cfg = TrainConfig(
        centers=CentersConfig(name="kmeans_refine", method=Method.kmeans, refine=RefineConfig(enabled=refine)),
        num_threads=threads,
        progress=False,
        export=False,
    )
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
    torch.manual_seed(seed)  # the solver draws its restarts from the global generator
    ik = pk.PseudoInverseIK(
        chain,
        num_retries=retries,
        joint_limits=limits,
        max_iterations=50,
        pos_tolerance=1e-4,
        rot_tolerance=1e9,
        orientation_weight=0.0,
    )
    sol = ik.solve(pk.Transform3d(pos=x, dtype=chain.dtype, device=x.device))
    score = sol.err_pos + 1e3 * (sol.solutions[..., 1] <= 0)  # (B, retries): wrong elbow last
    best = sol.solutions[torch.arange(x.shape[0], device=x.device), score.argmin(1)]
    return best, float((best[:, 1] > 0).float().mean())


def ik_rows(
    net: RBFNetwork,
    batch: int = 100_000,
    device: str = "cpu",
    repeats: int = 7,
    pk_batch: int = 1000,
    pk_retries: int = 10,
    pk_repeats: int = 3,
    threads: int = 1,
    onnx: bool = True,
    compiled: bool = False,
) -> list[dict]:
    """One row per IK method: queries/s, its ratio to the closed form and to pytorch-kinematics,
    the median FK error (mm) of its answers and the threads it ran on. `compiled` adds the
    torch.compile'd module (its compile seconds in the note); `onnx` the ONNX model under
    onnxruntime, if installed; `pk_batch` 0 leaves out pytorch-kinematics. torch runs on
    `threads` threads for the call (restored after)."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        return _ik_rows(net, batch, device, repeats, pk_batch, pk_retries, pk_repeats, threads, onnx, compiled)
    finally:
        torch.set_num_threads(before)


def _ik_rows(
    net: RBFNetwork,
    batch: int,
    device: str,
    repeats: int,
    pk_batch: int,
    pk_retries: int,
    pk_repeats: int,
    threads: int,
    onnx: bool,
    compiled: bool,
) -> list[dict]:
    _, x_cpu = workspace_positions(batch)
    x = x_cpu.to(device)
    net32 = copy.deepcopy(net).to(torch.float32).to(device).eval()  # what load_model gives
    rows = []

    def add(name: str, dev: str, n: int, seconds: float | None, answer: torch.Tensor | None, note: str = "") -> None:
        rows.append(
            {
                "method": name,
                "device": dev,
                "batch": n,
                "threads": threads,
                "queries_per_s": n / seconds if seconds else None,
                "median_err_mm": _err_mm(answer, x_cpu[:n]) if answer is not None else None,
                "note": note,
            }
        )

    fns = {"module": lambda: net32(x), "flag": lambda: net32.solve(x), "closed": lambda: scara.ik(x)}
    sess, onnx_note = _onnx_session(net, threads) if onnx else (None, "")
    if sess is not None:
        xn = x_cpu.numpy()
        fns["onnx"] = lambda: sess.run(None, {"positions": xn})
    with torch.inference_mode():
        # Warm-up 3: onnxruntime's memory arena grows over the first two runs of a batch size.
        t = interleaved_medians(fns, repeats, device, warmup=3)
        add(f"RBF network, torch (M = {net.num_centers})", device, batch, t["module"], net32(x))
        add("RBF network + workspace flag, torch", device, batch, t["flag"], net32(x))
        if compiled:
            fast = torch.compile(net32)
            first = timed(lambda: fast(x), device)
            tc, _ = median_seconds(lambda: fast(x), repeats, device)
            add("RBF network, torch.compile", device, batch, tc, fast(x), f"compile {first - tc:.1f} s")
        add("closed-form SCARA IK, torch", device, batch, t["closed"], scara.ik(x))
    if sess is not None:
        add(
            "RBF network + flag, ONNX (onnxruntime)",
            "cpu",
            batch,
            t["onnx"],
            torch.from_numpy(fns["onnx"]()[0]),
            onnx_note,
        )
    elif onnx_note:
        add("RBF network + flag, ONNX (onnxruntime)", "cpu", batch, None, None, onnx_note)

    if pk_batch > 0:
        chain = load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float32, device)
        xs = x[:pk_batch]
        t, _ = median_seconds(lambda: pk_iterative_ik(chain, xs, pk_retries), pk_repeats, device, warmup=1)
        best, right = pk_iterative_ik(chain, xs, pk_retries)
        add(
            f"pytorch-kinematics PseudoInverseIK ({pk_retries} restarts)",
            device,
            pk_batch,
            t,
            best,
            f"position only, 50 iterations max, tol 0.1 mm; right elbow {100 * right:.1f} %",
        )

    closed = next(r["queries_per_s"] for r in rows if r["method"].startswith("closed"))
    iterative = next((r["queries_per_s"] for r in rows if r["method"].startswith("pytorch-kinematics")), None)
    for r in rows:
        qps = r["queries_per_s"]
        r["x_closed_form"] = qps / closed if qps else None
        r["x_pk_iterative"] = qps / iterative if qps and iterative else None
    return rows


def _onnx_session(net: RBFNetwork, threads: int):
    """(onnxruntime session of the exported network on `threads` threads, note), or (None, why not)."""
    try:
        import onnxruntime as ort
    except ImportError:
        return None, "onnxruntime not installed"
    from rbfn.export import export_onnx

    with tempfile.TemporaryDirectory() as d:
        path = export_onnx(net, Path(d) / "ik.onnx")
        so = ort.SessionOptions()
        so.intra_op_num_threads, so.inter_op_num_threads = threads, 1
        return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"]), f"onnxruntime {ort.__version__}"


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(prog="python -m bench.ik_throughput", description=__doc__.splitlines()[0])
    p.add_argument("--checkpoint", type=Path, default=None, help="network to measure (default: train one)")
    p.add_argument("--num-centers", type=int, default=80, help="M of the network trained without --checkpoint")
    p.add_argument("--batch", type=int, default=100_000)
    p.add_argument("--threads", type=int, default=1, help="torch and onnxruntime threads (default 1)")
    p.add_argument("--repeats", type=int, default=7, help="timed runs per method (the median is reported)")
    p.add_argument("--pk-batch", type=int, default=0, help="pytorch-kinematics' batch (default 0: left out)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows and the machine to this file")
    a = p.parse_args(argv)
    if a.threads < 1:
        p.error(f"--threads {a.threads} must be >= 1")
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(a.threads)
    with threadpool_limits(a.threads):
        net = build_network(a.checkpoint, a.num_centers, threads=a.threads)
        rows = ik_rows(net, a.batch, repeats=a.repeats, pk_batch=a.pk_batch, threads=a.threads)
    print(f"IK at batch {a.batch}, M = {net.num_centers}, float32, {a.threads} thread(s), median of {a.repeats}:")
    for r in rows:
        qps = f"{r['queries_per_s']:10.3g} q/s" if r["queries_per_s"] else f"{'-':>14s}"
        ratio = f"{r['x_closed_form']:6.3f}x closed form" if r["x_closed_form"] else ""
        err = f"median FK error {r['median_err_mm']:.4f} mm" if r["median_err_mm"] is not None else ""
        print(f"  {r['method']:45s} {qps}  {ratio:20s} {err}  {r['note']}")
    if a.json:
        a.json.write_text(json.dumps({"machine": machine_info("cpu", a.threads), "rows": rows}, indent=1))
    return rows


if __name__ == "__main__":
    main()
