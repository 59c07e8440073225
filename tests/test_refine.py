import math

import pytest
import torch

import rbfn.refine as rf
from rbfn.config import RefineConfig, RefineMode
from rbfn.fit import design_matrix, ridge_solve


def _problem(m: int = 15):
    g = torch.Generator().manual_seed(0)
    z = torch.rand(600, 2, generator=g, dtype=torch.float64) * 2 - 1
    y = torch.stack([torch.sin(3 * z[:, 0]), z[:, 0] * z[:, 1]], -1)
    c = torch.rand(m, 2, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.full((m,), 0.4, dtype=torch.float64)
    weights = ridge_solve(design_matrix(z[:400], c, w), y[:400], 1e-8)
    return z[:400], y[:400], z[400:], y[400:], c, w, weights


def _val_mse(z_val, y_val, z_tr, y_tr, r: rf.Refined) -> float:
    """Validation MSE of the refined centres with weights re-solved on the training rows."""
    a = design_matrix(z_tr / r.input_scale, r.centers, r.widths)
    weights = ridge_solve(a, y_tr, 1e-8)
    return float((design_matrix(z_val / r.input_scale, r.centers, r.widths) @ weights - y_val).square().sum(-1).mean())


def test_minibatch_refinement_lowers_validation_error_and_keeps_the_best():
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    r = rf.refine_minibatch(z_tr, y_tr, z_val, y_val, c, w, weights, epochs=30, batch=32, lr=0.01, eval_every=5)
    assert len(r.history) == 1 + 30 // 5 and r.val_mse == min(r.history)
    assert r.history[-1] < 0.5 * r.history[0]                      # it learns, not just keeps the start
    assert r.centers.dtype == torch.float64 and r.centers.shape == (15, 2) and r.input_scale.shape == (2,)
    assert (r.widths > 0).all()
    # The kept centres are better than the start once the pipeline re-solves the weights too.
    start = rf.Refined(c, w, torch.ones(2, dtype=torch.float64), 0.0, [])
    assert _val_mse(z_val, y_val, z_tr, y_tr, r) < _val_mse(z_val, y_val, z_tr, y_tr, start)


def test_minibatch_refinement_is_seeded_and_caps_widths():
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    runs = [rf.refine_minibatch(z_tr, y_tr, z_val, y_val, c, w, weights, epochs=3, batch=64, seed=s,
                                max_width=0.41, lr=0.05) for s in (1, 1, 2)]
    assert torch.equal(runs[0].centers, runs[1].centers) and not torch.equal(runs[0].centers, runs[2].centers)
    assert all(float(r.widths.max()) <= 0.41 * (1 + 1e-6) for r in runs)


def test_minibatch_refinement_stops_where_it_diverges(caplog):
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    r = rf.refine_minibatch(z_tr, y_tr, z_val, y_val, c, w, weights, epochs=5, batch=32, lr=1e30)
    assert "diverged in epoch 1" in caplog.text and "batch_lr" in caplog.text
    assert r.history == [r.val_mse]                                # the start, the only finite iterate
    assert torch.allclose(r.centers, c, atol=1e-6) and torch.allclose(r.widths, w, rtol=1e-6)


def test_full_refinement_keeps_the_best_on_validation():
    z_tr, y_tr, z_val, y_val, c, w, _ = _problem()
    r = rf.refine_full(z_tr, y_tr, z_val, y_val, c, w, 1e-8, steps=20, lr=0.01, eval_every=5)
    assert len(r.history) == 5 and r.val_mse == min(r.history) and r.val_mse < r.history[0]


@pytest.mark.parametrize("mode,rows_max,full", [("auto", math.inf, True), ("auto", 0.0, False),
                                                ("full", 0.0, True), ("minibatch", math.inf, False)])
def test_mode_picks_the_way(monkeypatch, mode, rows_max, full):
    calls = []
    monkeypatch.setattr(rf, "FULL_ROWS_MAX", rows_max)
    monkeypatch.setattr(rf, "refine_full", lambda *a, **k: calls.append("full"))
    monkeypatch.setattr(rf, "refine_minibatch", lambda *a, **k: calls.append("minibatch"))
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    rf.refine(z_tr, y_tr, z_val, y_val, c, w, weights, 1e-8, RefineConfig(mode=RefineMode(mode)))
    assert calls == ["full" if full else "minibatch"]
