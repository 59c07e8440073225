import math

import pytest
import torch

import rbfn.refine as rf
from rbfn.config import RefineConfig, RefineMode
from rbfn.fit import ROUND_TOL, RoundingRule, design_matrix, ridge_fit, ridge_solve


def _problem(m: int = 15, width: float = 0.4):
    g = torch.Generator().manual_seed(0)
    z = torch.rand(600, 2, generator=g, dtype=torch.float64) * 2 - 1
    y = torch.stack([torch.sin(3 * z[:, 0]), z[:, 0] * z[:, 1]], -1)
    c = torch.rand(m, 2, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.full((m,), width, dtype=torch.float64)
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
    assert r.history[-1] < 0.5 * r.history[0]  # it learns, not just keeps the start
    assert r.centers.dtype == torch.float64 and r.centers.shape == (15, 2) and r.input_scale.shape == (2,)
    assert (r.widths > 0).all()
    # The kept centres are better than the start once the pipeline re-solves the weights too.
    start = rf.Refined(c, w, torch.ones(2, dtype=torch.float64), 0.0, [])
    assert _val_mse(z_val, y_val, z_tr, y_tr, r) < _val_mse(z_val, y_val, z_tr, y_tr, start)


def test_minibatch_refinement_is_seeded_and_caps_widths():
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    runs = [
        rf.refine_minibatch(
            z_tr, y_tr, z_val, y_val, c, w, weights, epochs=3, batch=64, seed=s, max_width=0.41, lr=0.05
        )
        for s in (1, 1, 2)
    ]
    assert torch.equal(runs[0].centers, runs[1].centers) and not torch.equal(runs[0].centers, runs[2].centers)
    assert all(float(r.widths.max()) <= 0.41 * (1 + 1e-6) for r in runs)


def test_minibatch_refinement_stops_where_it_diverges(caplog):
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    r = rf.refine_minibatch(z_tr, y_tr, z_val, y_val, c, w, weights, epochs=5, batch=32, lr=1e30)
    assert "diverged in epoch 1" in caplog.text and "centers.refine.minibatch.lr" in caplog.text
    assert r.history == [r.val_mse]  # the start, the only finite iterate
    assert torch.allclose(r.centers, c, atol=1e-6) and torch.allclose(r.widths, w, rtol=1e-6)


def test_full_refinement_keeps_the_best_on_validation():
    z_tr, y_tr, z_val, y_val, c, w, _ = _problem()
    r = rf.refine_full(z_tr, y_tr, z_val, y_val, c, w, ridge=1e-8, steps=20, lr=0.01, eval_every=5)
    assert len(r.history) == 5 and r.val_mse == min(r.history) and r.val_mse < r.history[0]


def test_full_refinement_under_the_float32_rule_beats_re_solving_afterwards():
    """With the rule, the ridge inside the loss is the one the rule picks for the current centres,
    so the refinement optimises the weights that will be deployed: they pass the rule, and their
    validation error is far below that of refining at a fixed ridge (the selection's, or the
    floor) and re-solving by the rule afterwards. Wide Gaussians (width 1 on [-1, 1]^2): accurate
    fits there cancel, and the rule binds."""
    z_tr, y_tr, z_val, y_val, c, w, _ = _problem(width=1.0)

    def deployed(r: rf.Refined):
        """The rule's fit (`ridge_fit` in float32 with ROUND_TOL) for the refined centres."""
        a_tr, a_val = (design_matrix(z / r.input_scale, r.centers, r.widths) for z in (z_tr, z_val))
        return ridge_fit(a_tr, y_tr, a_val, y_val, eval_dtype=torch.float32, round_tol=ROUND_TOL)

    start = float(deployed(rf.Refined(c, w, torch.ones(2, dtype=torch.float64), 0.0, [])).ridge)
    ruled = rf.refine_full(z_tr, y_tr, z_val, y_val, c, w, ridge=start, steps=100, lr=0.02, rule=RoundingRule())
    fit = deployed(ruled)
    assert fit.rounding is not None and fit.rounding <= ROUND_TOL
    assert ruled.val_mse == min(ruled.history) and math.isclose(ruled.val_mse, float(fit.val_mse), rel_tol=1e-12)
    for ridge in (start, 1e-11):  # the old way: a fixed ridge in the loss, the rule only at the end
        fixed = deployed(rf.refine_full(z_tr, y_tr, z_val, y_val, c, w, ridge=ridge, steps=100, lr=0.02))
        assert float(fit.val_mse) < 0.2 * float(fixed.val_mse)


@pytest.mark.parametrize(
    "mode,rows_max,full",
    [("auto", math.inf, True), ("auto", 0.0, False), ("full", 0.0, True), ("minibatch", math.inf, False)],
)
def test_mode_picks_the_way(monkeypatch, mode, rows_max, full):
    calls = []
    monkeypatch.setattr(rf, "FULL_ROWS_MAX", rows_max)
    monkeypatch.setattr(rf, "refine_full", lambda *a, **k: calls.append("full"))
    monkeypatch.setattr(rf, "refine_minibatch", lambda *a, **k: calls.append("minibatch"))
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    rf.refine(z_tr, y_tr, z_val, y_val, c, w, weights, ridge=1e-8, cfg=RefineConfig(mode=RefineMode(mode)))
    assert calls == ["full" if full else "minibatch"]


def test_row_loss_squared_task_and_pseudo_huber():
    err = torch.tensor([[0.003, -0.004], [0.0, 0.0], [3.0, 4.0]], dtype=torch.float64)
    assert torch.allclose(rf.row_loss(err), torch.tensor([25e-6, 0.0, 25.0], dtype=torch.float64))
    jac = torch.tensor([[2.0, 0.0], [0.0, 1.0], [1.0, 1.0]], dtype=torch.float64).expand(3, 3, 2)
    task = rf.row_loss(err, jac)  # |J err|^2: (2 e1)^2 + e2^2 + (e1 + e2)^2
    assert torch.allclose(task, (4 * err[:, 0] ** 2 + err[:, 1] ** 2 + err.sum(-1) ** 2))
    h = rf.row_loss(err, huber=0.1)
    assert h[1] == 0.0
    assert h[0] == pytest.approx(25e-6 / 2, rel=1e-3)  # small errors: |e|^2 / 2
    assert h[2] == pytest.approx(0.1 * 5.0, rel=3e-2)  # large ones: huber * |e|, linear


def test_minibatch_task_loss_lowers_the_task_error_and_returns_trained_weights():
    z_tr, y_tr, z_val, y_val, c, w, weights = _problem()
    # A fixed per-row "Jacobian" that weighs output 0 ten times output 1.
    jac_tr = torch.diag(torch.tensor([10.0, 1.0], dtype=torch.float64)).expand(400, 2, 2)
    jac_val = jac_tr[:200]
    r = rf.refine_minibatch(
        z_tr, y_tr, z_val, y_val, c, w, weights, epochs=30, batch=32, lr=0.01, huber=0.05, jacobians=(jac_tr, jac_val)
    )
    assert r.val_mse == min(r.history) and r.history[-1] < 0.5 * r.history[0]
    assert r.weights.shape == weights.shape and r.weights.dtype == torch.float64
    pred = design_matrix(z_val / r.input_scale, r.centers, r.widths) @ r.weights
    assert r.val_loss(pred) == pytest.approx(r.val_mse, rel=1e-4)  # the loss it kept, from the weights it returns
    start = design_matrix(z_val, c, w) @ weights
    assert r.val_loss(pred) < r.val_loss(start)


def test_refine_mode_auto_takes_minibatches_for_large_problems():
    cfg = RefineConfig()
    assert rf.refine_mode(cfg, 2000, 84) == "full"  # the SCARA's
    assert rf.refine_mode(cfg, 20000, 2010) == "minibatch"  # the UR5's M = 2000
    cfg.mode = RefineMode.full
    assert rf.refine_mode(cfg, 20000, 2010) == "full"
