"""The closed-loop comparison: every controller on every payload case, at equal gains, for one robot.

Every controller on every payload case runs in one batched simulation (`Stacked`: B = controllers
x cases), after a pilot run of `smc_obs` without payload that gives the adaptive RBFN its centres
(see rbfn.control.network) when an `arbfn_*` controller is compared. One batch pays the simulator's
per-operation overhead once instead of once per controller. Pure: tensors and metrics out,
nothing printed or written.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple, cast

import torch

from ..config import (
    ADAPTIVE,
    CLOSED_LOOP_SEARCHES,
    PILOT_STRIDE,
    ControlConfig,
    Dtype,
    Feedforward,
    GainsConfig,
    LoopConfig,
    NetworkConfig,
    NetworkLaw,
    NetworkObjective,
    Objective,
    RobotConfig,
    TuneConfig,
    network_method,
)
from ..progress import Progress
from .aot import ahead_of_time
from .batch import Stacked
from .controllers import InertiaSchedule, Model, make_controller
from .loop import RealLoop, real_loop, velocity_lag
from .models import model_scales
from .network import (
    ControlNet,
    PayloadBasis,
    control_network,
    desired_states,
    model_payload_torque,
    payload_basis,
    payload_residuals,
    pilot_residuals,
)
from .robot_setup import ControlRobot, GainFactors, control_robot
from .simulator import (
    Rollout,
    Scenario,
    SimulationDiverged,
    control_metrics,
    payload_schedule,
    pick_and_place,
    simulate,
)
from .trajectory import Reference
from .tuning import (
    ClosedLoopCost,
    Tuned,
    TuneScenarios,
    confirmed,
    run_scenarios,
    tune_network,
    tuning_cost,
    tuning_scenarios,
)

__all__ = [
    "ControlRun",
    "LawSettings",
    "ControlComparison",
    "PickedAndPlaced",
    "PICK_AND_PLACE",
    "compare_controllers",
    "case_name",
    "gap_closure",
]


PICK_AND_PLACE = "pick_and_place"  # the case key of control.pick_and_place's run


def case_name(payload: float) -> str:
    """Payload case key: 10.0 -> "10kg", 2.5 -> "2.5kg"."""
    return f"{payload:g}kg"


@dataclass
class ControlRun:
    """One controller's runs: metrics per case, its rollout (B = cases), and the time spent."""

    metrics: dict[str, dict[str, list[float]]]  # case -> rms_err, max_err, ... (lists of n)
    rollout: Rollout
    sim_seconds: float  # the whole batch's (every controller's) simulation
    select_seconds: float | None = None  # the network's centre selection (arbfn_*)
    basis: PayloadBasis | None = None  # phase 1's fit (arbfn_* under the two-phase law)
    tuned: Tuned | None = None  # the closed-loop tuning (arbfn_aco, _random, _cmaes; arbfn_kmeans: its cost)
    settings: LawSettings | None = None  # the two-phase law's, as chosen (control.network.feedforward, ...)


@dataclass
class ControlComparison:
    """Every controller's run, the desired joints (T, n), the scenario and the robot."""

    runs: dict[str, ControlRun]
    q_des: torch.Tensor
    scenario: Scenario
    payloads: list[float] = field(default_factory=list)
    robot: ControlRobot | None = None
    joint_scale: list[float] | None = None  # the controllers' torque-gain factor per joint (None: 1)
    tune_scenarios: TuneScenarios | None = None  # the closed-loop tuning's scenarios, where it ran
    tuning_seconds: float = 0.0  # wall time of the closed-loop tuning: the scenarios' smc references,
    # every search and its confirmation
    phase_one_payloads: list[float] | None = None  # kg: the two-phase law's phase 1 conditions, where it ran
    phase_one_seconds: float = 0.0  # wall time of phase 1's calibration runs
    choice_seconds: float = 0.0  # wall time of choosing the two-phase law's settings (LawSettings)
    pick_and_place: PickedAndPlaced | None = None  # control.pick_and_place's run, where it ran
    network: NetworkConfig | None = None  # control.network as it ran: its law and objective resolved


