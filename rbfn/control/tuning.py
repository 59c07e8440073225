"""Tuning the adaptive controller's network on the closed loop itself
(`control.network.objective=closed_loop`).

A candidate is the k-means twin's network (`rbfn.control.network`, centres and widths fitted to the
pilot run) moved: with the twin's centres c_i and widths w_i (standardised desired-state units),

    centre i = c_i + u_i,   width i = w_i exp(v_i + g),
    |u_ij| <= max_offset,   |v_i|, |g| <= log(max_width_factor),

x = (u, v, g) flattened (M (2n + 1) + 1,); x = 0 is the twin itself. The common log-width g is
one coordinate for what otherwise takes all M at once: on the SCARA most of the gain lies in
wider Gaussians. Its cost is what the controller is
judged by: every candidate runs the adaptive law from the twin's initial weights on every tuning
scenario, all of them as one batched simulation (B = candidates x scenarios, each environment with
its own network: features (T, B, M)), and

    cost = mean over scenarios of [ sum_j rms_j / rms_j(smc) + saturation_penalty sum_j sat_j ],

rms_j a joint's tracking RMS (t > 0.5 s), rms_j(smc) the plain sliding-mode controller's in the
same scenario (run once), sat_j the share of control periods its torque was at its limit (the
realistic loop; 0 in the ideal one). The scenarios are drawn from `control.network.tune`'s ranges
and never equal the evaluation's cases (`tuning_scenarios`).

Three searches spend the same budget, `iterations` batches of `population` candidates
(`tune_network`): ACO_R (`aco`), random search around the twin (`random`) and CMA-ES (`cmaes`);
each starts at the twin and keeps the best candidate it evaluated.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import torch

from aco import ACOR

from ..config import ADAPTIVE, CLOSED_LOOP_SEARCHES, ACORConfig, TuneConfig
from ..fit import design_matrix, ridge_fit
from ..gaussians import gaussian_features
from ..progress import Progress
from ..select import cma_ranks
from .controllers import Gains, JointRates, Model, make_controller
from .loop import RealLoop
from .network import ControlNet, desired_states
from .simulator import Plant, Scenario, SimulationDiverged, metric_tensors, simulate
from .trajectory import Reference

__all__ = [
    "TuneScenarios",
    "Tuned",
    "tuning_scenarios",
    "tuning_cost",
    "ClosedLoopCost",
    "tune_network",
    "confirmed",
    "run_scenarios",
]
MAX_DRAWS = 1000  # redraws of a scenario value that falls on an evaluation case before giving up


def tuning_cost(rms: torch.Tensor, sat: torch.Tensor, smc_rms: torch.Tensor, penalty: float) -> torch.Tensor:
    """The tuning's cost (the module docstring) of runs with RMS error and share of periods at the
    torque limit `rms`, `sat` (..., S, n) on S scenarios where smc's RMS is `smc_rms` (S, n): the
    mean over the scenarios of sum_j rms_j / rms_j(smc) + penalty sum_j sat_j, shape (...)."""
    return ((rms / smc_rms).sum(-1) + penalty * sat.sum(-1)).mean(-1)


@dataclass
class TuneScenarios:
    """The tuning's S scenarios: payloads (S,) kg, disturbance amplitudes (S, n) N m (N),
    frequencies (S,) rad/s and phases (S,) rad, and the sensor-noise seed (each scenario its own
    stream of it)."""

    payloads: torch.Tensor
    amplitude: torch.Tensor
    freq: torch.Tensor
    phase: torch.Tensor
    noise_seed: int

    def with_payload(self, kg: float) -> TuneScenarios:
        """These scenarios and one more: the heaviest one's disturbance, carrying `kg`."""
        i = int(self.payloads.argmax())
        return TuneScenarios(
            torch.cat([self.payloads, self.payloads.new_tensor([kg])]),
            torch.cat([self.amplitude, self.amplitude[i : i + 1]]),
            torch.cat([self.freq, self.freq[i : i + 1]]),
            torch.cat([self.phase, self.phase[i : i + 1]]),
            self.noise_seed,
        )

    def listed(self) -> dict[str, Any]:
        """As plain lists, for metrics.json."""
        return {
            "payloads": self.payloads.tolist(),
            "disturbance": self.amplitude.tolist(),
            "disturbance_freq": self.freq.tolist(),
            "disturbance_phase": self.phase.tolist(),
            "noise_seed": self.noise_seed,
        }


