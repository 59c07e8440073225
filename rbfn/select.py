"""Choosing centres and widths: ACO (ACO_R or the paper's Ant System), k-means, random, OLS, CMA-ES.

`select` works on scaled inputs z and returns centres (M, d) and widths (M,) in the same units,
with what the search recorded (time, ACO objective per iteration). Widths not searched by the
method come from the width rule, scaled by `width_scale` or by the scale with the lowest
validation error.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import torch

from aco import ACOR, ACOResult, AntSystem

from .centers import kmeans_centers, ols_centers, random_centers
from .config import CentersConfig, Method
from .objectives import FitObjective, cluster_objective
from .refine import refine_mode
from .widths import SCALE_GRID, base_widths, nearest_widths, paper_widths

log = logging.getLogger(__name__)

__all__ = ["Selection", "select", "choose_widths", "colony_objective", "visibility", "cma_ranks"]


@dataclass
class Selection:
    """Centres (M, d), widths (M,), seconds spent, and ACO best/mean objective per iteration;
    `chosen_by`, the method that actually chose the centres (`kmeans` where the colony skipped
    itself or searched widths only, else `cfg.method`), and `note`, why it differs from the
    configured one ("" where it does not)."""

    centers: torch.Tensor
    widths: torch.Tensor
    seconds: float
    aco_best: list[float] = field(default_factory=list)
    aco_mean: list[float] = field(default_factory=list)
    chosen_by: str = ""
    note: str = ""


def choose_widths(
    objective: FitObjective, centers: torch.Tensor, rule: str, scale: float | None, max_width: float
) -> torch.Tensor:
    """Widths (M,) = rule's base widths times `scale`, or the grid scale best on validation (every
    other grid scale where M * d > FULL_SEARCH_MAX: each costs a full fit there)."""
    base = base_widths(centers, rule)
    if rule == "paper" or scale is not None:
        return (base * (1.0 if scale is None else scale)).clamp(max=max_width)
    coarse = centers.shape[-2] * centers.shape[-1] > FULL_SEARCH_MAX  # every other scale (x2 apart)
    grid = torch.as_tensor(SCALE_GRID[::2] if coarse else SCALE_GRID, dtype=base.dtype, device=base.device)
    cand = (grid[:, None] * base).clamp(max=max_width)  # (S, M)
    err = objective(centers.expand(len(grid), *centers.shape), cand)
    return cand[int(err.argmin())]


def select(
    cfg: CentersConfig,
    objective: FitObjective,
    m: int,
    *,
    seed: int,
    max_width: float,
    progress: bool = False,
    generator: torch.Generator | None = None,
    resume: dict | None = None,
    on_state: Callable[[dict], None] | None = None,
) -> Selection:
    """Centres and widths for M = m with the method `cfg.method` on the objective's training inputs.

    For the ACO methods, `on_state` receives the colony's snapshots and `resume` continues from
    one; the generator must then be in the state it had when this selection first started.
    """
    g = generator or torch.Generator().manual_seed(seed)
    t0 = time.perf_counter()
    chosen = _METHODS[Method(cfg.method)](_Task(cfg, objective, m, seed, max_width, progress, g, resume, on_state))
    return Selection(
        chosen.centers,
        chosen.widths,
        time.perf_counter() - t0,
        chosen.best,
        chosen.mean,
        chosen.chosen_by or str(cfg.method),
        chosen.note,
    )


class _Task(NamedTuple):
    """What `select` gives a method: its settings, the objective, M, the seed, the widest width,
    whether to show progress, the generator, and the colony's snapshot to resume and hook."""

    cfg: CentersConfig
    objective: FitObjective
    m: int
    seed: int
    max_width: float
    progress: bool
    g: torch.Generator
    resume: dict | None
    on_state: Callable[[dict], None] | None