@dataclass
class PickedAndPlaced:
    """The pick-and-place run: its rollout (B = controllers, in control.controllers' order), the
    desired joints (T, n) and the mass carried (T,) at its rows, its scenario (the carries: shares
    of `rated`, kg) and its simulation's wall time (s)."""

    rollout: Rollout
    q_des: torch.Tensor
    carried: torch.Tensor  # (T,) kg at the rollout's rows (`payload_schedule`)
    scenario: Scenario
    rated: float
    seconds: float

    def masses(self) -> list[tuple[float, float, float]]:
        """(pick time s, place time s, mass kg) of each carry."""
        return [(c.on, c.off, c.share * self.rated) for c in self.scenario.carries]


def compare_controllers(
    cfg: ControlConfig,
    gains: GainsConfig,
    device: str = "cpu",
    robot: RobotConfig | None = None,
    setup: ControlRobot | None = None,
    loop: LoopConfig | None = None,
    progress: Progress | None = None,
) -> ControlComparison:
    """Run `cfg.controllers` on the payload cases (kg) along the robot's desired trajectory.

    robot: the robot (default: the SCARA); setup: an already checked `control_robot(robot, cfg)`;
    loop: how real the loop is (None: ideal). In the realistic loop the controllers act every
    control period (their adaptation steps gamma times it), the pilot run stays ideal. progress:
    where given, follows the closed-loop tuning's batches."""
    c = _Context.of(cfg, gains, device, setup or control_robot(robot or RobotConfig(), cfg), loop, progress)
    nw = _networks(c)
    cases = [case_name(p) for p in c.setup.payloads]
    payload = torch.tensor(c.setup.payloads, **c.kw)
    roll, q_des, per_env, seconds = _run_all(c, nw, c.sc, c.ref, payload, cases)
    b = len(cases)
    runs: dict[str, ControlRun] = {}
    for i, name in enumerate(c.cfg.controllers):
        envs = slice(i * b, (i + 1) * b)
        sat = None if roll.saturated is None else roll.saturated[envs]
        part = Rollout(roll.t, roll.q[:, envs], roll.qd[:, envs], roll.tau[:, envs], sat)
        runs[name] = ControlRun(
            metrics=dict(zip(cases, per_env[envs])),
            rollout=part,
            sim_seconds=seconds,
            select_seconds=nw.select_seconds.get(name),
            basis=nw.bases.get(network_method(name) or ""),
            tuned=nw.tuned.get(name),
            settings=nw.settings.get(network_method(name) or ""),
        )
    picked = _pick_and_place_run(c, nw, runs) if c.cfg.pick_and_place.picks else None
    if nw.cost is not None and "arbfn_kmeans" in runs:  # the twin on the tuning's scenarios, beside the searches
        t0 = time.perf_counter()
        runs["arbfn_kmeans"].tuned = Tuned(nw.nets["kmeans"], nw.cost.twin_cost, nw.cost.s, time.perf_counter() - t0)
    if "smc" in runs and "smc_exact" in runs:
        for run in runs.values():
            for case, m in run.metrics.items():
                m["gap_closure"] = gap_closure(runs["smc"].metrics[case], m, runs["smc_exact"].metrics[case])
    return ControlComparison(
        runs,
        q_des=q_des,
        scenario=c.sc,
        payloads=list(c.setup.payloads),
        robot=c.setup,
        joint_scale=c.factors.listed,
        tune_scenarios=None if nw.cost is None else nw.cost.scenarios,
        tuning_seconds=nw.tuning_seconds,
        phase_one_payloads=nw.conditions if nw.bases else None,
        phase_one_seconds=nw.phase_one_seconds,
        choice_seconds=nw.choice_seconds,
        pick_and_place=picked,
        network=c.cfg.network,
    )