def tuning_scenarios(
    tune: TuneConfig,
    *,
    rated_payload: float,
    disturbance: list[float],
    eval_payloads: list[float],
    eval_freq: float,
    eval_noise_seed: int,
) -> TuneScenarios:
    """Draw `tune.scenarios` scenarios (seeded by tune.seed) from tune's ranges: payloads as
    fractions of `rated_payload` kg (stratified: scenario i from the i-th of S equal parts of the
    range, so that light and heavy payloads are both tuned on), amplitudes as factors of the
    evaluation's `disturbance` (n,) N m (N), frequencies, phases. A payload within 1 % of the
    range's width (0.01 kg at least) of an evaluation payload, a frequency as near `eval_freq` and
    an amplitude factor as near 1 are drawn again, and the noise seed is never `eval_noise_seed`:
    the evaluation's cases are never tuned on.
    ValueError names the key whose range leaves nothing else to draw."""
    g = torch.Generator().manual_seed(tune.seed)

    def draw(key: str, low: float, high: float, avoid: list[float], tol: float) -> float:
        for _ in range(MAX_DRAWS):
            v = low + (high - low) * float(torch.rand((), generator=g, dtype=torch.float64))
            if all(abs(v - a) > tol for a in avoid):
                return v
        raise ValueError(
            f"control.network.tune.{key}={list(getattr(tune, key))} leaves nothing to draw (here "
            f"[{low:g}, {high:g}]) but the evaluation's own values {avoid}: widen the range"
        )

    p_lo, p_hi = (f * rated_payload for f in tune.payload)
    p_tol = max(0.01 * (p_hi - p_lo), 0.01)
    f_lo, f_hi = tune.disturbance_freq
    d_lo, d_hi = tune.disturbance
    a_lo, a_hi = tune.disturbance_phase
    payloads, factors, freqs, phases = [], [], [], []
    strata = tune.scenarios
    for i in range(tune.scenarios):  # payloads stratified: scenario i draws from the i-th of S equal parts
        lo, hi = p_lo + (p_hi - p_lo) * i / strata, p_lo + (p_hi - p_lo) * (i + 1) / strata
        payloads.append(draw("payload", lo, hi, list(eval_payloads), p_tol))
        factors.append(draw("disturbance", d_lo, d_hi, [1.0], max(0.01 * (d_hi - d_lo), 1e-3)))
        freqs.append(draw("disturbance_freq", f_lo, f_hi, [eval_freq], max(0.01 * (f_hi - f_lo), 1e-3)))
        phases.append(draw("disturbance_phase", a_lo, a_hi, [], 0.0))
    seed = eval_noise_seed
    while seed == eval_noise_seed:
        seed = int(torch.randint(0, 2**31 - 1, (), generator=g))
    amp = torch.tensor(factors, dtype=torch.float64)[:, None] * torch.tensor(disturbance, dtype=torch.float64)
    return TuneScenarios(
        torch.tensor(payloads, dtype=torch.float64),
        amp,
        torch.tensor(freqs, dtype=torch.float64),
        torch.tensor(phases, dtype=torch.float64),
        seed,
    )


