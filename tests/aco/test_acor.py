import torch

from aco import ACOR


def test_minimizes_shifted_sphere_and_respects_bounds():
    target = torch.tensor([0.3, -0.7, 0.5, 0.1], dtype=torch.float64)

    def obj(x):
        return (x - target).square().sum(-1)

    g = torch.Generator().manual_seed(0)
    init = torch.rand(10, 4, generator=g, dtype=torch.float64) * 2 - 1
    lo, hi = -torch.ones(4, dtype=torch.float64), torch.ones(4, dtype=torch.float64)
    res = ACOR(archive_size=10, ants=10, iterations=150, lower=lo, upper=hi).minimize(obj, init, generator=g)
    assert res.best_value < 1e-4
    assert ((res.best >= lo) & (res.best <= hi)).all()


def test_best_so_far_never_worsens_and_is_no_worse_than_init():
    def obj(x):  # multimodal (Rastrigin)
        return (x.square() - 10 * torch.cos(2 * torch.pi * x)).sum(-1) + 10 * x.shape[-1]

    g = torch.Generator().manual_seed(3)
    init = torch.rand(5, 6, generator=g, dtype=torch.float64) * 10 - 5
    res = ACOR(archive_size=8, ants=6, iterations=50).minimize(obj, init, generator=g)
    h = torch.tensor(res.best_history)
    assert (h[1:] <= h[:-1]).all()
    assert res.best_value <= obj(init).min().item()


def test_resume_from_state_continues_exactly():
    def obj(x):
        return (x - 0.3).square().sum(-1)

    def run(stop_at=None, state=None):
        g = torch.Generator().manual_seed(7)
        init = torch.rand(6, 5, generator=g, dtype=torch.float64)
        snaps = []
        colony = ACOR(archive_size=6, ants=4, iterations=stop_at or 30)
        res = colony.minimize(obj, init, generator=g, state=state, on_state=snaps.append)
        return res, snaps

    full, _ = run()
    _, snaps = run(stop_at=12)  # "interrupted" after 12 iterations
    resumed, _ = run(state=snaps[-1])
    assert resumed.best_history == full.best_history and torch.equal(resumed.best, full.best)
