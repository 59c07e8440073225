import pytest
import torch

from rbfn.config import CentersConfig
from rbfn.data import input_scaling
from rbfn.objectives import FitObjective, cluster_objective
from rbfn.select import select


@pytest.fixture(scope="module")
def objective(small_data):
    off, sc = input_scaling(small_data.train.x, "metres")
    return FitObjective(
        (small_data.train.x - off) / sc,
        small_data.train.q,
        (small_data.val.x - off) / sc,
        small_data.val.q,
        eval_dtype=torch.float32,
    )


@pytest.mark.parametrize(
    "method,colony",
    [
        ("random", "acor"),
        ("kmeans", "acor"),
        ("ols", "acor"),
        ("aco", "acor"),
        ("aco", "ant_system"),
        ("cmaes", "acor"),
    ],
)
def test_every_method_returns_centres_and_positive_widths(objective, method, colony):
    cfg = CentersConfig(method=method)
    cfg.aco.colony, cfg.aco.iterations = colony, 5
    cfg.aco.ant_system.candidates = cfg.ols.candidates = 100
    s = select(cfg, objective, 12, seed=0, max_width=2.0)
    assert s.centers.shape == (12, 3) and s.widths.shape == (12,)
    assert (s.widths > 0).all() and (s.widths <= 2.0).all()
    if method in ("aco", "cmaes"):  # one entry per iteration run (the Ant System
        assert 1 <= len(s.aco_best) <= 5  # stops early once every ant agrees)
        assert s.aco_best == sorted(s.aco_best, reverse=True)  # best-so-far never worsens


def test_acor_is_no_worse_than_its_kmeans_seed(objective):
    km = select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0)
    cfg = CentersConfig(method="aco")
    cfg.aco.iterations = 10
    aco = select(cfg, objective, 10, seed=0, max_width=2.0)
    e_km = objective(km.centers[None], km.widths[None]).item()
    e_aco = objective(aco.centers[None], aco.widths[None]).item()
    assert e_aco <= e_km * (1 + 1e-12)
    # ACO's centres stay inside the training inputs' box.
    z = objective.z_train
    assert ((aco.centers >= z.amin(0)) & (aco.centers <= z.amax(0))).all()


def test_cmaes_searches_the_colonys_box_from_its_start_at_its_budget(objective, monkeypatch):
    """CMA-ES ranks candidates on the colony's objective, within the colony's box, evaluating the
    colony's budget (archive + ants x iterations, the start first); it keeps the best it saw, so it
    is never worse than the k-means start, and it moves from it."""
    import rbfn.select as sel

    calls = []
    space = sel._space

    def counted(t):
        s = space(t)

        def obj(x):
            calls.append(x.clone())
            return s.objective(x)

        return s._replace(objective=obj)

    monkeypatch.setattr(sel, "_space", counted)
    cfg = CentersConfig(method="cmaes")
    cfg.aco.iterations, cfg.aco.ants, cfg.aco.acor.archive_size = 6, 5, 4
    s = select(cfg, objective, 10, seed=0, max_width=2.0)
    km = select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0)
    assert sum(len(x) for x in calls) == 1 + 5 * ((4 + 5 * 6 - 1) // 5) <= 4 + 5 * 6
    assert torch.allclose(calls[0][0, : 10 * 3], km.centers.reshape(-1))  # the start: the k-means seed
    z = objective.z_train
    every = torch.cat(calls)[:, : 10 * 3].reshape(-1, 10, 3)
    assert ((every >= z.amin(0)) & (every <= z.amax(0))).all()
    e_km = objective(km.centers[None], km.widths[None]).item()
    e = objective(s.centers[None], s.widths[None]).item()
    assert e < e_km and s.aco_best[-1] == pytest.approx(e, rel=1e-6)
    assert (s.chosen_by, s.note) == ("cmaes", "")
    again = select(cfg, objective, 10, seed=0, max_width=2.0)  # seeded
    assert torch.equal(again.centers, s.centers) and torch.equal(again.widths, s.widths)


def test_cmaes_hands_over_kmeans_where_the_full_search_costs_too_much(objective, monkeypatch):
    import rbfn.select as sel

    monkeypatch.setattr(sel, "FULL_SEARCH_MAX", 0)
    km = select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0)
    s = select(CentersConfig(method="cmaes"), objective, 10, seed=0, max_width=2.0)
    assert torch.equal(s.centers, km.centers) and torch.equal(s.widths, km.widths)
    assert s.chosen_by == "kmeans" and s.note.startswith("CMA-ES skipped itself at M = 10 (M * d = 30 > 0)")