class _Chosen(NamedTuple):
    """A method's answer: centres (M, d), widths (M,), the colony's best and mean objective per
    iteration (empty for the others), the method that chose them where another did (""), and why."""

    centers: torch.Tensor
    widths: torch.Tensor
    best: list[float]
    mean: list[float]
    chosen_by: str = ""
    note: str = ""


def _widths(t: _Task, centers: torch.Tensor) -> torch.Tensor:
    """The width rule's widths (`choose_widths`) for centres chosen without them."""
    return choose_widths(t.objective, centers, t.cfg.width_rule, t.cfg.width_scale, t.max_width)


def _random(t: _Task) -> _Chosen:
    centers = random_centers(t.objective.z_train, t.m, t.g)
    return _Chosen(centers, _widths(t, centers), [], [])


def _kmeans(t: _Task) -> _Chosen:
    centers = kmeans_centers(t.objective.z_train, t.m, t.seed, t.cfg.kmeans_restarts)
    return _Chosen(centers, _widths(t, centers), [], [])


def _ols(t: _Task) -> _Chosen:
    cfg, objective, m, z = t.cfg, t.objective, t.m, t.objective.z_train
    pool = _candidate_pool(z, cfg.ols.candidates, t.g)
    base = paper_widths(pool[None])[0, 0] * (pool.shape[0] / m) ** 0.5  # d_max / sqrt(2M)
    grid = torch.as_tensor(SCALE_GRID, dtype=z.dtype, device=z.device)
    scales = grid if cfg.width_scale is None else grid.new_tensor([cfg.width_scale])
    sets = ols_centers(z, objective.y_train, m, (scales * base).clamp(max=t.max_width), pool, objective.tail)
    w = (scales * base).clamp(max=t.max_width)[:, None].expand(-1, m)
    best = int(objective(sets, w).argmin())
    return _Chosen(sets[best], w[best].clone(), [], [])


def _aco(t: _Task) -> _Chosen:
    return _ant_system(t) if t.cfg.aco.colony == "ant_system" else _acor(t)


# The colony's subset keeps at least this many rows per design column P (the fit's excess
# validation error grows as P / rows: about 2 % here), whatever `centers.aco.fit_rows` says.
ROWS_PER_COLUMN = 50


def colony_objective(objective: FitObjective, m: int, fit_rows: int, seed: int) -> FitObjective:
    """The objective a colony ranks its ants on at M = m: `objective` on a seeded subset of at most
    max(fit_rows, ROWS_PER_COLUMN x P) training and validation rows (every row for fit_rows = 0).
    Ants are thousands of fits; the one fit that is kept is redone on every row."""
    if not fit_rows:
        return objective
    return objective.subset(max(fit_rows, ROWS_PER_COLUMN * objective.width(m)), seed)


def _candidate_pool(z: torch.Tensor, n: int, g: torch.Generator) -> torch.Tensor:
    """At most n distinct training inputs, uniformly chosen (all of them when n >= N)."""
    if n >= z.shape[0]:
        return z
    return z[torch.randperm(z.shape[0], generator=g)[:n].to(z.device)]


def visibility(z: torch.Tensor, pool: torch.Tensor, k: int = 10) -> torch.Tensor:
    """The Ant System's heuristic eta (C,) of candidates pool (C, d): the local density of the
    training inputs z (N, d), 1 / mean distance to the candidate's k nearest inputs. With
    p_j ~ tau_j^alpha eta_j^beta, beta > 0 favours centres where the data are dense."""
    d = torch.cdist(pool, z).topk(min(k, z.shape[0]), dim=-1, largest=False).values.mean(-1)
    return 1.0 / d.clamp_min(1e-12)