@dataclass
class _Context:
    """What every stage of a comparison shares: the settings (control.network's law and objective
    resolved), the robot, the tensors' dtype and device (`kw`), the scenario and its reference,
    the plant and nominal model, the realistic loop (None: ideal), the gains' per-joint factors,
    the ahead-of-time setting, the progress line and the URDF's position limits."""

    cfg: ControlConfig
    gains: GainsConfig
    setup: ControlRobot
    kw: dict[str, Any]
    sc: Scenario
    ref: Reference
    model: Model
    real: RealLoop | None
    loop: LoopConfig | None
    factors: GainFactors
    aot: bool
    progress: Progress | None
    limits: tuple[torch.Tensor, torch.Tensor] | None

    @classmethod
    def of(
        cls,
        cfg: ControlConfig,
        gains: GainsConfig,
        device: str,
        setup: ControlRobot,
        loop: LoopConfig | None,
        progress: Progress | None,
    ) -> _Context:
        dtype = torch.float64 if cfg.dtype == Dtype.float64 else torch.float32
        kw: dict[str, Any] = {"dtype": dtype, "device": device}
        sc = Scenario(cfg.duration, cfg.dt, cfg.integrator, cfg.payload_on, cfg.payload_off)
        sc.validate()
        aot = ahead_of_time(cfg.aot, device, cfg.compile)
        ref = Reference(*setup.trajectory(sc.times(torch.float64))).to(**kw)  # each (T, n)
        model = setup.nominal_model(gains.nominal_payload, model_scales(gains))
        real: RealLoop | None = None
        if loop is not None:
            effort = torch.tensor(setup.effort if setup.effort is not None else [float("inf")] * setup.n)
            real = real_loop(loop, sc.dt, setup.prismatic, effort, setup.joint_scale(**kw))
            if real is not None:  # every controller meets the same noise in each payload case
                real = replace(real, noise_envs=len(setup.payloads))
        cfg = replace(cfg, network=cfg.network.resolved(realistic=real is not None))  # a null law and objective
        factors = setup.gain_factors(gains, real, dt=sc.dt, **kw)  # the joint scale, capped where the loop needs
        limits = None if setup.lower is None else (torch.tensor(setup.lower), torch.tensor(setup.upper))
        return cls(cfg, gains, setup, kw, sc, ref, model, real, loop, factors, aot, progress, limits)

    @property
    def two_phase(self) -> bool:
        return self.cfg.network.law == NetworkLaw.two_phase

    @property
    def period(self) -> float:
        """The controllers' time step, s."""
        return self.sc.dt if self.real is None else self.real.period

    @property
    def velocity_lag(self) -> float:
        """The two-phase law's compensated velocity lag, s (`control.network.lag_compensation`;
        0 where it is off or the loop is ideal)."""
        return velocity_lag(self.real) if self.cfg.network.lag_compensation else 0.0

    def stage(self, what: str) -> None:
        """A step of no counted parts, for the progress line."""
        if self.progress is not None:
            self.progress.at(what, 0, 0)


@dataclass
class _Networks:
    """The adaptive controllers' networks (`made`, by controller) and how they came: the networks
    selected on the pilot run or phase 1 (`nets`, by method), phase 1's fits (`bases`, by method),
    the closed-loop tunings (`tuned`, by controller) and their cost, the inertia schedule and phase
    1's payloads (kg) of the two-phase law, and the seconds each stage took."""

    made: dict[str, ControlNet] = field(default_factory=dict)
    nets: dict[str, ControlNet] = field(default_factory=dict)
    bases: dict[str, PayloadBasis] = field(default_factory=dict)
    tuned: dict[str, Tuned] = field(default_factory=dict)
    select_seconds: dict[str, float] = field(default_factory=dict)
    cost: ClosedLoopCost | None = None
    schedule: InertiaSchedule | None = None
    conditions: list[float] = field(default_factory=list)
    pilot: tuple[torch.Tensor, torch.Tensor] | None = None
    tuning_seconds: float = 0.0
    phase_one_seconds: float = 0.0
    settings: dict[str, LawSettings] = field(default_factory=dict)  # by method: the two-phase law's, as chosen
    choice_seconds: float = 0.0