def test_acor_best_is_the_objective_of_what_it_returns(objective):
    """The colony's recorded best is the fit objective of the centres and widths it returns,
    evaluated alone (one ant, other row blocks): the same up to the float32 evaluation's rounding."""
    cfg = CentersConfig(method="aco")
    cfg.aco.iterations = 5
    s = select(cfg, objective, 10, seed=0, max_width=2.0)
    assert objective(s.centers[None], s.widths[None]).item() == pytest.approx(s.aco_best[-1], rel=1e-6)


@pytest.mark.parametrize("search", ["per_center", "scale", "none"])
def test_acor_width_search_options(objective, search):
    cfg = CentersConfig(method="aco")
    cfg.aco.iterations, cfg.aco.acor.search_widths = 5, search
    s = select(cfg, objective, 10, seed=0, max_width=2.0)
    km = select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0)
    assert (s.widths > 0).all() and (s.widths <= 2.0).all()
    if search == "none":
        assert torch.allclose(s.widths, km.widths)
    if search == "scale":  # one common factor on the seed's widths (where the cap does not bind)
        ratio = (s.widths / km.widths)[s.widths < 2.0]
        assert ratio.numel() > 0 and torch.allclose(ratio, ratio[0].expand_as(ratio))


def test_cluster_objective_is_kmeans_inertia():
    z = torch.tensor([[0.0, 0.0], [1.0, 0.0], [5.0, 5.0]], dtype=torch.float64)
    c = torch.tensor([[[0.0, 0.0], [5.0, 4.0]]], dtype=torch.float64)
    assert cluster_objective(z, c).item() == pytest.approx(1.0 + 1.0)


def test_ant_system_visibility_is_wired(objective):
    """centers.aco.ant_system.beta > 0 weighs candidates by the local data density and changes the choice."""
    from rbfn.select import visibility

    z = objective.z_train
    eta = visibility(z, z[:50])
    assert eta.shape == (50,) and (eta > 0).all()

    def run(beta):
        cfg = CentersConfig(method="aco")
        cfg.aco.colony, cfg.aco.iterations = "ant_system", 3
        cfg.aco.ant_system.candidates, cfg.aco.ant_system.beta = 100, beta
        return select(cfg, objective, 8, seed=0, max_width=2.0).centers

    assert not torch.equal(run(0.0), run(4.0))


@pytest.mark.parametrize("limit", ["FULL_SEARCH_MAX", "FULL_FLOPS"])
def test_reduced_acor_is_no_worse_than_its_kmeans_seed(objective, monkeypatch, limit):
    import rbfn.select as sel

    monkeypatch.setattr(sel, limit, 0)  # the large-M search on a small problem (too many coordinates, or flops)
    km = select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0)
    cfg = CentersConfig(method="aco")
    cfg.aco.iterations = 4
    aco = select(cfg, objective, 10, seed=0, max_width=2.0)
    assert torch.equal(aco.centers, km.centers)  # centres are the k-means seed's
    assert 1 <= len(aco.aco_best) <= 4
    e_km = objective(km.centers[None], km.widths[None]).item()
    e_aco = objective(aco.centers[None], aco.widths[None]).item()
    assert e_aco <= e_km * (1 + 1e-12)
    assert (aco.widths > 0).all() and (aco.widths <= 2.0).all()