def _ant_system(t: _Task) -> _Chosen:
    """The paper's colony: ants choose M of the candidate points; widths by the rule."""
    cfg, objective, m, seed, max_width, g = t.cfg, t.objective, t.m, t.seed, t.max_width, t.g
    pool = _candidate_pool(objective.z_train, cfg.aco.ant_system.candidates, g)
    scale = cfg.width_scale
    if cfg.width_rule != "paper" and scale is None:
        # Fix the width scale once, on a k-means solution, so ants compare centre sets only.
        km = kmeans_centers(objective.z_train, m, seed, 1)
        base = base_widths(km, cfg.width_rule)
        scale = float((choose_widths(objective, km, cfg.width_rule, None, max_width) / base).median())

    def widths_of(c: torch.Tensor) -> torch.Tensor:
        return (base_widths(c, cfg.width_rule) * (scale or 1.0)).clamp(max=max_width)

    if cfg.aco.objective == "fit":
        ranked = colony_objective(objective, m, cfg.aco.fit_rows, seed)

        def obj(idx: torch.Tensor) -> torch.Tensor:
            c = pool[idx.to(pool.device)]
            return ranked(c, widths_of(c))
    else:

        def obj(idx: torch.Tensor) -> torch.Tensor:
            return cluster_objective(objective.z_train, pool[idx.to(pool.device)])

    a, s = cfg.aco, cfg.aco.ant_system
    colony = AntSystem(
        ants=a.ants, iterations=a.iterations, rho=s.rho, Q=s.Q, alpha=s.alpha, beta=s.beta, progress=t.progress
    )
    eta = visibility(objective.z_train, pool) if s.beta else None
    res = colony.minimize(obj, pool.shape[0], m, eta=eta, generator=g, state=t.resume, on_state=t.on_state)
    centers = pool[res.best.to(pool.device)]
    return _Chosen(centers, widths_of(centers[None])[0], res.best_history, res.mean_history)


# Above this many centre coordinates M * d, or where the full colony's fits would cost more than
# FULL_FLOPS floating-point operations, the colony searches a few global width quantities instead
# of every coordinate (see `_acor_reduced`), or, where the mini-batch refinement follows and
# trains every width from the same start, skips itself; otherwise everything (as the SCARA's: its M = 80
# colony costs about 6e10, the UR5's M = 200 one 2.6e12, about 40 times as much).
FULL_SEARCH_MAX = 2048
FULL_FLOPS = 2e11
# Floating-point operations the reduced colony may spend on its fit objective (about a minute
# on one core at ~20 GFLOP/s in float64); it runs as many iterations as fit, at least one.
REDUCED_FLOPS = 1e12


class _Space(NamedTuple):
    """What the full searches of centres and widths share (`_acor`, `_cmaes`): the coordinates x
    (M d centre coordinates, then the width coordinates), their box (lower, upper), the start
    `seed` (the k-means centres c0 and their validation-tuned widths w0), the seed's spread per
    coordinate, `unpack` (x (K, D) -> centres (K, M, d), widths (K, M)) and the objective the
    ants are ranked on (x (K, D) -> (K,)). `too_large`: why the full search costs too much
    ("" where it does not), with `ranked` the fit objective the reduced search ranks on."""

    lower: torch.Tensor
    upper: torch.Tensor
    seed: torch.Tensor
    spread: torch.Tensor
    unpack: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
    objective: Callable[[torch.Tensor], torch.Tensor]
    c0: torch.Tensor
    w0: torch.Tensor
    ranked: FitObjective
    too_large: str