def _networks(c: _Context) -> _Networks:
    """Every adaptive controller's network: the pilot run (or phase 1's runs, under the two-phase
    law) once, then per controller its method's selection, phase 1's fit, or the closed-loop
    tuning with its confirmation."""
    nw = _Networks()
    network = c.cfg.network
    if c.two_phase:
        nw.schedule = c.setup.inertia_schedule(c.gains)
        # phase 1's payloads, kg: evenly up to the heaviest the design allows
        nw.conditions = torch.linspace(0.0, nw.schedule.high, network.conditions).tolist()
    confirm: ClosedLoopCost | None = None  # the tuning's scenarios at the evaluation's length
    for name in c.cfg.controllers:
        method = network_method(name)
        if method is None:
            continue
        if nw.pilot is None:
            nw.pilot = _pilot(c, nw)
        if c.two_phase:
            net = _static(c, nw, method)
            if method not in nw.bases:
                x, y = nw.pilot[0].double().cpu(), nw.pilot[1].double().cpu()
                nw.bases[method] = payload_basis(net, x, y, nw.conditions)
        elif network.objective == NetworkObjective.closed_loop and method in CLOSED_LOOP_SEARCHES:
            t_tune = time.perf_counter()
            twin = _static(c, nw, "kmeans")
            if nw.cost is None:  # the tuning's scenarios, and smc's reference errors on them
                c.stage("smc on the tuning scenarios")
                nw.cost = _closed_loop_cost(c, twin, nw.pilot)
            found = tune_network(method, nw.cost, network.tune, network.seed, network.aco.acor, progress=c.progress)
            c.stage(f"confirming {name}'s network at the evaluation's length")
            if confirm is None:  # the same scenarios, as long as the evaluation's episode
                confirm = _closed_loop_cost(c, twin, nw.pilot, full_length=True)
            nw.tuned[name] = confirmed(found, nw.cost, confirm)
            net = nw.tuned[name].net
            nw.tuning_seconds += time.perf_counter() - t_tune
        else:
            net = _static(c, nw, method)
        nw.made[name], nw.select_seconds[name] = net, net.seconds
    if c.two_phase and nw.made:
        _choose(c, nw)
    return nw


class LawSettings(NamedTuple):
    """The two-phase law's settings a comparison chooses per method (`_choose`): the joints it adds
    the network's predicted torque on (n,) 1 or 0 each, its payload estimate's step per control
    period (`gains.estimate_rate`) and the most its feedback may grow (`gains.feedback_growth`);
    under `control.network.feedforward=chosen`, the evidence for the joints: per joint (n,) the
    geometric mean over the tuning's scenarios of the RMS ratio with the network's torque to
    without it, at the chosen rate (below 1: the joint takes it; None where nothing was chosen)."""

    feedforward: torch.Tensor
    estimate_rate: float
    feedback_growth: float
    feedforward_ratio: torch.Tensor | None = None


class _Tried(NamedTuple):
    """A candidate's settings and its RMS error and share of periods at the torque limit (S, n) on
    the tuning's scenarios."""

    settings: LawSettings
    rms: torch.Tensor
    sat: torch.Tensor


