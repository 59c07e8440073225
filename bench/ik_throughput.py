"""IK queries per second at a large batch: the RBF network (torch module, ONNX under
onnxruntime) against the closed-form SCARA IK, float32, CPU, with each one's accuracy.

    python bench/ik_throughput.py CHECKPOINT [--batch 100000] [--threads 1] [--repeats 7]

Prints a Markdown table (median of --repeats timed calls after a warm-up) with the thread count.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def _time(fn, repeats: int) -> float:
    fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--batch", type=int, default=100_000)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeats", type=int, default=7)
    a = p.parse_args()
    torch.set_num_threads(a.threads)

    from rbfn import load_model
    from rbfn.export import export_onnx
    from rbfn.robots import scara

    net = load_model(a.checkpoint).float()
    g = torch.Generator().manual_seed(123)
    low, high = torch.tensor([0.0, 0.3, 0.5]), torch.tensor([2.0, 2.0, 1.5])
    q = low + torch.rand(a.batch, 3, generator=g) * (high - low)
    x = scara.fk(q.double()).float()

    def err_mm(q_hat: torch.Tensor) -> float:
        return float(((scara.fk(q_hat.double()) - x.double()).norm(dim=-1) * 1000).median())

    rows = []
    with torch.inference_mode():
        t = _time(lambda: net(x), a.repeats)
        rows.append(("RBF network, torch module", t, err_mm(net(x))))
        t = _time(lambda: net.solve(x), a.repeats)
        rows.append(("RBF network + workspace flag, torch", t, err_mm(net(x))))
        t = _time(lambda: scara.ik(x), a.repeats)
        rows.append(("closed-form SCARA IK, torch", t, err_mm(scara.ik(x))))
    try:
        import onnxruntime as ort

        with tempfile.TemporaryDirectory() as d:
            path = export_onnx(load_model(a.checkpoint), Path(d) / "ik.onnx")
            so = ort.SessionOptions()
            so.intra_op_num_threads = a.threads
            so.inter_op_num_threads = 1
            sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
            xn = x.numpy()
            t = _time(lambda: sess.run(None, {"positions": xn}), a.repeats)
            rows.append(("RBF network + flag, ONNX (onnxruntime)", t,
                         err_mm(torch.from_numpy(sess.run(None, {"positions": xn})[0]))))
    except ImportError:
        print("onnxruntime not installed: ONNX row skipped")

    closed = next(r[1] for r in rows if r[0].startswith("closed"))
    print(f"# IK throughput, batch {a.batch}, float32, CPU, {a.threads} thread(s); torch {torch.__version__}; "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; "
          f"M = {net.num_centers}")
    print("| method | queries/s | time / closed form | median FK error (mm) |\n|---|---|---|---|")
    for name, t, e in rows:
        print(f"| {name} | {a.batch / t:.3g} | {t / closed:.2f} | {e:.4g} |")


if __name__ == "__main__":
    main()