class ClosedLoopCost:
    """The closed-loop cost of candidate networks (see the module docstring): `__call__(x)` with x
    (K, M (2n + 1)) returns (K,) costs, inf where a candidate's run diverged. Built once per
    comparison; it runs `smc` on the scenarios once for the reference RMS.

    plant, model, gains, joint_scale (n,), rates, observer: the comparison's; twin: the k-means
    twin (its standardisation, centres, widths); scenario: the tuning episode (its duration and
    payload window); ref: its desired trajectory (T, n) at the integration step; loop: the
    realistic loop (None: ideal); pilot: (z, y) the pilot run's standardised inputs and residual
    torque, for warm-started weights (None: the twin's zeros)."""

    def __init__(
        self,
        *,
        plant: Plant,
        model: Model,
        gains: Gains,
        twin: ControlNet,
        scenarios: TuneScenarios,
        scenario: Scenario,
        ref: Reference,
        tune: TuneConfig,
        observer: bool = True,
        joint_scale: torch.Tensor | None = None,
        rates: JointRates | None = None,
        loop: RealLoop | None = None,
        pilot: tuple[torch.Tensor, torch.Tensor] | None = None,
        compile: bool = False,
        aot: bool = False,
    ) -> None:
        self.model, self.gains, self.twin, self.tune = model, gains, twin, tune
        self.observer, self.scale, self.rates, self.pilot, self.compile = observer, joint_scale, rates, pilot, compile
        self.aot = aot
        self.scenarios, self.scenario, self.ref = scenarios, scenario, ref
        s = scenarios.payloads.shape[0]
        self.s, self.n = s, ref.q_d.shape[1]
        self.loop = None if loop is None else replace(loop, noise_envs=s, seed=scenarios.noise_seed)
        self.period = scenario.dt if self.loop is None else self.loop.period
        self.plant = plant
        m, d = twin.centers.shape
        self.m, self.d = m, d
        limit_u, limit_v = tune.max_offset, math.log(tune.max_width_factor)
        self.upper = torch.cat([torch.full((m * d,), limit_u), torch.full((m + 1,), limit_v)]).double()
        self.lower = -self.upper
        self.z = (desired_states(ref).double().cpu() - twin.offset) / twin.scale  # (T, d)
        kw: dict[str, Any] = {"dtype": ref.q_d.dtype, "device": ref.q_d.device}
        self.kw = kw
        t0 = time.perf_counter()
        smc = make_controller("smc", gains, self.period, model=model, joint_scale=joint_scale, rates=rates)
        rms, _ = self._run(smc, 1)
        self.smc_rms = rms[0].clamp_min(1e-12)  # (S, n)
        self.smc_seconds = time.perf_counter() - t0

    @functools.cached_property
    def twin_cost(self) -> float:
        """The k-means twin's cost (x = 0), run once and shared by the searches' confirmation and
        arbfn_kmeans' record."""
        return float(self(torch.zeros(1, self.dimension, dtype=torch.float64))[0])

    @property
    def dimension(self) -> int:
        """D = M (d + 1) + 1: the centre offsets, the log-widths and the common log-width."""
        return self.m * (self.d + 1) + 1

    def networks(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Centres (K, M, d) and widths (K, M), standardised units, of candidates x (K, D)."""
        k = x.shape[0]
        x = x.double().cpu()
        u = x[:, : self.m * self.d].reshape(k, self.m, self.d)
        v, g = x[:, self.m * self.d : -1], x[:, -1:]
        return self.twin.centers.double() + u, self.twin.widths.double() * (v + g).exp()

    def net(self, x: torch.Tensor, seconds: float) -> ControlNet:
        """Candidate x (D,) as a ControlNet (its weights initialised as the twin's)."""
        centers, widths = self.networks(x[None])
        return ControlNet(
            self.twin.offset, self.twin.scale, centers[0], widths[0], self._w0(centers, widths)[0], seconds
        )

    def _w0(self, centers: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
        """Initial weights (K, M, n): zeros, or (warm start) each candidate's ridge fit of the pilot."""
        k = centers.shape[0]
        if self.pilot is None:
            return torch.zeros(k, self.m, self.n, dtype=torch.float64)
        z, y = self.pilot
        fits = []
        for c, w in zip(centers, widths):
            a_tr = design_matrix(z[0::2], c, w, tail=False)
            a_val = design_matrix(z[1::2], c, w, tail=False)
            fits.append(ridge_fit(a_tr, y[0::2], a_val, y[1::2]).weights)
        return torch.stack(fits)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """Costs (K,) of candidates x (K, D); inf for a candidate whose run diverged."""
        centers, widths = self.networks(x)
        w0 = self._w0(centers, widths)
        k = x.shape[0]
        cost = torch.full((k,), math.inf, dtype=torch.float64)
        alive = list(range(k))
        while alive:
            idx = torch.tensor(alive)
            feats = gaussian_features(self.z, centers[idx], widths[idx])  # (K', T, M)
            feats = feats.transpose(0, 1).repeat_interleave(self.s, 1)  # (T, K' S, M)
            ctrl = make_controller(
                ADAPTIVE + "tune",
                self.gains,
                self.period,
                model=self.model,
                features=feats.to(**self.kw),
                w0=w0[idx].repeat_interleave(self.s, 0).to(**self.kw),
                observer=self.observer,
                joint_scale=self.scale,
                rates=self.rates,
            )
            try:
                rms, sat = self._run(ctrl, len(alive))
            except SimulationDiverged as e:
                alive.pop(e.environment // self.s)  # that candidate's cost stays inf; run the others again
                continue
            cost[idx] = tuning_cost(rms, sat, self.smc_rms, self.tune.saturation_penalty)
            break
        return cost

    def _run(self, ctrl, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """RMS error (k, S, n) and share of periods at the torque limit (k, S, n) of `ctrl` driving
        k blocks of the S scenarios."""
        return run_scenarios(
            self.plant, ctrl, k, self.scenarios, self.scenario, self.ref, self.loop, compile=self.compile, aot=self.aot
        )


def run_scenarios(
    plant: Plant,
    ctrl: Any,
    k: int,
    scenarios: TuneScenarios,
    scenario: Scenario,
    ref: Reference,
    loop: RealLoop | None,
    *,
    compile: bool = False,
    aot: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """RMS error (k, S, n) and share of periods at the torque limit (k, S, n) of `ctrl` driving k
    blocks of the S `scenarios` (each block its payloads, disturbances and noise), along `ref`
    over `scenario`'s episode, in `loop` (None: ideal; its noise shared by the blocks:
    `noise_envs` S). Raises SimulationDiverged naming the environment."""
    s, n = scenarios.payloads.shape[0], ref.q_d.shape[1]
    kw: dict[str, Any] = {"dtype": ref.q_d.dtype, "device": ref.q_d.device}
    b = k * s
    varied = plant.varied(
        scenarios.amplitude.repeat(k, 1).to(**kw), scenarios.freq.repeat(k).to(**kw), scenarios.phase.repeat(k).to(**kw)
    )
    roll = simulate(
        varied,
        ctrl,
        scenario,
        ref,
        q0=ref.q_d[:1].expand(b, n).clone(),
        qd0=ref.qd_d[:1].expand(b, n).clone(),
        payload=scenarios.payloads.repeat(k).to(**kw),
        compile=compile,
        aot=aot,
        loop=loop,
    )
    q_des = ref.q_d if loop is None else ref.q_d[:: loop.substeps][: roll.t.shape[0]]
    rms = metric_tensors(roll, q_des, scenario)["rms_err"].double().cpu().reshape(k, s, n)
    sat = torch.zeros_like(rms) if roll.saturated is None else roll.saturated.double().cpu().reshape(k, s, n)
    return rms, sat


@dataclass
class Tuned:
    """A search's result: the best network, its cost, the closed-loop episodes it ran, the time
    it took (s), the best-so-far cost after each iteration, and the best candidate x (D,) (None:
    not searched)."""

    net: ControlNet
    cost: float
    episodes: int
    seconds: float
    curve: list[float] = field(default_factory=list)
    x: torch.Tensor | None = None
    confirmation: tuple[float, float] | None = None  # (this network, the twin) at the evaluation's length
    kept_twin: bool = False  # the search's network failed the confirmation: the twin kept


class _Tally:
    """Counts a search's episodes and keeps its best candidate and best-so-far curve; tells
    `progress` how many of `batches` batches of candidates are done."""

    def __init__(
        self, cost: ClosedLoopCost, batches: int = 0, what: str = "", progress: Progress | None = None
    ) -> None:
        self.cost, self.episodes = cost, 0
        self.batches, self.what, self.progress = batches, what, progress
        self.curve: list[float] = []
        self.best_x: torch.Tensor | None = None
        self.best = math.inf

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        values = self.cost(x)
        self.episodes += x.shape[0] * self.cost.s
        i = int(values.argmin())
        if self.best_x is None or float(values[i]) < self.best:
            self.best, self.best_x = float(values[i]), x[i].clone()
        self.curve.append(self.best)
        if self.progress is not None:
            self.progress.at(self.what, len(self.curve), self.batches, "batches of candidates")
        return values


def confirmed(found: Tuned, cost: ClosedLoopCost, confirm: ClosedLoopCost) -> Tuned:
    """`found` where, on the tuning's scenarios in episodes as long as the evaluation's (`confirm`),
    its cost is no higher than its k-means twin's; else the twin, with its tuning cost
    (`kept_twin`). An adapted network can drift unstable after the tuning's shorter episode ends
    (on the Unitree Z1 a tuned network's weights drove two joints to their torque limits from
    8 s of 10), which the search cannot see; the confirmation costs 2 x S episodes of the
    evaluation's length, counted in `episodes`."""
    if found.x is None:
        return found
    twin = torch.zeros_like(found.x)
    mine, theirs = (float(c) for c in confirm(torch.stack([found.x, twin])))
    episodes = found.episodes + 2 * confirm.s
    if mine <= theirs:
        return replace(found, episodes=episodes, confirmation=(mine, theirs))
    return replace(
        found,
        net=cost.net(twin, found.seconds),
        cost=cost.twin_cost,
        episodes=episodes + cost.s,
        x=twin,
        confirmation=(mine, theirs),
        kept_twin=True,
    )


def tune_network(
    search: str,
    cost: ClosedLoopCost,
    tune: TuneConfig,
    seed: int,
    acor: ACORConfig | None = None,
    progress: Progress | None = None,
) -> Tuned:
    """The best network `search` (one of rbfn.config.CLOSED_LOOP_SEARCHES) finds in tune.iterations batches of
    tune.population candidates, starting at the twin (x = 0): `aco`, ACO_R (its archive
    min(acor.archive_size, population), q and xi from `acor`) whose first ants are the twin and
    population - 1 draws N(0, spread^2) around it; `random`, the same first batch, then batch after
    batch of such draws; `cmaes`, CMA-ES from mean 0 with step size `spread`. Every candidate is
    clipped to the same box (cost.lower, cost.upper). progress: where given, follows the batches."""
    if search not in _SEARCHES:
        raise ValueError(f"unknown closed-loop search {search!r}; choose one of {list(CLOSED_LOOP_SEARCHES)}")
    g = torch.Generator().manual_seed(seed)
    tally = _Tally(cost, tune.iterations, f"tuning the network by {search}", progress)
    t0 = time.perf_counter()
    _SEARCHES[search](_Search(tally, cost, tune, g, seed, acor or ACORConfig()))
    seconds = time.perf_counter() - t0
    assert tally.best_x is not None
    return Tuned(cost.net(tally.best_x, seconds), tally.best, tally.episodes, seconds, tally.curve, tally.best_x)


class _Search(NamedTuple):
    """What a closed-loop search is given: the cost it calls (`_Tally`, batches of candidates
    (K, dimension) -> costs (K,)), the problem's box and size (`cost`), the budget (`tune`), the
    generator and seed, and the colony's parameters."""

    tally: Any
    cost: ClosedLoopCost
    tune: TuneConfig
    g: torch.Generator
    seed: int
    acor: ACORConfig

    def around_twin(self, first: bool) -> torch.Tensor:
        """A batch of draws N(0, spread^2) around the twin (x = 0), the first one the twin itself
        where `first`, clipped to the box."""
        x = self.tune.spread * torch.randn(
            self.tune.population, self.cost.dimension, generator=self.g, dtype=torch.float64
        )
        if first:
            x[0] = 0.0  # the twin itself
        return torch.maximum(torch.minimum(x, self.cost.upper), self.cost.lower)


def _aco(s: _Search) -> None:
    """ACO_R: its archive min(acor.archive_size, population), q and xi from `acor`; the first ants
    the twin and population - 1 draws around it."""
    pop = s.tune.population
    colony = ACOR(
        archive_size=min(s.acor.archive_size, pop),
        ants=pop,
        q=s.acor.q,
        xi=s.acor.xi,
        iterations=s.tune.iterations - 1,
        lower=s.cost.lower,
        upper=s.cost.upper,
    )
    colony.minimize(s.tally, s.around_twin(True), generator=s.g)


def _random(s: _Search) -> None:
    """The same first batch as the colony's, then batch after batch of draws around the twin."""
    for it in range(s.tune.iterations):
        s.tally(s.around_twin(it == 0))


def _cmaes(s: _Search) -> None:
    """CMA-ES (the cmaes package) from mean 0 with step size `spread`, within the box."""
    import numpy as np
    from cmaes import CMA

    lo, hi, pop = s.cost.lower, s.cost.upper, s.tune.population
    opt = CMA(
        mean=np.zeros(s.cost.dimension),
        sigma=s.tune.spread,
        bounds=np.stack([lo.numpy(), hi.numpy()], 1),
        seed=s.seed,
        population_size=pop,
    )
    for _ in range(s.tune.iterations):
        xs = [opt.ask() for _ in range(pop)]
        values = s.tally(torch.tensor(np.stack(xs), dtype=torch.float64))
        opt.tell(list(zip(xs, cma_ranks(values).tolist())))  # a diverged run ranks last


# Each closed-loop search of rbfn.config.NETWORK_METHODS (searches=True), by its name.
_SEARCHES: dict[str, Callable[[_Search], None]] = {"aco": _aco, "random": _random, "cmaes": _cmaes}
assert set(_SEARCHES) == set(CLOSED_LOOP_SEARCHES), (
    "every closed-loop search of NETWORK_METHODS needs its function here"
)
