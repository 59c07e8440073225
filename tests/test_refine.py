import torch

import rbfn.refine as rf


def test_subsampled_refinement_keeps_the_best_on_validation(monkeypatch):
    monkeypatch.setattr(rf, "FULL_ROWS_MAX", 0)          # the large-problem path on a small problem
    g = torch.Generator().manual_seed(0)
    z = torch.rand(600, 2, generator=g, dtype=torch.float64) * 2 - 1
    y = torch.stack([torch.sin(3 * z[:, 0]), z[:, 0] * z[:, 1]], -1)
    c = torch.rand(15, 2, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.full((15,), 0.4, dtype=torch.float64)
    r = rf.refine(z[:400], y[:400], z[400:], y[400:], c, w, 1e-8, steps=6, lr=0.01)
    assert 2 <= len(r.history) <= 7 and r.val_mse == min(r.history)
    assert r.centers.shape == (15, 2) and (r.widths > 0).all() and r.input_scale.shape == (2,)
    w0 = rf._blocked_solve(z[:400], y[:400], c, w, True, 1e-8, block=64)
    assert torch.allclose(w0, rf.ridge_solve(rf.design_matrix(z[:400], c, w), y[:400], 1e-8), atol=1e-8)
