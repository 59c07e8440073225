import torch

from rbfn.objectives import FitObjective


def _objective(memory=2**31, eval_dtype=torch.float32, block=64):
    g = torch.Generator().manual_seed(3)
    z = torch.rand(700, 3, generator=g, dtype=torch.float64) * 2 - 1
    y = torch.stack([torch.sin(3 * z[:, 0]) * z[:, 1], torch.cos(2 * z[:, 2])], -1)
    return FitObjective(z[:500], y[:500], z[500:], y[500:], eval_dtype=eval_dtype, memory=memory, block=block), g


def test_blocked_objective_equals_unblocked():
    whole, g = _objective()
    c = torch.rand(5, 30, 3, generator=g, dtype=torch.float64) * 2 - 1
    w = torch.rand(5, 30, generator=g, dtype=torch.float64) * 0.6 + 0.2
    for dtype in (torch.float32, None):
        whole.eval_dtype = dtype
        blocked, _ = _objective(memory=0, eval_dtype=dtype)           # forces row blocks, one ant a batch
        a, b = whole(c, w), blocked(c, w)
        assert torch.allclose(a, b, rtol=1e-6), (a, b)
        assert torch.allclose(blocked.blocked(c, w), b)                # all ants in one batch