def _space(t: _Task) -> _Space:
    """The full search's coordinates over centre coordinates (bounded to the data's box) and widths
    (per-centre log widths, one log scale of the seed widths, or none: `cfg.aco.acor.search_widths`),
    its start at the k-means centres and their widths, and its objective (`cfg.aco.objective`)."""
    cfg, objective, m, max_width = t.cfg, t.objective, t.m, t.max_width
    a, r = cfg.aco, cfg.aco.acor
    z = objective.z_train
    d = z.shape[1]
    c0 = kmeans_centers(z, m, t.seed, cfg.kmeans_restarts)
    w0 = choose_widths(objective, c0, cfg.width_rule, cfg.width_scale, max_width)
    ranked = colony_objective(objective, m, a.fit_rows, t.seed) if a.objective == "fit" else objective
    full_cost = (r.archive_size + a.ants * a.iterations) * ranked.cost(m)
    too_large = ""
    if a.objective == "fit" and (m * d > FULL_SEARCH_MAX or full_cost > FULL_FLOPS):
        too_large = (
            f"M * d = {m * d} > {FULL_SEARCH_MAX}"
            if m * d > FULL_SEARCH_MAX
            else f"its fits would cost {full_cost:.2g} flops > {FULL_FLOPS:.2g}"
        )
    lo, hi = z.amin(0), z.amax(0)
    span = float((hi - lo).norm())
    # Width coordinates: M log widths, one log scale of the seed widths, or none.
    n_w = {"per_center": m, "scale": 1, "none": 0}[r.search_widths]
    if r.search_widths == "per_center":
        w_lo, w_hi, w_seed = math.log(span * 1e-3), math.log(max_width), w0.log()
    else:
        w_lo, w_hi, w_seed = math.log(1 / 16), math.log(16), torch.zeros(n_w, dtype=z.dtype, device=z.device)
    lower = torch.cat([lo.repeat(m), torch.full((n_w,), w_lo, dtype=z.dtype, device=z.device)])
    upper = torch.cat([hi.repeat(m), torch.full((n_w,), w_hi, dtype=z.dtype, device=z.device)])

    def unpack(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        c = x[:, : m * d].reshape(-1, m, d)
        if r.search_widths == "per_center":
            w = x[:, m * d :].exp()
        elif r.search_widths == "scale":
            w = (w0 * x[:, m * d :].exp()).clamp(max=max_width)
        else:
            w = w0.expand(x.shape[0], m)
        return c, w

    if a.objective == "fit":

        def obj(x: torch.Tensor) -> torch.Tensor:
            return ranked(*unpack(x))
    else:

        def obj(x: torch.Tensor) -> torch.Tensor:
            return cluster_objective(z, unpack(x)[0])

    spread = torch.cat(
        [
            (r.init_spread * nearest_widths(c0, k=1)).repeat_interleave(d),
            torch.full((n_w,), r.init_spread, dtype=z.dtype, device=z.device),
        ]
    )
    seed = torch.cat([c0.reshape(-1), w_seed]).clamp(lower, upper)
    return _Space(lower, upper, seed, spread, unpack, obj, c0, w0, ranked, too_large)


def _acor(t: _Task) -> _Chosen:
    """ACO_R over the full search's coordinates (`_space`).

    The archive is seeded with k-means centres and their validation-tuned widths, plus
    perturbations of them (so archive members share one centre ordering and the Gaussian
    sampling compares like with like). Where the full search costs too much (`_too_large`),
    k-means chooses the centres and the answer's note says why.
    """
    a, r, g = t.cfg.aco, t.cfg.aco.acor, t.g
    s = _space(t)
    if s.too_large:
        return _too_large(t, s.ranked, s.c0, s.w0, s.too_large)
    noise = torch.randn(r.archive_size - 1, s.seed.shape[0], dtype=s.seed.dtype, generator=g).to(s.seed.device)
    init = torch.cat([s.seed[None], s.seed + s.spread * noise])
    colony = ACOR(
        archive_size=r.archive_size,
        ants=a.ants,
        q=r.q,
        xi=r.xi,
        iterations=a.iterations,
        lower=s.lower,
        upper=s.upper,
        progress=t.progress,
    )
    res = colony.minimize(s.objective, init, generator=g, state=t.resume, on_state=t.on_state)
    c, w = s.unpack(res.best[None])
    return _Chosen(c[0], w[0].clamp(max=t.max_width), res.best_history, res.mean_history)


def _cmaes(t: _Task) -> _Chosen:
    """CMA-ES (the cmaes package) over the colony's coordinates, box, start and objective
    (`_space`), at its budget: archive_size + ants x iterations evaluations of the objective, the
    start first, then generations of `ants` candidates (at least 2). It searches in units of the
    start's spread per coordinate (its step size 1 there: the colony's perturbations of its
    archive). A candidate outside the box is ranked at its nearest point in the box, its
    objective times 1 + its squared distance outside (in those units), and that point is what
    it keeps: the best it evaluated, never worse than the start on the objective. (The library's
    own bounds resample each candidate until it falls inside: seconds a generation at the
    SCARA network's 250 coordinates.) Where the full search costs too much it returns k-means'
    centres and widths, and its note says why. It does not resume a stopped run: it starts
    again, to the same answer.
    """
    import numpy as np
    from cmaes import CMA

    a, m = t.cfg.aco, t.m
    s = _space(t)
    if s.too_large:
        note = f"CMA-ES skipped itself at M = {m} ({s.too_large}); the centres and widths are k-means'"
        log.info("CMA-ES: skipped at M = %d (%s)", m, s.too_large)
        return _Chosen(s.c0, s.w0, [], [], "kmeans", note)
    unit = s.spread.clamp_min(torch.finfo(s.spread.dtype).tiny).double().cpu()
    start = s.seed.double().cpu()
    lo, hi = (s.lower.double().cpu() - start) / unit, (s.upper.double().cpu() - start) / unit
    pop = max(a.ants, 2)
    generations = (a.acor.archive_size + a.ants * a.iterations - 1) // pop

    def evaluate(inside: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The objective (K,) (inf where not finite) at points `inside` (K, D) of the box, in the
        search's units, and those points' x."""
        x = (start + unit * inside).to(s.seed).clamp(s.lower, s.upper)
        v = s.objective(x).double().cpu()
        return torch.where(torch.isfinite(v), v, torch.full_like(v, math.inf)), x

    v0, x0 = evaluate(torch.zeros(1, start.shape[0], dtype=torch.float64))
    best_v, best_x = float(v0[0]), x0[0]
    opt = CMA(mean=np.zeros(start.shape[0]), sigma=1.0, seed=t.seed, population_size=pop)
    best, mean = [], []
    for _ in range(generations):
        ys = torch.from_numpy(np.stack([opt.ask() for _ in range(pop)]))
        inside = torch.maximum(torch.minimum(ys, hi), lo)
        v, x = evaluate(inside)
        outside = (ys - inside).square().sum(1)
        opt.tell(list(zip(ys.numpy(), cma_ranks(v * (1 + outside)).tolist())))
        finite = v[torch.isfinite(v)]
        i = int(v.argmin())
        if float(v[i]) < best_v:
            best_v, best_x = float(v[i]), x[i]
        best.append(best_v)
        mean.append(float(finite.mean()) if finite.numel() else math.inf)
    c, w = s.unpack(best_x[None])
    return _Chosen(c[0], w[0].clamp(max=t.max_width), best, mean)


def cma_ranks(values: torch.Tensor) -> torch.Tensor:
    """What CMA-ES is told of candidates' `values` (K,): each non-finite one (a failed fit, a
    diverged run) replaced by ten times the worst finite one (1e300 where none is finite), so that
    it ranks last; CMA-ES uses the values only to rank the candidates."""
    finite = torch.isfinite(values)
    worst = float(values[finite].max()) * 10 if bool(finite.any()) else 1e300
    return torch.where(finite, values, torch.full_like(values, worst))


# The centre selectors by `rbfn.config.Method`, the one list of their names.
_METHODS: dict[Method, Callable[[_Task], _Chosen]] = {
    Method.aco: _aco,
    Method.kmeans: _kmeans,
    Method.random: _random,
    Method.ols: _ols,
    Method.cmaes: _cmaes,
}
assert set(_METHODS) == set(Method), "each rbfn.config.Method needs its selector here"


def _too_large(t: _Task, ranked: FitObjective, c0: torch.Tensor, w0: torch.Tensor, why: str) -> _Chosen:
    """`_acor` where the full search costs too much (`why`): the k-means centres c0 (M, d) with
    widths w0 (M,), searched over two global width quantities (`_acor_reduced`) or, before the
    mini-batch refinement, as they are."""
    m, z = t.m, t.objective.z_train
    if t.cfg.refine.enabled and refine_mode(t.cfg.refine, z.shape[0], t.objective.width(m)) == "minibatch":
        # The reduced colony's two global width quantities are a subset of what the mini-batch
        # refinement then trains per centre from the same k-means start, over many epochs, and
        # it erased their gain (UR5, M = 2000: 2-4 % worse than without them, docs/results.md):
        # the colony skips itself. Before the `full` refinement (the SCARA at M = 160) it still
        # helps (0.125 against 0.142 mm over five seeds), so it runs there.
        what = (
            "it could search two global width quantities only, which the mini-batch refinement trains "
            "per centre; the k-means centres and their validation-tuned widths go to the refinement as they are"
        )
        log.info("colony: skipped at M = %d (%s): %s", m, why, what)
        return _Chosen(c0, w0, [], [], "kmeans", f"the colony skipped itself at M = {m} ({why}): {what}")
    note = (
        f"the colony searched two global width quantities only at M = {m} ({why}); the centres are "
        "k-means' (rbfn.select._acor_reduced)"
    )
    widths, res = _acor_reduced(t, ranked, c0, w0)
    return _Chosen(c0, widths, res.best_history, res.mean_history, "kmeans", note)


def _acor_reduced(
    t: _Task, objective: FitObjective, c0: torch.Tensor, w0: torch.Tensor
) -> tuple[torch.Tensor, ACOResult]:
    """ACO_R over two global width quantities, the k-means centres c0 (M, d) held fixed; returns
    the widths (M,) and the colony's result. `objective`: the colony's (`colony_objective`).

    x = (log scale s, exponent b): widths = e^s * w0_med * (w0 / w0_med)^(1 + b), w0 the seed's
    validation-tuned per-centre widths (median w0_med; its scale from a grid 2x apart), clamped
    to max_width; s in [log 1/4, log 4], b in [-1, 1]. x = 0 is the seed itself, so the result is
    never worse than it on the objective. At large M * d the full search (M * (d + 1) coordinates,
    one fit per ant costing O(N P^2)) cannot move in the few ants it can afford; these two quantities (how wide, and how
    much the width follows the local centre spacing) are what the seed's coarse grid scale leaves
    open. The archive and ants shrink to 3 and the iterations to the budget `REDUCED_FLOPS`.
    """
    a, r, max_width, g = t.cfg.aco, t.cfg.aco.acor, t.max_width, t.g
    z = objective.z_train
    k = min(r.archive_size, 3)
    ants = min(a.ants, 3)
    evals = max(int(REDUCED_FLOPS / objective.cost(c0.shape[0])), k + ants)
    iterations = max(1, min(a.iterations, (evals - k) // ants))
    lower = torch.tensor([math.log(0.25), -1.0], dtype=z.dtype, device=z.device)
    upper = -lower
    w_med = w0.median()
    rel = (w0 / w_med).log()

    def widths_of(x: torch.Tensor) -> torch.Tensor:
        return (w_med * (x[:, :1] + (1 + x[:, 1:]) * rel).exp()).clamp(max=max_width)  # (K, M)

    def obj(x: torch.Tensor) -> torch.Tensor:
        return objective(c0.expand(x.shape[0], *c0.shape), widths_of(x))

    noise = torch.randn(k - 1, 2, dtype=z.dtype, generator=g).to(z.device)
    init = torch.cat([torch.zeros(1, 2, dtype=z.dtype, device=z.device), 0.2 * noise])
    colony = ACOR(
        archive_size=k, ants=ants, q=r.q, xi=r.xi, iterations=iterations, lower=lower, upper=upper, progress=t.progress
    )
    res = colony.minimize(obj, init, generator=g, state=t.resume, on_state=t.on_state)
    return widths_of(res.best[None])[0], res
