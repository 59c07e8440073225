"""Exports reproduce the module: ONNX under onnxruntime and the torch.export program."""
import pytest
import torch

from rbfn.export import export_onnx, export_pt2
from rbfn.fit import design_matrix, ridge_fit
from rbfn.layer import assemble


@pytest.fixture(scope="module")
def net(small_data):
    x, q = small_data.train.x, small_data.train.q
    off = x.mean(0)
    c = (x[:15] - off).clone()
    w = torch.full((15,), 0.6, dtype=torch.float64)
    fit = ridge_fit(design_matrix(x - off, c, w), q, design_matrix(small_data.val.x - off, c, w), small_data.val.q)
    n = assemble(c, w, fit.weights, off, torch.ones(3, dtype=torch.float64), tail=True)
    n.set_domain(x, q)
    return n


@pytest.mark.parametrize("batch", [1, 7, 300])
def test_pt2_and_onnx_match_module(net, small_data, tmp_path, batch):
    x = small_data.test.x[:batch].float()
    with torch.no_grad():
        y_ref, in_ref = net.float().solve(x)
    net.double()
    prog = torch.export.load(str(export_pt2(net, tmp_path / "ik.pt2")))
    y, inside = prog.module()(x)
    assert torch.allclose(y, y_ref, atol=1e-5) and torch.equal(inside, in_ref)
    ort = pytest.importorskip("onnxruntime")
    sess = ort.InferenceSession(str(export_onnx(net, tmp_path / "ik.onnx")), providers=["CPUExecutionProvider"])
    y_onnx, in_onnx = sess.run(None, {"positions": x.numpy()})
    assert abs(y_onnx - y_ref.numpy()).max() < 1e-5
    assert (in_onnx == in_ref.numpy()).all()
