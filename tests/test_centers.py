import torch

from rbfn.centers import kmeans_centers, ols_centers, random_centers
from rbfn.layer import gaussian_features


def test_ols_recovers_separated_generating_centres():
    # Greedy forward selection finds the generating centres when their Gaussians barely overlap
    # (with strong overlap it may first pick a candidate between two of them, by design).
    g = torch.Generator().manual_seed(0)
    z = torch.rand(800, 2, generator=g, dtype=torch.float64)
    pool = torch.rand(40, 2, generator=g, dtype=torch.float64)
    true = torch.tensor([[0.2, 0.2], [0.8, 0.3], [0.5, 0.8]], dtype=torch.float64)
    pool[[3, 17, 29]] = true
    width = torch.tensor([0.08], dtype=torch.float64)
    y = gaussian_features(z, true, width.expand(3)) @ torch.tensor([[1.0], [-2.0], [1.5]], dtype=torch.float64)
    sets = ols_centers(z, y, 3, width, pool, tail=False)
    assert {tuple(r.tolist()) for r in sets[0]} == {tuple(r.tolist()) for r in true}


def test_kmeans_and_random_shapes():
    z = torch.rand(300, 3, dtype=torch.float64)
    assert kmeans_centers(z, 8, seed=0, restarts=2).shape == (8, 3)
    r = random_centers(z, 8, torch.Generator().manual_seed(0))
    assert r.shape == (8, 3) and len({tuple(v.tolist()) for v in r}) == 8


def test_kmeans_restarts_capped_on_large_problems():
    from rbfn.centers import kmeans_restarts

    assert kmeans_restarts(2000, 80, 3, 10) == 10  # the SCARA's default: unchanged
    assert kmeans_restarts(20000, 2000, 9, 10) == 1  # the UR5's
    assert kmeans_restarts(20000, 200, 9, 10) == 5
