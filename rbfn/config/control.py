"""The closed loop's schemas (evaluate.py's `control` part): the gains, the adaptive network and
the one list of its methods (`NETWORK_METHODS`), its closed-loop tuning, the pick-and-place run
and the scenario. The loop's sensing and actuation: `rbfn.config.loop`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple, Optional

from .base import Choice, Dtype, _check_aot, _need, _seed, finite
from .training import ACOConfig, Colony, Method, Objective


class NetworkObjective(Choice):  # what the adaptive controller's centre search minimises
    closed_loop = "closed_loop"
    fit = "fit"
    cluster = "cluster"


class NetworkLaw(Choice):  # how the adaptive controller's network learns (rbfn.control.controllers)
    two_phase = "two_phase"
    tracking = "tracking"


class Feedforward(Choice):  # the joints the two-phase law feeds the network's predicted torque forward on
    chosen = "chosen"
    on = "on"
    off = "off"


class Integrator(Choice):
    rk4 = "rk4"
    euler = "euler"  # semi-implicit


class Friction(Choice):
    sign = "sign"
    smooth = "smooth"  # tanh(qd / 0.01)


class Robust(Choice):
    sign = "sign"
    sat = "sat"


class Trajectory(Choice):  # the desired joint path of the closed loop
    paper = "paper"
    sinusoid = "sinusoid"


# The controllers by name, with what each is (docs/control.md's table); the adaptive RBFN is
# ADAPTIVE + one of NETWORK_METHODS (arbfn_aco, ...). `rbfn.control.controllers` builds each.
BASE_CONTROLLERS: dict[str, str] = {
    "pd": "PD on the joint error, Kp e + Kd de (no model)",
    "ctc": "computed torque on the nominal model",
    "smc": "sliding mode: M_hat qr'' + C_hat qr' + G_hat + K s + epsilon sgn(s), s = de + Lambda e",
    "smc_obs": "`smc` + a generalized-momentum disturbance observer",
    "smc_exact": "the perfect-knowledge ceiling: `smc`'s feedback with every force known exactly",
}
ADAPTIVE = "arbfn_"


class NetworkMethod(NamedTuple):
    """One way to choose the adaptive network's centres and widths, the controller arbfn_<name>.

    `selector`: the selector (`Method`, `rbfn.select.select`) it runs on the pilot run's or phase
    1's fit; None where it has its own (`grid`).
    `cluster`: the colony on k-means' objective instead of the fit. `searches`: it searches the
    closed loop itself under control.network.objective=closed_loop (`rbfn.control.tuning`, which
    implements each such search). `what`: one line for messages and the docs."""

    selector: Method | None
    cluster: bool
    searches: bool
    what: str


# The one list of network methods: the config's allowed names, the dispatch (rbfn.control.network,
# rbfn.control.tuning) and the docs' table come from it.
NETWORK_METHODS: dict[str, NetworkMethod] = {
    "aco": NetworkMethod(Method.aco, False, True, "ACO_R on the fit; on the closed loop under objective=closed_loop"),
    "aco_cluster": NetworkMethod(Method.aco, True, False, "ACO_R on k-means' objective"),
    "kmeans": NetworkMethod(Method.kmeans, False, False, "k-means: the twin the closed-loop searches start from"),
    "random": NetworkMethod(Method.random, False, True, "random centres; random search on the closed loop"),
    "grid": NetworkMethod(None, False, False, "centres evenly along one period of the reference"),
    "cmaes": NetworkMethod(
        Method.cmaes,
        False,
        True,
        "CMA-ES (the cmaes package) on the fit; on the closed loop under objective=closed_loop",
    ),
}
CONTROL_CENTER_METHODS = tuple(NETWORK_METHODS)
# The searches that tune the network on the closed loop itself (control.network.objective=closed_loop).
CLOSED_LOOP_SEARCHES = tuple(name for name, m in NETWORK_METHODS.items() if m.searches)


def network_method(controller: str) -> str | None:
    """The network method of an adaptive controller's name (arbfn_kmeans -> kmeans); None for any
    other controller. The one place the prefix is read."""
    return controller[len(ADAPTIVE) :] if controller.startswith(ADAPTIVE) else None


PILOT_STRIDE = 10  # the control network's pilot run is sampled every 10 control periods


@dataclass
class GainsConfig:
    """Feedback and adaptation gains shared by every controller of a comparison (group `gains`: the
    robot's `paper` or `tuned` set, conf/gains/robot/<robot>_<set>.yaml). The torque gains K,
    epsilon, pd_kp, pd_kd and gamma act on joint j times `control.joint_scale` s_j (1 on the SCARA)."""

    K: float = 50.0  # N m s / rad (N s / m): s feedback
    Lambda: float = 20.0  # 1/s: sliding-surface slope
    epsilon: float = 0.05  # N m (N): robust term amplitude
    robust: Robust = Robust.sat  # sign | sat
    boundary: float = 0.01  # rad/s (m/s): saturation boundary layer width of sat(s / boundary)
    observer_gain: float = 1000.0  # 1/s: momentum-observer bandwidth
    gamma: float = 500.0  # adaptation rate Gamma of dW/dt = Gamma h s^T (alpha = gamma dt)
    gamma_decay: float = 1e9  # s: Gamma(t) = gamma / (1 + t / gamma_decay)
    leakage: float = 0.0  # 1/s: sigma-modification
    pd_kp: float = 0.0  # PD gains; 0: K Lambda and K, the same feedback as smc's K s
    pd_kd: float = 0.0
    dead_zone: float = 0.0  # rad/s (m/s) per joint: the adaptation ignores |s| below it (measurement noise)
    # The two-phase law (control.network.law=two_phase, rbfn.control.controllers.TwoPhase): its
    # estimator's momentum observer, 1/s, and the payload estimate's normalised LMS step per control period.
    estimator_gain: float = 30.0
    estimate_rate: float = 0.05
    # the two-phase law: the most by which a joint's feedback gain K grows with the inertia the
    # estimated payload adds (1: fixed gains)
    feedback_growth: float = 1.5
    nominal_payload: float = 0.0  # kg: the payload the nominal model carries (0: the unloaded robot, the paper's)
    # The nominal model's factors, M_hat = model_inertia M, C_hat = model_coriolis C, G_hat = model_gravity G:
    # the paper's 0.9, 0.8 and 0.85 (its controller knows the robot to within 10-20 %).
    model_inertia: float = 0.9
    model_coriolis: float = 0.8
    model_gravity: float = 0.85
    # Per joint j, for the robot's rated payload (robot.rated_payload): the observer no faster than
    # the feedback's bandwidth K s_j / M_hat_jj and the adaptation rate divided by M_hat_jj's growth,
    # M_hat_jj at home carrying the rated payload (rbfn.control.robot_setup.ControlRobot.joint_rates).
    # The realistic sets' choice: their integrators stay stable whatever the arm carries.
    inertia_scaling: bool = False
    # deg; 0: off. The realistic loop: each joint's torque gains capped so that its feedback's
    # crossover K s_j / Me_jj (Me_jj the joint's apparent inertia at home, 1 / (M_hat^-1)_jj) keeps
    # this phase margin against the loop's delays, hold and velocity filter
    # (rbfn.control.loop.crossover_limit, ControlRobot.feedback_scale). The realistic sets: 30.
    phase_margin: float = 0.0

    def check(self, key: str = "gains") -> None:
        for k, v in vars(self).items():
            if isinstance(v, float):
                _need(math.isfinite(v), f"{key}.{k}", v, "must be finite")
        for k in ("K", "Lambda", "boundary", "observer_gain", "gamma_decay", "model_inertia", "estimator_gain"):
            _need(getattr(self, k) > 0, f"{key}.{k}", getattr(self, k), "must be > 0")
        for k in ("epsilon", "gamma", "leakage", "pd_kp", "pd_kd", "dead_zone", "nominal_payload"):
            _need(getattr(self, k) >= 0, f"{key}.{k}", getattr(self, k), "must be >= 0")
        for k in ("model_coriolis", "model_gravity"):
            _need(getattr(self, k) >= 0, f"{key}.{k}", getattr(self, k), "must be >= 0")
        _need(0 <= self.phase_margin < 90, f"{key}.phase_margin", self.phase_margin, "must be in [0, 90) degrees")
        _need(0 < self.estimate_rate <= 1, f"{key}.estimate_rate", self.estimate_rate, "must be in (0, 1]")
        _need(self.feedback_growth >= 1, f"{key}.feedback_growth", self.feedback_growth, "must be >= 1")


@dataclass
class TuneConfig:
    """The closed-loop search (`control.network.objective=closed_loop`, rbfn.control.tuning): its own
    scenarios, drawn (seeded) from these ranges and never evaluate.py's own cases, and its budget,
    the same for every search (arbfn_aco, arbfn_random, arbfn_cmaes): `iterations` batches of
    `population` candidates, each run on every scenario (population x iterations x scenarios
    closed-loop episodes). Ranges are [low, high]; times in s."""

    scenarios: int = 4  # payload, disturbance and noise draws, each one episode per candidate
    # s, each episode, shorter than control.duration; null: min(6 s, 0.6 control.duration)
    duration: Optional[float] = None
    # s, the payload window inside the episode; null: the evaluation's (1 to 4 s by default), scaled by
    # duration / control.duration where it does not fit (with 3 s episodes and a 1.5 s window the tuned
    # networks did worse held out than with 6 s and the evaluation's 3 s)
    payload_on: Optional[float] = None
    payload_off: Optional[float] = None
    payload: list[float] = field(default_factory=lambda: [0.0, 1.0])  # fractions of robot.rated_payload
    disturbance: list[float] = field(default_factory=lambda: [0.5, 1.5])  # factors of control.disturbance
    disturbance_freq: list[float] = field(default_factory=lambda: [1.0, 4.0])  # rad/s
    disturbance_phase: list[float] = field(default_factory=lambda: [0.0, 2 * math.pi])  # rad
    seed: int = 1  # the scenario draws (the sensor-noise seed among them)
    population: int = 16  # candidates per iteration (ants, CMA-ES's population, random draws)
    iterations: int = 16
    spread: float = 0.3  # the first candidates' spread around the k-means twin (offsets, log-widths)
    max_offset: float = 1.0  # a centre moves at most this far per coordinate (standardised units)
    max_width_factor: float = 4.0  # each log-width factor and the common one within [1 / factor, factor]
    saturation_penalty: float = 1.0  # cost per joint-share of time at the torque limit (realistic loop)
    # the two-phase law's choice (control.network.estimate_rate_factors, ...) takes no candidate a joint
    # of which is at its torque limit, in any scenario, for longer than this share of the evaluation's
    # episode (control.duration; a payload's arrival and removal saturate for about as long in either
    # episode), where another candidate stays within it
    saturation_limit: float = 0.01

    def episode(self, duration: float, payload_on: float, payload_off: float) -> tuple[float, float, float]:
        """(episode, payload on, payload off) in s for an evaluation of `duration` s whose payload
        window is [payload_on, payload_off]: the configured values, or where null the derived ones."""
        d = self.duration if self.duration is not None else min(6.0, 0.6 * duration)
        on, off = (
            (payload_on, payload_off) if payload_off <= d else (payload_on * d / duration, payload_off * d / duration)
        )
        return (
            d,
            on if self.payload_on is None else self.payload_on,
            off if self.payload_off is None else self.payload_off,
        )

    def check(self, key: str, duration: float, window: tuple[float, float] = (1.0, 4.0)) -> None:
        """`duration`: control.duration, the evaluation's episode (s); `window`: its payload window (s)."""
        _need(self.scenarios >= 1, f"{key}.scenarios", self.scenarios, "must be >= 1")
        for k in ("duration", "payload_on", "payload_off"):
            v = getattr(self, k)
            _need(v is None or finite(v), f"{key}.{k}", v, "must be a finite number of seconds or null (derived)")
        d, on, off = self.episode(duration, *window)
        _need(
            0 < d < duration,
            f"{key}.duration",
            self.duration if self.duration is not None else f"null (derived: {d:g})",
            f"must be > 0 s (errors are measured after 0.5 s, or over the second half of an episode shorter "
            f"than 1 s) and shorter than control.duration={duration}",
        )
        _need(
            0 <= on < off <= d,
            f"{key}.payload_on/payload_off",
            [on, off],
            f"need 0 <= payload_on < payload_off <= the episode, {key}.duration={d:g}",
        )
        for k, low in (("payload", 0.0), ("disturbance", 0.0), ("disturbance_freq", 0.0), ("disturbance_phase", None)):
            v = list(getattr(self, k))
            _need(
                len(v) == 2 and all(finite(x) for x in v) and v[0] <= v[1] and (low is None or v[0] >= low),
                f"{key}.{k}",
                v,
                "a range [low, high] of finite numbers, low <= high" + ("" if low is None else f", low >= {low:g}"),
            )
        _seed(f"{key}.seed", self.seed)
        _need(self.population >= 2, f"{key}.population", self.population, "must be >= 2 (ACO_R's archive)")
        _need(self.iterations >= 1, f"{key}.iterations", self.iterations, "must be >= 1")
        for k in ("spread", "max_offset"):
            _need(finite(getattr(self, k)) and getattr(self, k) > 0, f"{key}.{k}", getattr(self, k), "must be > 0")
        _need(
            finite(self.max_width_factor) and self.max_width_factor >= 1,
            f"{key}.max_width_factor",
            self.max_width_factor,
            "must be >= 1",
        )
        _need(
            finite(self.saturation_penalty) and self.saturation_penalty >= 0,
            f"{key}.saturation_penalty",
            self.saturation_penalty,
            "must be >= 0",
        )
        _need(
            finite(self.saturation_limit) and 0 <= self.saturation_limit <= 1,
            f"{key}.saturation_limit",
            self.saturation_limit,
            "must be a share of periods in [0, 1]",
        )


@dataclass
class NetworkConfig:
    """The adaptive controller's RBF network (controllers arbfn_<method>). `objective`: what
    arbfn_aco's colony minimises: `closed_loop`, the tracking error of the adapted network on
    `tune`'s scenarios (arbfn_random and arbfn_cmaes search the same at the same budget); `fit`, the
    pilot run's residual torque, or phase 1's at every payload (arbfn_random: random centres);
    `cluster`, k-means' objective. `law` and `objective` null: derived by `resolved`."""

    num_centers: int = 25
    observer: bool = True  # combine the network with the momentum observer
    warm_start: bool = False  # start W at the ridge fit of the pilot run's residual torque
    seed: int = 0
    objective: Optional[NetworkObjective] = None  # null: closed_loop under the tracking law, else fit
    # two_phase: a basis fitted offline to the residual at `conditions` payloads from 0 to 1.25x the
    # rated one, then only the payload's coordinate adapts online (TwoPhase); tracking: the paper's
    # dW/dt = Gamma h s^T from zero weights; null: two_phase in the realistic loop, tracking in the
    # ideal one or where objective is closed_loop
    law: Optional[NetworkLaw] = None
    conditions: int = 6
    # two_phase: the joints on which the law adds the network's predicted torque. chosen: per joint,
    # whichever of on and off tracks better in the closed loop on `tune`'s scenarios (never the
    # evaluation's); on: every joint; off: none (the network then only estimates the payload)
    feedforward: Feedforward = Feedforward.chosen
    # two_phase: compare the measured velocity with the reference's as the realistic loop measures it
    # (qd_d - lag qdd_d, the lag of its backward difference and velocity filter); false: with qd_d
    lag_compensation: bool = True
    # two_phase: the payload estimate's rates tried, factors of gains.estimate_rate (each in (0, 1]),
    # then the feedback's growths, factors of gains.feedback_growth (each >= 1 / gains.feedback_growth);
    # with more than one, the cheapest in the closed loop on `tune`'s scenarios under the tuning's
    # cost (never the evaluation's); one: that value, no run. A payload heavy against the arm wants a
    # fast estimate and more growth, a light one a quiet estimate (a disturbance leaks into it)
    estimate_rate_factors: list[float] = field(default_factory=lambda: [1.0, 0.3, 0.1, 0.03])
    feedback_growth_factors: list[float] = field(default_factory=lambda: [1.0, 1.5, 2.0])
    aco: ACOConfig = field(default_factory=ACOConfig)
    tune: TuneConfig = field(default_factory=TuneConfig)

    def resolved(self, realistic: bool) -> NetworkConfig:
        """This config with a null `law` and `objective` derived, for the realistic loop or (not
        `realistic`) the ideal one. The law: `tracking` where the objective is `closed_loop` (the
        tuning searches that law's network) or the loop is ideal (there `smc_obs` alone reaches the
        perfect-knowledge ceiling, and the two-phase law's observer, which carries the estimate,
        does not: docs/control.md), else `two_phase`. The objective: `closed_loop` under the
        tracking law, `fit` under the two-phase one."""
        law = self.law
        if law is None:
            tracking = self.objective == NetworkObjective.closed_loop or not realistic
            law = NetworkLaw.tracking if tracking else NetworkLaw.two_phase
        objective = self.objective
        if objective is None:
            objective = NetworkObjective.closed_loop if law == NetworkLaw.tracking else NetworkObjective.fit
        return replace(self, law=law, objective=objective)

    def check(
        self,
        key: str = "control.network",
        duration: float = 10.0,
        controllers: tuple = (),
        window: tuple[float, float] = (1.0, 4.0),
        realistic: bool = True,
    ) -> None:
        """`duration`: control.duration (s); `controllers`: control.controllers; `window`: control's
        payload window (s); `realistic`: the loop is the realistic one (`resolved`)."""
        if self.law is None or self.objective is None:
            self.resolved(realistic).check(key, duration, controllers, window, realistic)
            return
        _need(self.num_centers >= 1, f"{key}.num_centers", self.num_centers, "must be >= 1")
        _need(self.conditions >= 2, f"{key}.conditions", self.conditions, "must be >= 2 (a direction needs two)")
        _seed(f"{key}.seed", self.seed)
        factors = list(self.estimate_rate_factors)
        _need(
            len(factors) >= 1 and all(finite(f) and 0 < f <= 1 for f in factors),
            f"{key}.estimate_rate_factors",
            factors,
            "a non-empty list of factors of gains.estimate_rate, each in (0, 1]",
        )
        growths = list(self.feedback_growth_factors)
        _need(
            len(growths) >= 1 and all(finite(f) and f > 0 for f in growths),
            f"{key}.feedback_growth_factors",
            growths,
            "a non-empty list of positive factors of gains.feedback_growth (each growth must stay >= 1)",
        )
        if self.law == NetworkLaw.two_phase:
            _need(
                self.objective != NetworkObjective.closed_loop,
                f"{key}.objective",
                str(self.objective),
                f"the closed-loop tuning searches the tracking law's network: with {key}.law=two_phase "
                "choose fit (phase 1's fit at every payload) or cluster",
            )
        self.aco.check(f"{key}.aco", self.num_centers if self.aco.colony == Colony.ant_system else 1)
        _need(
            self.aco.objective == Objective.fit,
            f"{key}.aco.objective",
            str(self.aco.objective),
            f"the control network's objective is {key}.objective (closed_loop, fit or cluster); leave this at fit",
        )
        if self.objective != NetworkObjective.closed_loop:
            if self.law == NetworkLaw.two_phase and any(network_method(name) for name in controllers):
                self.tune.check(f"{key}.tune", duration, window)  # the law's settings are chosen on its scenarios
            return
        if "arbfn_aco" in controllers:
            _need(
                self.aco.colony == Colony.acor,
                f"{key}.aco.colony",
                str(self.aco.colony),
                f"the closed_loop objective searches continuous offsets with acor; or set {key}.objective=fit",
            )
        if any(network_method(name) in CLOSED_LOOP_SEARCHES for name in controllers):
            self.tune.check(f"{key}.tune", duration, window)


@dataclass
class PickAndPlaceConfig:
    """A long run beside the payload cases, every controller along the same trajectory: the payload
    is picked up and put down `picks` times, its masses drawn between none and robot.rated_payload
    (`rbfn.control.simulator.pick_and_place`); metrics.json's case `pick_and_place`."""

    picks: int = 0  # 0: no such run
    duration: float = 60.0  # s
    seed: int = 0  # draws the masses

    def check(self, key: str, dt: float) -> None:
        _need(self.picks >= 0, f"{key}.picks", self.picks, "must be >= 0 (0: no pick-and-place run)")
        _need(
            finite(self.duration) and self.duration >= 1.0 + 10 * dt * max(self.picks, 1),
            f"{key}.duration",
            self.duration,
            f"must be finite, the first pick is at 1 s, and each of the {key}.picks={self.picks} cycles needs "
            f"10 steps of dt={dt} s",
        )


@dataclass
class ControlConfig:
    """The closed-loop scenario of evaluate.py (times in s, masses in kg), for the robot `robot`.

    Per joint j the plant feels friction viscous s_j qd + coulomb s_j sign(qd) and the disturbance
    disturbance s_j sin(disturbance_freq t), and the torque gains (K, epsilon, pd_kp, pd_kd, gamma)
    act as gain * s_j, where s = `joint_scale`: empty derives it, 1 on every joint of the SCARA (the
    paper's numbers are its own) and the unloaded inertia diagonal M_jj(home) in kg m^2 (kg) of any
    other arm, whose joints span orders of magnitude (UR5: 2.4 kg m^2 shoulder, 3.4e-4 wrist 3).
    """

    enabled: bool = True
    controllers: list[str] = field(default_factory=lambda: ["pd", "ctc", "smc", "smc_obs", "arbfn_aco", "arbfn_kmeans"])
    trajectory: Optional[Trajectory] = None  # the desired joints; null: the robot's own (its closed form's,
    # `paper` for the SCARA), else `sinusoid`
    amplitude: float = 0.1  # sinusoid: amplitude per joint, a fraction of half its box range, about
    # robot.home
    payloads: list[float] = field(default_factory=list)  # kg; empty: 0, half and all of robot.rated_payload
    payload_link: str = ""  # the link whose origin carries the payload; empty: robot.end_link
    duration: float = 10.0
    dt: float = 1e-3
    integrator: Integrator = Integrator.rk4
    payload_on: float = 1.0
    payload_off: float = 4.0
    friction: Friction = Friction.sign
    viscous: float = 12.0  # N m s/rad (N s/m) per unit joint scale
    coulomb: float = 0.2  # N m (N) per unit joint scale
    disturbance: float = 5.0  # N m (N) per unit joint scale
    disturbance_freq: float = 2.0  # rad/s
    joint_scale: list[float] = field(default_factory=list)  # per joint; empty: derived (see above)
    dtype: Dtype = Dtype.float64
    compile: bool = False  # torch.compile the fused step, either loop (slow to compile; for long runs)
    # The step compiled ahead of time, either loop, cached on disk (a minute or two once per
    # configuration): auto (compiled on a CPU unless $ACO_RBFN_AOT says 0, eager on CUDA), true, false
    aot: str = "auto"
    pick_and_place: PickAndPlaceConfig = field(default_factory=PickAndPlaceConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)

    def check(self, key: str = "control", realistic: bool = True) -> None:
        """`realistic`: the loop is the realistic one (what a null control.network.law means)."""
        self._check_controllers(key)
        self._check_scenario(key)
        self.pick_and_place.check(f"{key}.pick_and_place", self.dt)
        self._check_network(key, realistic)

    def _check_controllers(self, key: str) -> None:
        """The controllers' names, once each, and how their loop is compiled."""
        arbfn = [ADAPTIVE + m for m in NETWORK_METHODS]
        for name in self.controllers:
            _need(
                name in BASE_CONTROLLERS or name in arbfn,
                f"{key}.controllers",
                name,
                f"choose from {[*BASE_CONTROLLERS, *arbfn]}",
            )
        _need(
            len(set(self.controllers)) == len(self.controllers),
            f"{key}.controllers",
            list(self.controllers),
            "each controller may appear once",
        )
        _check_aot(self.aot, f"{key}.aot")
        _need(
            not (self.compile and str(self.aot).lower() == "true"),
            f"{key}.aot",
            self.aot,
            f"choose one of {key}.compile and {key}.aot",
        )

    def _check_scenario(self, key: str) -> None:
        """The scenario: its trajectory's amplitude, time step and length, payload window and cases,
        friction and disturbance, and joint scale."""
        _need(
            finite(self.amplitude) and 0 <= self.amplitude <= 1, f"{key}.amplitude", self.amplitude, "must be in [0, 1]"
        )
        _need(finite(self.dt) and self.dt > 0, f"{key}.dt", self.dt, "must be a positive number of seconds")
        _need(
            finite(self.duration) and self.duration >= self.dt,
            f"{key}.duration",
            self.duration,
            f"must be finite and >= {key}.dt={self.dt}",
        )
        _need(
            finite(self.payload_on)
            and finite(self.payload_off)
            and 0 <= self.payload_on < self.payload_off <= self.duration,
            f"{key}.payload_on/payload_off",
            [self.payload_on, self.payload_off],
            f"need 0 <= payload_on < payload_off <= {key}.duration={self.duration}",
        )
        _need(
            0.5 < self.duration, f"{key}.duration", self.duration, "must exceed 0.5 s (errors are measured after 0.5 s)"
        )
        _need(
            all(finite(p) and p >= 0 for p in self.payloads),
            f"{key}.payloads",
            list(self.payloads),
            "a list of masses >= 0 kg (empty: 0, half and all of robot.rated_payload)",
        )
        _need(
            len(set(self.payloads)) == len(self.payloads),
            f"{key}.payloads",
            list(self.payloads),
            "each payload case may appear once (cases are keyed by mass)",
        )
        for k in ("viscous", "coulomb", "disturbance", "disturbance_freq"):
            _need(
                finite(getattr(self, k)) and getattr(self, k) >= 0,
                f"{key}.{k}",
                getattr(self, k),
                "must be finite and >= 0",
            )
        _need(
            all(finite(v) and v > 0 for v in self.joint_scale),
            f"{key}.joint_scale",
            list(self.joint_scale),
            "positive finite factors, one per joint (empty: derived from the robot)",
        )

    def _check_network(self, key: str, realistic: bool) -> None:
        """The adaptive network's settings, where an adaptive controller runs: its size against the
        pilot run's samples, then `NetworkConfig.check`."""
        n = self.network
        _need(n.num_centers >= 1, f"{key}.network.num_centers", n.num_centers, "must be >= 1")
        if any(network_method(name) for name in self.controllers):
            steps = int(round(self.duration / self.dt))
            n_train = (steps // PILOT_STRIDE + 1) // 2  # even pilot samples train the network
            _need(
                n.num_centers <= n_train,
                f"{key}.network.num_centers",
                n.num_centers,
                f"exceeds the pilot run's {n_train} training samples ({key}.duration={self.duration} s, "
                f"one sample per {PILOT_STRIDE} periods, half of them for training)",
            )
            n.check(
                f"{key}.network",
                self.duration,
                tuple(self.controllers),
                (self.payload_on, self.payload_off),
                realistic,
            )
