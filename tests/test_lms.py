import pytest
import torch

from rbfn.lms import NLMS, RLS, make_learner


def _stream(n, p=6, out=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(n, p, generator=g, dtype=torch.float64)
    w_true = torch.randn(p, out, generator=g, dtype=torch.float64)
    y = a @ w_true + 0.01 * torch.randn(n, out, generator=g, dtype=torch.float64)
    return a, y, w_true


@pytest.mark.parametrize("cls", [NLMS, RLS])
def test_one_step_reduces_the_error_on_its_own_pair(cls):
    a, y, _ = _stream(4)
    learner = cls(torch.zeros(4, 6, 2, dtype=torch.float64))
    before = learner.update(a[:, None], y[:, None])
    after = y[:, None] - a[:, None] @ learner.w
    assert bool((after.norm(dim=-1) < before.norm(dim=-1)).all())


@pytest.mark.parametrize("name,passes", [("nlms", 30), ("rls", 1)])
def test_converges_to_the_least_squares_solution(name, passes):
    a, y, _ = _stream(400)
    w_ls = torch.linalg.lstsq(a, y).solution
    learner = make_learner(name, torch.zeros(1, 6, 2, dtype=torch.float64), alpha0=0.5, decay=0.0, forgetting=1.0)
    for _ in range(passes):
        for i in range(0, 400, 4):
            learner.update(a[None, i : i + 4], y[None, i : i + 4])
    tol = 0.02 if name == "nlms" else 1e-3
    assert torch.allclose(learner.w[0], w_ls, atol=tol)


@pytest.mark.parametrize("cls", [NLMS, RLS])
def test_nan_pair_is_rejected_without_corrupting_weights(cls):
    a, y, _ = _stream(3)
    w0 = torch.randn(3, 6, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    learner = cls(w0)
    a_bad = a.clone()
    a_bad[1, 2] = float("nan")
    y_bad = y.clone()
    y_bad[2, 0] = float("inf")
    learner.update(a_bad[:, None], y_bad[:, None])
    assert torch.isfinite(learner.w).all()
    assert torch.equal(learner.w[1], w0[1]) and torch.equal(learner.w[2], w0[2])
    assert not torch.equal(learner.w[0], w0[0]) and learner.rejected == 2


def test_bad_settings():
    w = torch.zeros(1, 2, 1)
    with pytest.raises(ValueError, match=r"alpha0=2.5"):
        NLMS(w, alpha0=2.5)
    with pytest.raises(ValueError, match=r"forgetting=1.5"):
        RLS(w, forgetting=1.5)
    with pytest.raises(ValueError, match="unknown learner 'adam'"):
        make_learner("adam", w)


def test_rls_weights_whose_matrices_cannot_fit_are_refused_before_any_work(monkeypatch):
    """RLS holds B (P, P) matrices and an update one more: too many is an error naming the weights
    and the estimate, not the allocator's."""
    import rbfn.memory

    monkeypatch.setattr(rbfn.memory, "available_bytes", lambda device="cpu": 10**6)
    with pytest.raises(
        ValueError,
        match=r"weights=\(100, 500, 3\) needs at least 191 MiB \(the inverse covariance, 100 \(500, 500\) matrices.*"
        r"more than this machine's available memory \(977 KiB\); adapt fewer environments B or fewer design columns",
    ):
        RLS(torch.zeros(100, 500, 3))
    assert RLS(torch.zeros(1, 20, 3)).p.shape == (1, 20, 20)  # 3.1 KiB: fits