@pytest.mark.parametrize("limit", ["FULL_SEARCH_MAX", "FULL_FLOPS"])
def test_the_large_m_colony_skips_itself_where_the_minibatch_refinement_follows(objective, monkeypatch, caplog, limit):
    """Where only the two global width quantities could be searched, a mini-batch refinement that
    follows trains every width from the same k-means start: the colony hands over k-means' own
    centres and widths (kmeans_refine's start, bit for bit), runs no iteration and says why.
    Before the full refinement, or none, the reduced colony searches."""
    import rbfn.select as sel

    monkeypatch.setattr(sel, limit, 0)
    km = select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0)
    cfg = CentersConfig(method="aco")
    cfg.aco.iterations, cfg.refine.enabled, cfg.refine.mode = 4, True, "minibatch"
    with caplog.at_level("INFO", logger="rbfn.select"):
        aco = select(cfg, objective, 10, seed=0, max_width=2.0)
    assert torch.equal(aco.centers, km.centers) and torch.equal(aco.widths, km.widths)
    assert aco.aco_best == [] and aco.aco_mean == []
    assert "colony: skipped at M = 10" in caplog.text
    # The record says what ran: k-means chose the centres, and why.
    assert aco.chosen_by == "kmeans" and aco.note.startswith("the colony skipped itself at M = 10 (")
    cfg.refine.mode = "auto"  # full at this size
    reduced = select(cfg, objective, 10, seed=0, max_width=2.0)
    assert 1 <= len(reduced.aco_best) <= 4
    assert reduced.chosen_by == "kmeans" and "two global width quantities only at M = 10" in reduced.note
    monkeypatch.undo()  # the full colony at this size: it searches every coordinate
    full = select(cfg, objective, 10, seed=0, max_width=2.0)
    assert len(full.aco_best) == 4 and (full.chosen_by, full.note) == ("aco", "")
    assert select(CentersConfig(method="kmeans"), objective, 10, seed=0, max_width=2.0).chosen_by == "kmeans"


def test_objective_subset_is_the_objective_on_seeded_rows(objective):
    sub = objective.subset(100, seed=3)
    assert sub.z_train.shape == (100, 3) and sub.z_val.shape == (100, 3)
    assert torch.equal(sub.z_train, objective.subset(100, seed=3).z_train)  # seeded
    assert not torch.equal(sub.z_train, objective.subset(100, seed=4).z_train)
    rows = (sub.z_train[:, None] == objective.z_train[None]).all(-1)  # rows of the original, once each
    assert (rows.sum(1) == 1).all() and torch.equal(objective.y_train[rows.int().argmax(1)], sub.y_train)
    direct = FitObjective(sub.z_train, sub.y_train, sub.z_val, sub.y_val, eval_dtype=torch.float32)
    c, w = objective.z_train[:8][None], torch.full((1, 8), 0.5, dtype=torch.float64)
    assert torch.equal(sub(c, w), direct(c, w))
    assert objective.subset(10**6, seed=0) is objective


def test_colony_ranks_on_a_subset_of_at_least_50_rows_per_column(objective):
    from rbfn.select import colony_objective

    assert colony_objective(objective, 10, 0, seed=0) is objective  # fit_rows = 0: every row
    assert colony_objective(objective, 10, 100, seed=0) is objective  # 50 x 14 columns >= 600 rows
    small = colony_objective(objective, 2, 100, seed=0)  # 50 x 6 = 300 rows
    assert small.z_train.shape[0] == 300 and small.z_val.shape[0] == 300


@pytest.mark.parametrize("colony", ["acor", "ant_system"])
def test_colony_ranks_ants_on_its_subset(objective, monkeypatch, colony):
    """The recorded best is the subset objective's value of what the colony returns; where the
    rows are fewer than fit_rows the selection is the one on every row, exactly."""
    import rbfn.select as sel

    def run(fit_rows):
        cfg = CentersConfig(method="aco")
        cfg.aco.colony, cfg.aco.iterations, cfg.aco.fit_rows = colony, 3, fit_rows
        cfg.aco.ant_system.candidates = 100
        return select(cfg, objective, 6, seed=0, max_width=2.0)

    every, default = run(0), run(2048)
    assert torch.equal(every.centers, default.centers) and every.aco_best == default.aco_best
    monkeypatch.setattr(sel, "ROWS_PER_COLUMN", 1)
    s = run(150)
    ranked = sel.colony_objective(objective, 6, 150, seed=0)
    assert ranked.z_train.shape[0] == 150
    assert ranked(s.centers[None], s.widths[None]).item() == pytest.approx(s.aco_best[-1], rel=1e-6)
    assert objective(s.centers[None], s.widths[None]).item() != pytest.approx(s.aco_best[-1], rel=1e-6)