def _choose(c: _Context, nw: _Networks) -> None:
    """The two-phase law's settings per method (`LawSettings`, into `nw.settings`), chosen in the
    closed loop on the tuning's scenarios (never the evaluation's) and one more, the heaviest of
    them carrying the heaviest payload the design allows (1.25 x the rated one), in two batched
    runs.

    First the payload estimate's rate, `gains.estimate_rate` times each of
    `control.network.estimate_rate_factors`, with the joints the network's torque is added on
    (`control.network.feedforward`: every joint (on), none (off), or (chosen), at each rate, per
    joint where the law with it tracks better than without it: the geometric mean over the
    scenarios of the RMS ratio below 1); then, at that rate and on those joints, the feedback's
    growth, `gains.feedback_growth` times each of `control.network.feedback_growth_factors`. Each
    time the cheapest candidate under the tuning's cost (`rbfn.control.tuning`: the mean over the
    scenarios of sum_j rms_j / rms_j(smc) + saturation_penalty sum_j sat_j) wins among those no
    joint of which is at its torque limit, in any scenario, for longer than `tune.saturation_limit`
    of the evaluation's episode (among all where none is), the first listed on a tie. A candidate whose run diverges is
    dropped and the rest run again (at its rate the other way of adding the torque takes every
    joint); a method none of whose candidates ran keeps the first rate and growth without the
    network's torque."""
    n, network, gains = c.setup.n, c.cfg.network, c.gains
    methods = sorted({cast(str, network_method(name)) for name in nw.made})
    rates = [gains.estimate_rate * f for f in network.estimate_rate_factors]
    growths = [gains.feedback_growth * f for f in network.feedback_growth_factors]
    fixed = torch.full((n,), 1.0 if network.feedforward == Feedforward.on else 0.0)
    masks = [torch.ones(n), torch.zeros(n)] if network.feedforward == Feedforward.chosen else [fixed]
    nw.settings = {m: LawSettings(fixed.clone(), rates[0], growths[0]) for m in methods}  # without a run
    if len(rates) == len(masks) == len(growths) == 1:
        return
    c.stage(
        f"choosing the two-phase law's settings: {len(rates)} estimate rates, {len(masks)} ways to feed "
        f"forward, {len(growths)} growths"
    )
    t0 = time.perf_counter()
    scenarios, sc, ref = _tuning_episode(c)
    assert nw.schedule is not None
    scenarios = scenarios.with_payload(nw.schedule.high)  # the settings must hold up to the design's bound
    ref = ref.to(**c.kw)
    features = _two_phase_features(c, nw, ref, methods)
    s = scenarios.payloads.shape[0]
    loop = None if c.real is None else replace(c.real, noise_envs=s, seed=scenarios.noise_seed)

    def run(laws: list[tuple[str, LawSettings]], smc: bool) -> tuple[dict[int, _Tried], torch.Tensor | None]:
        """Each law that ran, by its index in `laws`, and (`smc`) smc's RMS (S, n) beside them."""
        alive = list(range(len(laws)))
        while alive:
            ctrls = [_make(c, nw, ADAPTIVE + laws[i][0], features[laws[i][0]], None, laws[i][1]) for i in alive]
            ctrls = ([_make(c, nw, "smc")] if smc else []) + ctrls
            try:
                rms, sat = run_scenarios(
                    c.setup.plant, Stacked(ctrls, [s] * len(ctrls)), len(ctrls), scenarios, sc, ref, loop,
                    compile=c.cfg.compile, aot=c.aot,
                )  # fmt: skip
            except SimulationDiverged as e:
                if smc and e.environment < s:
                    raise  # smc itself
                alive.pop(e.environment // s - int(smc))
                continue
            k = int(smc)
            tried = {i: _Tried(laws[i][1], rms[k + j], sat[k + j]) for j, i in enumerate(alive)}
            return tried, (rms[0] if smc else None)
        return {}, None

    first = [(m, r, k) for m in methods for r in range(len(rates)) for k in range(len(masks))]
    tried, smc_rms = run([(m, LawSettings(masks[k], rates[r], growths[0])) for m, r, k in first], smc=True)
    if smc_rms is None:  # every candidate diverged: each method keeps the defaults above
        nw.choice_seconds = time.perf_counter() - t0
        return
    reference = smc_rms.clamp_min(1e-12)
    tune, scale = network.tune, sc.duration / c.cfg.duration

    chosen: dict[str, _Tried] = {}
    for m in methods:
        candidates = []
        for r, rate in enumerate(rates):
            ways = [tried[i] for i, law in enumerate(first) if law[:2] == (m, r) and i in tried]
            if len(ways) == 2:  # chosen: per joint, with it (the first) where it beats without it
                on, off = ways
                ratio = (on.rms / off.rms.clamp_min(1e-15)).log().mean(0).exp()
                keep = ratio < 1.0
                settings = LawSettings(keep.double(), rate, growths[0], ratio)
                ways = [_Tried(settings, torch.where(keep, on.rms, off.rms), torch.where(keep, on.sat, off.sat))]
            candidates += ways[:1]
        if candidates:
            chosen[m] = _cheapest(candidates, reference, tune, scale)
    second = [(m, chosen[m].settings._replace(feedback_growth=g)) for m in chosen for g in growths[1:]]
    # Compiled, as the first run's batch (smc beside, the last law repeated up to its count), so
    # that the first run's package serves it (its key holds the shapes, not the laws' settings):
    # on the UR5 a package is about 150 s to build, the repeats about 3 s a run.
    padded = second + second[-1:] * (len(first) - len(second)) if c.aot else second
    grown, _ = run(padded, smc=c.aot) if second else ({}, None)
    for m, t in chosen.items():
        others = [grown[i] for i, (name, _) in enumerate(second) if name == m and i in grown]  # not the repeats
        nw.settings[m] = _cheapest([t, *others], reference, tune, scale).settings
    nw.choice_seconds = time.perf_counter() - t0


def _cheapest(candidates: list[_Tried], reference: torch.Tensor, tune: TuneConfig, scale: float = 1.0) -> _Tried:
    """The candidate of least tuning cost (the mean over scenarios of sum_j rms_j / reference_j +
    saturation_penalty sum_j sat_j; `reference` (S, n) smc's RMS) among those no joint of which is
    at its torque limit for more than `tune.saturation_limit` of any scenario, its share of
    periods times `scale` (the tuning episode's length over the evaluation's: a transient's
    seconds at the limit as a share of the evaluation; among all, where none is within); the
    first on a tie."""
    cost = [float(tuning_cost(t.rms, t.sat, reference, tune.saturation_penalty)) for t in candidates]
    within = [i for i, t in enumerate(candidates) if float(t.sat.max()) * scale <= tune.saturation_limit]
    return candidates[min(within or range(len(candidates)), key=lambda i: cost[i])]


def _pilot(c: _Context, nw: _Networks) -> tuple[torch.Tensor, torch.Tensor]:
    """The residual torques the networks are chosen on: phase 1's calibration runs under the
    two-phase law (their seconds in `nw`), else the pilot run."""
    plant, scale, compile = c.setup.plant, c.factors.scale, c.cfg.compile
    if c.two_phase:
        c.stage(f"phase 1: {len(nw.conditions)} payload conditions")
        t_one = time.perf_counter()
        pilot = payload_residuals(
            plant, c.sc, c.ref, c.gains, c.model, nw.conditions, stride=PILOT_STRIDE, joint_scale=scale,
            compile=compile, aot=c.aot,
        )  # fmt: skip
        nw.phase_one_seconds = time.perf_counter() - t_one
        return pilot
    c.stage("the pilot run")
    return pilot_residuals(
        plant, c.sc, c.ref, c.gains, c.model, stride=PILOT_STRIDE, joint_scale=scale, compile=compile, aot=c.aot
    )


def _static(c: _Context, nw: _Networks, method: str) -> ControlNet:
    """The network `method` selects from the pilot run (once per method); under the two-phase law
    from phase 1's runs, fitting every condition's residual at once (each joint's in units of its
    torque gain factor)."""
    assert nw.pilot is not None
    if method not in nw.nets:
        network, scale = c.cfg.network, c.factors.scale
        aco = network.aco
        if network.objective != NetworkObjective.closed_loop:  # the colony's static objective
            aco = replace(aco, objective=Objective(str(network.objective)))
        y = nw.pilot[1].double().cpu()
        if c.two_phase:
            y = (y if scale is None else y / scale.double().cpu()).reshape(y.shape[0], -1)
        nw.nets[method] = control_network(
            method,
            nw.pilot[0].double().cpu(),
            y,
            m=network.num_centers,
            seed=network.seed,
            sample_dt=c.sc.dt * PILOT_STRIDE,
            aco=aco,
            warm_start=network.warm_start,
        )
    return nw.nets[method]


def _along(c: _Context, nw: _Networks, ref: Reference, b: int) -> Stacked:
    """Every controller along `ref`, stacked, each on b environments (an adaptive network's
    features are the reference's)."""
    controllers = []
    if nw.made and c.two_phase:
        phase_two = _two_phase_features(c, nw, ref, {cast(str, network_method(name)) for name in nw.made})
    elif nw.made:
        x = desired_states(ref)
    for name in c.cfg.controllers:
        features = w0 = settings = None
        if name in nw.made:
            net, method = nw.made[name], cast(str, network_method(name))
            if c.two_phase:
                features, settings = phase_two[method], nw.settings[method]
            else:
                features, w0 = net.features(x), net.w0
        controllers.append(_make(c, nw, name, features, w0, settings))
    return Stacked(controllers, [b] * len(controllers))


def _two_phase_features(c: _Context, nw: _Networks, ref: Reference, methods) -> dict[str, torch.Tensor]:
    """Per method, what the two-phase law is given along `ref` (`PayloadBasis.outputs`, (T, 3n)):
    the reference's desired states and the model's torque per kg computed once for every method."""
    x = desired_states(ref, acceleration=True).double().cpu()
    own = model_payload_torque(c.model, ref).double().cpu()
    return {m: nw.bases[m].outputs(nw.nets[m].features(x), own).to(**c.kw) for m in methods}


def _make(
    c: _Context,
    nw: _Networks,
    name: str,
    features: torch.Tensor | None = None,
    w0: torch.Tensor | None = None,
    settings: LawSettings | None = None,
):
    """Controller `name` as this comparison builds it: its gains, period, nominal model, factors
    and law, with an adaptive network's `features` along the reference, initial weights `w0` and
    the two-phase law's `settings` (None: the gains', the network's torque on every joint)."""
    gains = c.gains
    if settings is not None:
        gains = replace(gains, estimate_rate=settings.estimate_rate, feedback_growth=settings.feedback_growth)
    return make_controller(
        name,
        gains,
        c.period,
        model=c.model,
        features=features,
        w0=w0,
        observer=c.cfg.network.observer,
        joint_scale=c.factors.scale,
        plant=c.setup.plant,
        rates=c.factors.rates,
        law=str(c.cfg.network.law),
        schedule=nw.schedule,
        feedforward=None if settings is None else settings.feedforward.to(**c.kw),
        velocity_lag=c.velocity_lag,
    )


def _run_all(
    c: _Context, nw: _Networks, sc: Scenario, ref: Reference, payload: torch.Tensor, cases: list[str]
) -> tuple[Rollout, torch.Tensor, list[dict], float]:
    """Every controller on the `payload` cases (B,) kg named `cases`: (rollout, B = controllers x
    cases; the desired joints at its rows; metrics per environment; seconds)."""
    b, k, n = payload.shape[0], len(c.cfg.controllers), c.setup.n
    ctrl = _along(c, nw, ref, b)
    c.stage(f"simulating {k} controllers on {b} cases for {sc.duration:g} s")
    q0, qd0 = ref.q_d[:1].expand(b * k, n).clone(), ref.qd_d[:1].expand(b * k, n).clone()
    real_b = None if c.real is None else replace(c.real, noise_envs=b)  # every controller meets the same noise
    t0 = time.perf_counter()
    try:
        roll = simulate(
            c.setup.plant,
            ctrl,
            sc,
            ref,
            q0=q0,
            qd0=qd0,
            payload=payload.repeat(k),
            compile=c.cfg.compile,
            aot=c.aot,
            loop=real_b,
        )
    except SimulationDiverged as e:
        i, j = divmod(e.environment, b)
        case = cases[j] if cases[j] == PICK_AND_PLACE else f"payload {cases[j]}"
        raise SimulationDiverged(f"controller {c.cfg.controllers[i]}, {case}: {e}", e.environment) from None
    seconds = time.perf_counter() - t0
    q_des = ref.q_d if c.real is None else ref.q_d[:: c.real.substeps][: roll.t.shape[0]]  # at the rollout's rows
    return roll, q_des, control_metrics(roll, q_des, sc, c.limits), seconds


def _pick_and_place_run(c: _Context, nw: _Networks, runs: dict[str, ControlRun]) -> PickedAndPlaced:
    """The same controllers along a longer run of the same trajectory while the payload is picked
    and placed; its metrics join each run's as the case PICK_AND_PLACE."""
    pnp = c.cfg.pick_and_place
    long = replace(c.sc, duration=pnp.duration, carries=pick_and_place(pnp.duration, pnp.picks, pnp.seed))
    long.validate()
    ref_long = Reference(*c.setup.trajectory(long.times(torch.float64))).to(**c.kw)
    rated = torch.tensor([c.setup.rated_payload], **c.kw)
    roll_long, q_des_long, per_env, seconds = _run_all(c, nw, long, ref_long, rated, [PICK_AND_PLACE])
    for i, name in enumerate(c.cfg.controllers):
        runs[name].metrics[PICK_AND_PLACE] = per_env[i]
    carried = payload_schedule(long, long.steps + 1, rated, **c.kw)[:, 0]  # kg, every step and the end
    if c.real is not None:
        carried = carried[:: c.real.substeps][: roll_long.t.shape[0]]
    return PickedAndPlaced(roll_long, q_des_long, carried, long, c.setup.rated_payload, seconds)


def _closed_loop_cost(
    c: _Context, twin: ControlNet, pilot: tuple[torch.Tensor, torch.Tensor], full_length: bool = False
) -> ClosedLoopCost:
    """The closed-loop tuning's cost for this comparison: its own scenarios (`tuning_scenarios`,
    never the evaluation's payloads, disturbance frequency or noise seed) and episode (with
    `full_length`, as long as the evaluation's, its payload window: the confirmation), in the same
    loop, at the same gains, factors and adaptation rate, from the `twin`'s initial weights, with
    the `pilot` run's (inputs, residuals) as its warm start."""
    cfg, tune = c.cfg, c.cfg.network.tune
    like = pilot[0]
    scenarios, sc, ref = _tuning_episode(c, full_length)
    ref = ref.to(dtype=like.dtype, device=like.device)
    x, y = pilot[0].double().cpu(), pilot[1].double().cpu()
    return ClosedLoopCost(
        plant=c.setup.plant,
        model=c.model,
        gains=c.gains,
        twin=twin,
        scenarios=scenarios,
        scenario=sc,
        ref=ref,
        tune=tune,
        observer=cfg.network.observer,
        joint_scale=c.factors.scale,
        rates=c.factors.rates,
        loop=c.real,
        pilot=((x - twin.offset) / twin.scale, y) if cfg.network.warm_start else None,
        compile=cfg.compile,
        aot=ahead_of_time(cfg.aot, like.device, cfg.compile),
    )


def _tuning_episode(c: _Context, full_length: bool = False) -> tuple[TuneScenarios, Scenario, Reference]:
    """The closed-loop tuning's scenarios (`tuning_scenarios`: never the evaluation's payloads,
    disturbance frequency or noise seed), its episode (with `full_length`, as long as the
    evaluation's, its payload window; errors measured after its first 0.5 s, or in its second half
    if it is shorter than 1 s) and the desired trajectory along it (float64, CPU)."""
    cfg, setup, loop = c.cfg, c.setup, c.loop
    tune, plant = cfg.network.tune, setup.plant
    amplitude = [float(plant.dist)] * setup.n if isinstance(plant.dist, (int, float)) else list(plant.dist)
    scenarios = tuning_scenarios(
        tune,
        rated_payload=setup.rated_payload,
        disturbance=amplitude,
        eval_payloads=list(setup.payloads),
        eval_freq=cfg.disturbance_freq,
        eval_noise_seed=loop.noise_seed if loop is not None else 0,
    )
    duration, on, off = tune.episode(cfg.duration, cfg.payload_on, cfg.payload_off)
    if full_length:
        duration, on, off = cfg.duration, cfg.payload_on, cfg.payload_off
    sc = Scenario(duration, cfg.dt, cfg.integrator, on, off)
    sc = replace(sc, metrics_after=min(sc.metrics_after, duration / 2))  # an episode shorter than 1 s: its second half
    sc.validate()
    return scenarios, sc, Reference(*setup.trajectory(sc.times(torch.float64)))


def gap_closure(smc: dict, run: dict, exact: dict) -> list[float]:
    """Per joint, the share of the gap between `smc` and the perfect-knowledge `smc_exact` that a
    run closes: (rms_smc - rms) / (rms_smc - rms_exact); 1 reaches the ceiling, 0 is no better than
    smc, negative is worse. NaN where smc is already at the ceiling (no gap to close)."""
    out = []
    for s, c, e in zip(smc["rms_err"], run["rms_err"], exact["rms_err"]):
        gap = s - e
        out.append((s - c) / gap if gap > 0 else float("nan"))
    return out
