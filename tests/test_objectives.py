import pytest
import torch

from rbfn.fit import design_matrix, ridge_fit, rounding_scale
from rbfn.objectives import FitObjective


def _problem(seed=3, k=5, m=30):
    g = torch.Generator().manual_seed(seed)
    z = torch.rand(700, 3, generator=g, dtype=torch.float64) * 2 - 1
    y = torch.stack([torch.sin(3 * z[:, 0]) * z[:, 1], torch.cos(2 * z[:, 2])], -1)
    c = torch.rand(k, m, 3, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.rand(k, m, generator=g, dtype=torch.float64) * 0.6 + 0.2
    return z, y, c, w


def _reference(z, y, c, w, tail=True, **kw):
    """ridge_fit on the whole design matrices: what the objective must equal."""
    return ridge_fit(design_matrix(z[:500], c, w, tail), y[:500], design_matrix(z[500:], c, w, tail), y[500:], **kw)


@pytest.mark.parametrize("eval_dtype", [torch.float32, None])
@pytest.mark.parametrize("tail", [True, False])
def test_objective_equals_ridge_fit_on_whole_design_matrices(eval_dtype, tail):
    z, y, c, w = _problem()
    ref = _reference(z, y, c, w, tail, eval_dtype=eval_dtype).val_mse
    rtol = 1e-6 if eval_dtype else 1e-10  # float32 predictions: float32 sums in another order
    # All ants at once, validation Gaussians kept; one ant a batch in blocks of 64 rows, rebuilt.
    for memory, block in ((2**31, 2048), (0, 64)):
        obj = FitObjective(
            z[:500], y[:500], z[500:], y[500:], tail=tail, eval_dtype=eval_dtype, memory=memory, block=block
        )
        assert torch.allclose(obj(c, w), ref, rtol=rtol, atol=0), (memory, block)


def test_rounding_scale_near_the_tolerance_is_judged_in_float64():
    """The objective sums rounding scales in float32; one within float32 rounding of the tolerance
    is redone in float64, so the stable ridges (and the error) are ridge_fit's on either side."""
    z, y, c, w = _problem(k=3)
    a_val = design_matrix(z[500:], c, w)
    fit = _reference(z, y, c, w, eval_dtype=torch.float32)
    bound = rounding_scale(a_val, fit.weights, torch.float32).amax((-2, -1))  # float64 sums
    assert torch.allclose(bound, fit.rounding)
    chosen = []
    for factor in (1 - 1e-9, 1 + 1e-9):  # far below float32's resolution
        tol = float(bound[0]) * factor
        obj = FitObjective(z[:500], y[:500], z[500:], y[500:], eval_dtype=torch.float32, round_tol=tol)
        exact = []
        blocks = obj._val_blocks
        obj._val_blocks = lambda *a, **kw: exact.append(kw.get("exact", False)) or blocks(*a, **kw)  # noqa: B023 - this obj's
        ref = _reference(z, y, c, w, eval_dtype=torch.float32, round_tol=tol)
        assert torch.allclose(obj(c, w), ref.val_mse, rtol=1e-6, atol=0)
        assert any(exact)  # the float64 rescoring ran
        chosen.append(float(ref.ridge[0]))
    assert chosen[0] > chosen[1]  # the tolerance decides ant 0's ridge


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_objective_on_cuda_equals_cpu():
    z, y, c, w = _problem()
    cpu = FitObjective(z[:500], y[:500], z[500:], y[500:], eval_dtype=torch.float32)
    gpu = FitObjective(*(t.cuda() for t in (z[:500], y[:500], z[500:], y[500:])), eval_dtype=torch.float32)
    assert torch.allclose(gpu(c.cuda(), w.cuda()).cpu(), cpu(c, w), rtol=1e-6, atol=0)
