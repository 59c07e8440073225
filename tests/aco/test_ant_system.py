import itertools

import pytest
import torch

from aco import AntSystem


def _subset_problem(n=10, seed=0):
    g = torch.Generator().manual_seed(seed)
    values = torch.rand(n, generator=g, dtype=torch.float64)
    pair = torch.rand(n, n, generator=g, dtype=torch.float64) * 0.5

    def objective(idx):  # (K, M) -> (K,): a non-additive cost, strictly positive
        v = values[idx].sum(-1)
        p = pair[idx.unsqueeze(-1), idx.unsqueeze(-2)].sum((-1, -2))
        return 1.0 + v + p

    return objective


def test_finds_brute_force_optimum_of_small_subset_problem():
    obj = _subset_problem()
    subsets = torch.tensor(list(itertools.combinations(range(10), 3)))
    brute = obj(subsets).min().item()
    res = AntSystem(ants=20, iterations=100).minimize(obj, 10, 3, generator=torch.Generator().manual_seed(1))
    assert res.best_value == pytest.approx(brute)
    assert obj(res.best[None]).item() == pytest.approx(res.best_value)


def test_best_so_far_never_worsens():
    obj = _subset_problem(30, seed=4)
    res = AntSystem(ants=5, iterations=40).minimize(obj, 30, 6, generator=torch.Generator().manual_seed(0))
    h = torch.tensor(res.best_history)
    assert (h[1:] <= h[:-1]).all()
    assert res.best_value == h[-1]


def test_pheromone_update_as_printed():
    # One ant, one iteration: tau = (1 - rho) tau0 + rho * Q / L for chosen, (1 - rho) tau0 otherwise.
    seen = {}

    def obj(idx):
        seen["idx"] = idx
        return torch.full((idx.shape[0],), 4.0, dtype=torch.float64)

    colony = AntSystem(ants=1, iterations=1, rho=0.9, Q=100.0)
    colony.minimize(obj, 5, 2, generator=torch.Generator().manual_seed(0))
    expect = torch.full((5,), 0.1, dtype=torch.float64)
    expect[seen["idx"][0]] += 0.9 * 100.0 / 4.0
    assert torch.allclose(colony.pheromone, expect)


def test_bad_subset_size():
    with pytest.raises(ValueError, match="subset_size"):
        AntSystem().minimize(lambda i: torch.ones(i.shape[0]), 5, 6)


def test_resume_from_state_continues_exactly():
    obj = _subset_problem(25, seed=2)

    def run(iterations, state=None):
        snaps = []
        colony = AntSystem(ants=6, iterations=iterations, rho=0.5)
        res = colony.minimize(
            obj, 25, 5, generator=torch.Generator().manual_seed(3), state=state, on_state=snaps.append
        )
        return res, snaps

    full, _ = run(30)
    _, snaps = run(9)
    resumed, _ = run(30, snaps[-1])
    assert resumed.best_history == full.best_history and torch.equal(resumed.best, full.best)
