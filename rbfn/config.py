"""Every configuration schema and every allowed name, in one place; validation done once at the edge.

This module is the bottom layer of the package: it imports nothing from `rbfn`. train.py and
evaluate.py register the schemas with Hydra's ConfigStore (`register_configs`), so a mistyped
value or an unknown choice (an Enum field) fails when the config is composed, naming the options.
Each schema's `check` method sits beside its fields and raises ValueError naming the full key, the
bad value and what is allowed; `validate_train` / `validate_evaluate` run them once, before any
work starts. Schemas follow the concerns: the robot; the data; the centres (one schema per colony,
one per refinement mode); the network; and, for evaluation, the gains, the closed-loop scenario
and the online part.
"""

from __future__ import annotations

import json
import math
import os
import typing
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from enum import Enum
from typing import Any, Optional

__all__ = [
    "Choice",
    "Method",
    "Colony",
    "Objective",
    "WidthRule",
    "WidthSearch",
    "RefineMode",
    "RefineLoss",
    "Solver",
    "InputScaling",
    "Integrator",
    "Friction",
    "Dtype",
    "Robust",
    "PathName",
    "Learner",
    "Target",
    "Trajectory",
    "Workspace",
    "SELECTORS",
    "BASE_CONTROLLERS",
    "CONTROL_CENTER_METHODS",
    "CLOSED_LOOP_SEARCHES",
    "MAX_SEED",
    "ROBOT_PRESETS",
    "RobotConfig",
    "DataConfig",
    "ACORConfig",
    "AntSystemConfig",
    "ACOConfig",
    "OLSConfig",
    "FullRefineConfig",
    "MinibatchRefineConfig",
    "RefineConfig",
    "CentersConfig",
    "GrowthConfig",
    "RBFNConfig",
    "TrainConfig",
    "GainsConfig",
    "NetworkConfig",
    "NetworkObjective",
    "NetworkLaw",
    "TuneConfig",
    "ControlConfig",
    "PickAndPlaceConfig",
    "OnlineConfig",
    "LoopConfig",
    "EvalConfig",
    "validate_train",
    "validate_evaluate",
    "check_types",
    "check_overrides",
    "validate_device",
    "finite",
    "plain",
    "register_configs",
]


class Choice(str, Enum):
    """A named option: compares, hashes, prints and serialises as its plain string."""

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


# Named options as classes. Member names equal their values, so Hydra overrides use the plain
# words ("global" too).
class Method(Choice):
    aco = "aco"
    kmeans = "kmeans"
    random = "random"
    ols = "ols"


class Colony(Choice):
    acor = "acor"
    ant_system = "ant_system"


class Objective(Choice):
    fit = "fit"
    cluster = "cluster"


class NetworkObjective(Choice):  # what the adaptive controller's centre search minimises
    closed_loop = "closed_loop"
    fit = "fit"
    cluster = "cluster"


class NetworkLaw(Choice):  # how the adaptive controller's network learns (rbfn.control.controllers)
    two_phase = "two_phase"
    tracking = "tracking"


class WidthRule(Choice):
    paper = "paper"
    vars()["global"] = "global"  # a keyword, so set through the class namespace
    per_center = "per_center"


class WidthSearch(Choice):
    per_center = "per_center"
    scale = "scale"
    none = "none"


class RefineMode(Choice):
    auto = "auto"  # full where N P^2 <= 2e9
    full = "full"
    minibatch = "minibatch"


class RefineLoss(Choice):  # minibatch: the error J(q) dq, or dq itself
    task = "task"
    joint = "joint"


class Solver(Choice):
    lstsq = "lstsq"
    lms = "lms"


class InputScaling(Choice):
    metres = "metres"
    standard = "standard"


class Integrator(Choice):
    rk4 = "rk4"
    euler = "euler"  # semi-implicit


class Friction(Choice):
    sign = "sign"
    smooth = "smooth"  # tanh(qd / 0.01)


class Dtype(Choice):
    float64 = "float64"
    float32 = "float32"


class Robust(Choice):
    sign = "sign"
    sat = "sat"


class PathName(Choice):
    paper = "paper"
    circle = "circle"
    figure8 = "figure8"
    sinusoid = "sinusoid"


class Learner(Choice):
    nlms = "nlms"
    rls = "rls"


class Target(Choice):  # IK input
    position = "position"  # (B, 3) m
    pose = "pose"  # (B, 7) m + quaternion


class Workspace(Choice):  # where the IK answers
    box = "box"  # one branch, joints inside robot.joint_low..joint_high (one network, rbfn.layer)
    full = "full"  # every pose within the URDF limits, every branch (charts of joint space, rbfn.charts)


class Trajectory(Choice):  # the desired joint path of the closed loop
    paper = "paper"
    sinusoid = "sinusoid"


# Presets of the `centers` group (conf/centers/NAME.yaml); a label, recorded with every run.
SELECTORS = ("aco", "aco_paper", "kmeans", "kmeans_refine", "random", "ols")
# Controllers by name; the adaptive RBFN is arbfn_<one of CONTROL_CENTER_METHODS>.
BASE_CONTROLLERS = ("pd", "ctc", "smc", "smc_obs", "smc_exact")
CONTROL_CENTER_METHODS = ("aco", "aco_cluster", "kmeans", "random", "grid", "cmaes")
# The searches that tune the network on the closed loop itself (control.network.objective=closed_loop).
CLOSED_LOOP_SEARCHES = ("aco", "random", "cmaes")
# The packaged robots: folders rbfn/robots/NAME/ (NAME.urdf, optional closed forms), presets
# conf/robot/NAME.yaml (tests/robots/test_registry.py checks that the three lists agree).
ROBOT_PRESETS = ("scara", "ur5", "panda")
# Seeds feed scikit-learn's random_state (< 2**32) and derive data streams seed * 1000 + k.
MAX_SEED = 2**32 - 1
# Useful widths, as multiples of a width rule's base (the paper's d_max / sqrt(2M), or the mean
# distance to the nearest centres): validation chooses among 0.25 .. 64 (rbfn.widths.SCALE_GRID).
# Below 1/16, a Gaussian is exp(-128) ~ 3e-56 half-way to the next centre: the network is its bias
# alone between centres (and float32 features underflow to zero).
MIN_WIDTH_SCALE = 1.0 / 16.0
MAX_WIDTH_SCALE = 1024.0
PILOT_STRIDE = 10  # the control network's pilot run is sampled every 10 control periods


# ----------------------------------------------------------------------------------------- train
@dataclass
class RobotConfig:
    """The robot (group `robot`: scara, ur5, panda; or `urdf`, any serial URDF with `urdf` and `end_link`):
    its chain, the box of joints its IK answers in and the kind of target, and its physical facts.
    The defaults are the SCARA's preset, conf/robot/scara.yaml, but for gravity (null: the
    preset's) and home (empty: the box centre; the SCARA's paper trajectory has none).
    With `derive` (robot=urdf, conf/robot/urdf.yaml) the keys left at its markers (name "",
    target null, joint_low/joint_high/home/encoder_counts empty, gravity/control_rate null,
    rated_payload < 0) are derived from the URDF by `rbfn.robots.derive.derive_robot`, which
    train.py and evaluate.py call first; given keys win.

    Joint values are in the URDF's units (rad, or m for prismatic joints), in the URDF's joint
    order along the chain root -> end link, `locked` joints excluded from the box and the IK output.
    """

    name: str = "scara"  # the preset's label; with `urdf` empty, its packaged URDF
    urdf: str = ""  # a URDF file; empty: the packaged URDF of `name`
    end_link: str = "quill"
    target: Optional[Target] = Target.position  # position (B, 3) | pose (B, 7); null: derived (robot=urdf)
    joint_low: list[float] = field(default_factory=lambda: [0.0, 0.3, 0.5])  # the IK branch's box
    joint_high: list[float] = field(default_factory=lambda: [2.0, 2.0, 1.5])
    locked: dict[str, float] = field(default_factory=dict)  # joint name -> held value (redundant arms)
    # a redundant arm's joint whose value is an input of the network beside the pose (pose targets
    # only); "": none. robot=urdf picks one for a 7-joint arm (rbfn.robots.derive)
    redundancy: str = ""
    rotation_scale: float = 0.3  # m per unit of the rotation features (pose targets)
    gravity: Optional[float] = None  # m/s^2 along -z of the root; null: the preset's (name), else 9.81
    home: list[float] = field(default_factory=list)  # a nominal pose per free joint; empty: the box centre
    rated_payload: float = 20.0  # kg: control payload cases default to 0, half and all of it; < 0: derived
    control_rate: Optional[float] = None  # Hz: the maker's controller cycle (the realistic loop's rate)
    # per chain joint: counts per revolution (per metre, prismatic) of the joint-side position
    # measurement (the realistic loop's encoders); empty: exact
    encoder_counts: list[float] = field(default_factory=list)
    derive: bool = False  # robot=urdf: fill the keys left at their markers from the URDF (see above)
    box_halfwidth: float = 0.5  # rad (m, prismatic): the derived box, home +- this, clipped to the limits
    # where the IK answers: box (one branch inside joint_low..joint_high) or full (every pose within the
    # URDF limits, every branch: `charts` networks, one a chart of joint space, rbfn.charts)
    workspace: Workspace = Workspace.box
    charts: int = 64  # workspace=full: how many charts (and networks)
    chart_centers: int = 300  # workspace=full: centres of each chart's network (rbfn.num_centers: the box's)
    chart_samples: int = 3000  # workspace=full: training samples drawn a chart, on average (a sixth validate)
    # workspace=full: refine each chart's centres as `centers.refine` says (false: the charts skip the
    # refinement, ~100 s a UR5 chart against ~2-8 s for its selection and fit)
    chart_refine: bool = False

    def check(self, key: str = "robot") -> None:
        """The URDF itself is checked when it is loaded."""
        derived = "(robot=urdf derives it from the URDF, rbfn.robots.derive, before this check)"
        _need(self.target is not None, f"{key}.target", self.target, f"position or pose {derived}")
        _need(
            finite(self.box_halfwidth) and self.box_halfwidth > 0,
            f"{key}.box_halfwidth",
            self.box_halfwidth,
            "must be > 0 (rad, or m for a prismatic joint)",
        )
        lo, hi = self.joint_low, self.joint_high
        _need(
            len(lo) == len(hi) and len(lo) > 0,
            f"{key}.joint_low",
            list(lo),
            f"{key}.joint_low and {key}.joint_high ({list(hi)}) need one value per joint each",
        )
        for i, (l, h) in enumerate(zip(lo, hi)):
            if not (finite(l) and finite(h) and l < h):
                raise ValueError(
                    f"{key}.joint_low/joint_high: empty or invalid range for joint {i + 1}: "
                    f"[{l}, {h}] ({key}.joint_low < {key}.joint_high required)"
                )
        _need(
            self.urdf != "" or self.name in ROBOT_PRESETS,
            f"{key}.name",
            self.name,
            f"with {key}.urdf empty, choose a packaged robot: {list(ROBOT_PRESETS)} (or give {key}.urdf=PATH)",
        )
        for j, v in self.locked.items():
            _need(finite(v), f"{key}.locked.{j}", v, "must be a finite joint value")
        _need(
            not self.redundancy or self.target == Target.pose,
            f"{key}.redundancy",
            self.redundancy,
            f'"" with {key}.target={self.target} (a redundant position arm: hold joints with {key}.locked); '
            "a joint name with pose targets",
        )
        _need(
            self.redundancy not in self.locked,
            f"{key}.redundancy",
            self.redundancy,
            f"a free joint, not one of {key}.locked {list(self.locked)}",
        )
        _need(
            finite(self.rotation_scale) and self.rotation_scale > 0,
            f"{key}.rotation_scale",
            self.rotation_scale,
            "must be > 0 m",
        )
        _need(
            self.gravity is None or (finite(self.gravity) and self.gravity >= 0),
            f"{key}.gravity",
            self.gravity,
            "must be >= 0 m/s^2 or null",
        )
        _need(
            len(self.home) in (0, len(lo)) and all(finite(v) for v in self.home),
            f"{key}.home",
            list(self.home),
            f"empty (the box centre) or one finite value per joint ({len(lo)})",
        )
        _need(
            finite(self.rated_payload) and self.rated_payload >= 0,
            f"{key}.rated_payload",
            self.rated_payload,
            f"must be >= 0 kg; < 0: derived {derived}",
        )
        _check_sensing(self.control_rate, self.encoder_counts, key)
        _need(
            not isinstance(self.charts, bool) and isinstance(self.charts, int) and self.charts >= 1,
            f"{key}.charts",
            self.charts,
            "must be an integer >= 1 (charts of joint space with workspace=full)",
        )
        for name, least in (("chart_centers", 1), ("chart_samples", 12)):
            v = getattr(self, name)
            _need(
                not isinstance(v, bool) and isinstance(v, int) and v >= least,
                f"{key}.{name}",
                v,
                f"must be an integer >= {least}",
            )


@dataclass
class DataConfig:
    n_train: int = 2000
    n_val: int = 1000
    n_test: int = 5000

    def check(self, key: str = "data") -> None:
        _need(
            self.n_train >= 2,
            f"{key}.n_train",
            self.n_train,
            "must be >= 2 (widths come from distances between samples)",
        )
        for name in ("n_val", "n_test"):
            _need(getattr(self, name) > 0, f"{key}.{name}", getattr(self, name), "must be > 0")


@dataclass
class ACORConfig:
    """ACO_R (`colony: acor`), the continuous colony: a Gaussian-kernel archive of solutions."""

    archive_size: int = 20  # archive k
    q: float = 0.2  # rank locality
    xi: float = 0.85  # spread
    init_spread: float = 0.3  # seed perturbation, in nearest-centre distances
    search_widths: WidthSearch = WidthSearch.per_center  # also search widths (per centre, one scale, none)

    def check(self, key: str) -> None:
        _need(self.archive_size >= 2, f"{key}.archive_size", self.archive_size, "must be >= 2")
        _need(finite(self.q) and self.q > 0, f"{key}.q", self.q, "must be > 0")
        _need(finite(self.xi) and self.xi > 0, f"{key}.xi", self.xi, "must be > 0")
        _need(
            finite(self.init_spread) and self.init_spread >= 0, f"{key}.init_spread", self.init_spread, "must be >= 0"
        )


@dataclass
class AntSystemConfig:
    """The paper's discrete Ant System (`colony: ant_system`): ants choose M of `candidates` points."""

    rho: float = 0.9  # evaporation
    Q: float = 100.0  # deposit
    alpha: float = 1.0  # pheromone exponent
    beta: float = 0.0  # heuristic exponent (visibility: local data density)
    candidates: int = 500  # candidate pool: training inputs drawn at random

    def check(self, key: str, num_centers: int) -> None:
        _need(finite(self.rho) and 0 < self.rho < 1, f"{key}.rho", self.rho, "must be in (0, 1)")
        _need(finite(self.Q) and self.Q > 0, f"{key}.Q", self.Q, "must be > 0")
        _need(finite(self.alpha) and self.alpha >= 0, f"{key}.alpha", self.alpha, "must be >= 0")
        _need(finite(self.beta) and self.beta >= 0, f"{key}.beta", self.beta, "must be >= 0")
        _need(
            self.candidates >= num_centers,
            f"{key}.candidates",
            self.candidates,
            f"must be >= the number of centres ({num_centers}): ants choose them among the candidates",
        )


@dataclass
class ACOConfig:
    """A colony (`centers.aco`, `control.network.aco`): what every colony shares, then one schema per
    colony; only the chosen colony's settings are read."""

    colony: Colony = Colony.acor
    objective: Objective = Objective.fit
    iterations: int = 100  # NC_max
    ants: int = 20  # ants per iteration
    fit_rows: int = 2048  # fit objective: the colony ranks ants on at most max(fit_rows, 50 P) training
    # and validation rows (a seeded subset; 0: every row); the final fit uses all
    acor: ACORConfig = field(default_factory=ACORConfig)
    ant_system: AntSystemConfig = field(default_factory=AntSystemConfig)

    def check(self, key: str, num_centers: int) -> None:
        _need(self.iterations >= 0, f"{key}.iterations", self.iterations, "must be >= 0")
        _need(self.ants >= 1, f"{key}.ants", self.ants, "must be >= 1")
        _need(self.fit_rows >= 0, f"{key}.fit_rows", self.fit_rows, "must be >= 0 (0: every row)")
        self.acor.check(f"{key}.acor")
        self.ant_system.check(f"{key}.ant_system", num_centers if self.colony == Colony.ant_system else 1)


@dataclass
class OLSConfig:
    """Orthogonal least squares (`method: ols`): forward selection from `candidates` training inputs."""

    candidates: int = 500

    def check(self, key: str, num_centers: int) -> None:
        _need(
            self.candidates >= num_centers,
            f"{key}.candidates",
            self.candidates,
            f"must be >= the number of centres ({num_centers}): OLS chooses them among the candidates",
        )


@dataclass
class FullRefineConfig:
    """`mode: full`: Adam on the whole training set, the output weights solved inside the loss."""

    steps: int = 2000  # Adam steps
    lr: float = 0.02  # Adam step size

    def check(self, key: str) -> None:
        _need(self.steps >= 0, f"{key}.steps", self.steps, "must be >= 0")
        _need(finite(self.lr) and self.lr > 0, f"{key}.lr", self.lr, "must be > 0")


@dataclass
class MinibatchRefineConfig:
    """`mode: minibatch`: Adam on mini-batches, the output weights trained too."""

    epochs: int = 300  # passes over the training set
    batch: int = 256  # rows per Adam step
    lr: float = 0.003  # first Adam step size, decayed to 0 on a cosine
    loss: RefineLoss = RefineLoss.task  # task error (m; rotation x robot.rotation_scale) | joint error
    huber: float = 0.005  # pseudo-Huber threshold on a row's error norm (m for task); 0: squared

    def check(self, key: str) -> None:
        _need(self.epochs >= 0, f"{key}.epochs", self.epochs, "must be >= 0")
        _need(self.batch >= 1, f"{key}.batch", self.batch, "must be >= 1")
        _need(finite(self.lr) and self.lr > 0, f"{key}.lr", self.lr, "must be > 0")
        _need(finite(self.huber) and self.huber >= 0, f"{key}.huber", self.huber, "must be >= 0 (0: squared error)")


@dataclass
class RefineConfig:
    """Gradient refinement of centres, widths and input scales after the selection; the `mode`
    (auto: full where N P^2 <= 2e9) picks which of `full` and `minibatch` runs."""

    enabled: bool = False
    mode: RefineMode = RefineMode.auto
    learn_input_scale: bool = True
    min_ridge: float = 1e-11  # floor on the relative ridge inside the loss (conditioning)
    full: FullRefineConfig = field(default_factory=FullRefineConfig)
    minibatch: MinibatchRefineConfig = field(default_factory=MinibatchRefineConfig)

    def check(self, key: str) -> None:
        _need(finite(self.min_ridge) and self.min_ridge >= 0, f"{key}.min_ridge", self.min_ridge, "must be >= 0")
        self.full.check(f"{key}.full")
        self.minibatch.check(f"{key}.minibatch")


@dataclass
class CentersConfig:
    name: str = "aco"  # the preset's label, one of SELECTORS
    method: Method = Method.aco
    width_rule: WidthRule = WidthRule.per_center
    width_scale: Optional[float] = None  # fixed scale of the rule's width; null: chosen on validation
    kmeans_restarts: int = 10
    aco: ACOConfig = field(default_factory=ACOConfig)
    ols: OLSConfig = field(default_factory=OLSConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)

    def check(self, num_centers: int, key: str = "centers") -> None:
        _need(self.name in SELECTORS, f"{key}.name", self.name, f"choose one of {list(SELECTORS)}")
        _need(
            self.width_scale is None
            or (finite(self.width_scale) and MIN_WIDTH_SCALE <= self.width_scale <= MAX_WIDTH_SCALE),
            f"{key}.width_scale",
            self.width_scale,
            f"must be null (chosen on validation) or in [{MIN_WIDTH_SCALE:g}, {MAX_WIDTH_SCALE:g}] times the width "
            f"rule's base: narrower Gaussians vanish between the centres, and the network returns its bias alone",
        )
        _need(self.kmeans_restarts >= 1, f"{key}.kmeans_restarts", self.kmeans_restarts, "must be >= 1")
        self.aco.check(f"{key}.aco", num_centers if self.method == Method.aco else 1)
        self.ols.check(f"{key}.ols", num_centers if self.method == Method.ols else 1)
        self.refine.check(f"{key}.refine")


@dataclass
class GrowthConfig:
    start: int = 0  # first M; 0 disables growth (fit at num_centers only)
    factor: float = 2.0  # next M = ceil(M * factor), capped at num_centers
    goal: float = 0.0  # E goal: validation 1/2 mean ||y - d||^2 (rad^2, m^2)

    def check(self, key: str = "rbfn.growth") -> None:
        _need(self.start >= 0, f"{key}.start", self.start, "must be >= 0 (0: no growth)")
        _need(finite(self.factor) and self.factor > 1.0, f"{key}.factor", self.factor, "must be > 1")
        _need(finite(self.goal) and self.goal >= 0, f"{key}.goal", self.goal, "must be >= 0")


@dataclass
class RBFNConfig:
    num_centers: int = 40
    input_scaling: InputScaling = InputScaling.metres
    tail: bool = True  # linear tail A z + b beside the Gaussians
    solver: Solver = Solver.lstsq
    lms_alpha0: float = 0.5
    lms_epochs: int = 50
    max_width: float = 2.0  # cap on widths, scaled units (float32 conditioning)
    # float32 deployment: a fit's rounding scale may reach this fraction of its own validation RMS
    # error per output where that exceeds the absolute 2e-6 (rad, m); 0: the absolute bound alone
    round_rel: float = 0.0
    growth: GrowthConfig = field(default_factory=GrowthConfig)

    def check(self, n_train: int, key: str = "rbfn") -> None:
        _need(self.num_centers > 0, f"{key}.num_centers", self.num_centers, "must be > 0")
        _need(
            self.num_centers <= n_train,
            f"{key}.num_centers",
            self.num_centers,
            f"exceeds the training set size data.n_train={n_train}; use at most {n_train} centres",
        )
        _need(finite(self.max_width) and self.max_width > 0, f"{key}.max_width", self.max_width, "must be > 0")
        _need(
            finite(self.round_rel) and 0 <= self.round_rel < 1, f"{key}.round_rel", self.round_rel, "must be in [0, 1)"
        )
        _need(0 < self.lms_alpha0 < 2, f"{key}.lms_alpha0", self.lms_alpha0, "must be in (0, 2)")
        _need(self.lms_epochs >= 1, f"{key}.lms_epochs", self.lms_epochs, "must be >= 1")
        self.growth.check(f"{key}.growth")


@dataclass
class TrainConfig:
    robot: RobotConfig = field(default_factory=RobotConfig)
    data: DataConfig = field(default_factory=DataConfig)
    centers: CentersConfig = field(default_factory=CentersConfig)
    rbfn: RBFNConfig = field(default_factory=RBFNConfig)
    seed: int = 0
    device: str = "cpu"
    num_threads: int = 0  # torch threads; 0 leaves torch's default
    progress: bool = True  # progress bars on a terminal; each part's "still running" line every 30 s (terminal and log)
    export: bool = True  # write ik.onnx and ik.pt2 next to checkpoint.pt

    def check(self) -> None:
        """Every value's type and every value (whether the run fits in memory:
        `rbfn.memory.check_train`)."""
        check_types(self)
        self.data.check()
        self.rbfn.check(self.data.n_train)
        self.centers.check(self.rbfn.num_centers)
        self.robot.check()
        _seed("seed", self.seed)
        validate_device(self.device, self.num_threads)


# -------------------------------------------------------------------------------------- evaluate
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
            0.5 < d < duration,
            f"{key}.duration",
            self.duration if self.duration is not None else f"null (derived: {d:g})",
            f"must exceed 0.5 s (errors are measured after 0.5 s) and be shorter than control.duration={duration}",
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
            _need(
                "arbfn_cmaes" not in controllers,
                "control.controllers",
                "arbfn_cmaes",
                f"CMA-ES searches the closed loop only: needs {key}.objective=closed_loop (it is {self.objective}; "
                f"{key}.law=tracking makes it the default)",
            )
            return
        if "arbfn_aco" in controllers:
            _need(
                self.aco.colony == Colony.acor,
                f"{key}.aco.colony",
                str(self.aco.colony),
                f"the closed_loop objective searches continuous offsets with acor; or set {key}.objective=fit",
            )
        if any(f"arbfn_{m}" in controllers for m in CLOSED_LOOP_SEARCHES):
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
    figure_payload: Optional[float] = None  # kg, the case drawn in the figures; null: half the rated payload
    pick_and_place: PickAndPlaceConfig = field(default_factory=PickAndPlaceConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)

    def check(self, key: str = "control", realistic: bool = True) -> None:
        """`realistic`: the loop is the realistic one (what a null control.network.law means)."""
        arbfn = [f"arbfn_{m}" for m in CONTROL_CENTER_METHODS]
        for name in self.controllers:
            _need(
                name in BASE_CONTROLLERS or name in arbfn,
                f"{key}.controllers",
                name,
                f"choose from {list(BASE_CONTROLLERS + tuple(arbfn))}",
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
        _need(
            self.figure_payload is None or finite(self.figure_payload),
            f"{key}.figure_payload",
            self.figure_payload,
            "must be a finite mass in kg or null",
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
        self.pick_and_place.check(f"{key}.pick_and_place", self.dt)
        n = self.network
        _need(n.num_centers >= 1, f"{key}.network.num_centers", n.num_centers, "must be >= 1")
        if any(name.startswith("arbfn_") for name in self.controllers):
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


@dataclass
class OnlineConfig:
    """Online IK adaptation in the closed loop (evaluate.py's `online` part; needs a checkpoint),
    on the robot the checkpoint was trained for.

    The "real" robot differs from the model by `link_error` (relative errors of links 1, 2, ...:
    link k runs from joint k to joint k+1, or to the end link for the last joint) and
    `offset_error` (offsets added to joints 1, 2, ... in chain order, rad or m); missing entries
    are 0. `sizes` are link-1 errors to sweep: each row scales the whole configured perturbation
    so that its link-1 error equals the size; the configured perturbation itself
    (size = link_error[0]) is the one the headline metrics report.
    """

    enabled: bool = True
    duration: float = 20.0  # s
    dt: float = 1e-3  # s
    path: Optional[PathName] = None  # null: paper (SCARA), sinusoid (URDF arms)
    amplitude: float = 0.25  # sinusoid path: per joint amplitude / half the trained box range
    link_error: list[float] = field(default_factory=lambda: [0.03, -0.02])  # relative, links 1, 2, ...
    offset_error: list[float] = field(default_factory=lambda: [0.02, 0.0, 0.0])  # joints 1, 2, ... (rad or m)
    sizes: list[float] = field(default_factory=lambda: [0.0, 0.01, 0.03, 0.05])  # link-1 errors
    learner: Learner = Learner.nlms
    alpha0: float = 0.5  # NLMS step alpha(0)
    decay: float = 0.0  # s; alpha(t) = alpha0 / (1 + t / decay); 0: constant
    forgetting: float = 0.9995  # RLS forgetting factor
    update_every: int = 10  # control periods per update (the pairs of one mini-batch)
    aot: str = "auto"  # the closed-loop chunk compiled ahead of time, cached on disk: as control.aot
    save_checkpoint: bool = True  # write checkpoint_online.pt (the configured perturbation's network)

    def check(self, key: str = "online") -> None:
        _check_aot(self.aot, f"{key}.aot")
        _need(finite(self.dt) and self.dt > 0, f"{key}.dt", self.dt, "must be a positive number of seconds")
        _need(
            finite(self.duration) and self.duration >= 4.0,
            f"{key}.duration",
            self.duration,
            "must be >= 4 s (the metrics use the first and last 2 s)",
        )
        _need(
            len(self.link_error) > 0 and all(finite(v) and v > -1 for v in self.link_error),
            f"{key}.link_error",
            list(self.link_error),
            "relative errors > -1 of links 1, 2, ... (at least link 1)",
        )
        _need(
            all(finite(v) for v in self.offset_error),
            f"{key}.offset_error",
            list(self.offset_error),
            "finite joint offsets (rad or m) of joints 1, 2, ...",
        )
        _need(
            finite(self.amplitude) and 0 < self.amplitude <= 0.5,
            f"{key}.amplitude",
            self.amplitude,
            "must be in (0, 0.5] (the sinusoid path's two terms then stay inside the trained box)",
        )
        _need(
            len(self.sizes) > 0 and all(finite(s) for s in self.sizes),
            f"{key}.sizes",
            list(self.sizes),
            "a non-empty list of link-1 errors",
        )
        ref = self.link_error[0]
        _need(
            ref != 0 or all(s == 0 for s in self.sizes),
            f"{key}.sizes",
            list(self.sizes),
            f"sizes scale the configured perturbation by its link-1 error, and {key}.link_error[0] is 0",
        )
        _need(
            any(math.isclose(s, ref, rel_tol=1e-9, abs_tol=1e-12) for s in self.sizes),
            f"{key}.sizes",
            list(self.sizes),
            f"must include {key}.link_error[0]={ref}, the configured perturbation",
        )
        _need(0 <= self.alpha0 < 2, f"{key}.alpha0", self.alpha0, "must be in [0, 2)")
        _need(finite(self.decay) and self.decay >= 0, f"{key}.decay", self.decay, "must be >= 0")
        _need(0 < self.forgetting <= 1, f"{key}.forgetting", self.forgetting, "must be in (0, 1]")
        _need(self.update_every >= 1, f"{key}.update_every", self.update_every, "must be >= 1")


@dataclass
class LoopConfig:
    """How real the closed loop is (group `loop`: `ideal`, today's exact loop, every value off;
    `realistic`, what a real arm has). Times in control periods of 1 / control_rate s.

    The controller reads the positions measured `sensing_delay` periods ago, quantised by the
    encoders and with Gaussian noise, and velocities from their filtered finite differences; it
    acts every 1 / control_rate s (zero-order hold; the plant integrates at control.dt), and its
    torque acts `actuation_delay` periods later, saturated at the URDF's effort limits, with
    Gaussian noise. The observer and the adaptation are told the torque actually applied.
    """

    name: str = "ideal"  # the preset's label
    control_rate: Optional[float] = None  # Hz; null: the controller acts every control.dt
    sensing_delay: int = 0  # periods between a measurement and its use
    actuation_delay: int = 0  # periods between a command and its torque
    encoder_counts: list[float] = field(default_factory=list)  # per joint (robot.encoder_counts); empty: exact
    position_noise: float = 0.0  # rad (m): standard deviation on the measured positions
    velocity_cutoff: Optional[float] = None  # Hz: first-order filter on position differences; null: exact velocity
    torque_limits: bool = False  # saturate the torques at the URDF's effort limits
    torque_noise: float = 0.0  # N m (N) per unit joint scale: standard deviation on the applied torque
    noise_seed: int = 0  # the sensor and torque noise streams

    @property
    def ideal(self) -> bool:
        """Every part off: the loop is today's exact one, bit for bit."""
        return (
            self.control_rate is None
            and self.sensing_delay == 0
            and self.actuation_delay == 0
            and not self.encoder_counts
            and self.position_noise == 0
            and self.velocity_cutoff is None
            and not self.torque_limits
            and self.torque_noise == 0
        )

    def check(self, dt: float, key: str = "loop") -> None:
        """dt: the integration step (control.dt), s."""
        rate = self.control_rate
        _check_sensing(rate, self.encoder_counts, key)
        if rate is not None:
            sub = 1.0 / (rate * dt)
            _need(
                sub >= 1 - 1e-9 and abs(sub - round(sub)) < 1e-6,
                f"{key}.control_rate",
                rate,
                f"its period must be a whole number of integration steps control.dt={dt} s",
            )
        for k in ("sensing_delay", "actuation_delay"):
            _need(0 <= getattr(self, k) <= 100, f"{key}.{k}", getattr(self, k), "must be in [0, 100] periods")
        for k in ("position_noise", "torque_noise"):
            _need(finite(getattr(self, k)) and getattr(self, k) >= 0, f"{key}.{k}", getattr(self, k), "must be >= 0")
        cut = self.velocity_cutoff
        _need(cut is None or (finite(cut) and cut > 0), f"{key}.velocity_cutoff", cut, "must be > 0 Hz or null")
        _seed(f"{key}.noise_seed", self.noise_seed)


@dataclass
class EvalConfig:
    checkpoint: Optional[str] = None  # null: the newest checkpoint.pt under outputs_dir
    outputs_dir: str = "outputs"
    ik: bool = True  # the IK accuracy part (needs a checkpoint)
    n_test: int = 10000
    seed: Optional[int] = None  # null: the checkpoint's training seed; the test stream is derived
    device: str = "cpu"
    num_threads: int = 0  # torch threads; 0: torch's default, or one per process while the parts
    # run side by side
    parallel: bool = True  # checkpoint parts, half the control figures in forked processes
    # (fork, CPU, >= 2 cores)
    progress: bool = True  # each part's "still running" line every 30 s (terminal and log), with where it stands
    robot: RobotConfig = field(default_factory=RobotConfig)  # the control part's robot (IK: the checkpoint's)
    gains: GainsConfig = field(default_factory=GainsConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    online: OnlineConfig = field(default_factory=OnlineConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)

    def check(self) -> None:
        """Every value's type and every value of every enabled part (whether the parts fit in
        memory: `rbfn.memory.check_evaluate`)."""
        check_types(self)
        _need(self.n_test > 0, "n_test", self.n_test, "must be > 0")
        if self.seed is not None:
            _seed("seed", self.seed)
        validate_device(self.device, self.num_threads)
        self.robot.check()
        if self.control.enabled:
            self.control.check(realistic=not self.loop.ideal)
            self.gains.check()
            self.loop.check(self.control.dt)
        if self.online.enabled:
            self.online.check()


# ------------------------------------------------------------------------------------ validation
def validate_train(cfg: TrainConfig) -> None:
    """Raise ValueError naming the first bad value of a training config (`TrainConfig.check`)."""
    cfg.check()


def validate_evaluate(cfg: EvalConfig) -> None:
    """Raise ValueError naming the first bad value of an evaluation config (`EvalConfig.check`)."""
    cfg.check()


def _type_error(annotation: Any, value: Any) -> str | None:
    """What is allowed where `value` is not of the field type `annotation` (None where it is): a
    bool field takes only true or false (not 1, 2 or "yes", which OmegaConf would take for true),
    an int field only integers (not 1.5, not true), a float field only numbers (not true), a str
    field no bool (true would become "True"), a choice one of its names; lists and dicts element by
    element. Nested config schemas are checked field by field by `check_types`."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Union:  # Optional[X]
        inner = [a for a in args if a is not type(None)]
        return None if value is None else _type_error(inner[0], value)
    if annotation is bool:
        return None if isinstance(value, bool) else "must be true or false"
    if annotation is int:
        return None if isinstance(value, int) and not isinstance(value, bool) else "must be an integer"
    if annotation is float:
        return None if isinstance(value, (int, float)) and not isinstance(value, bool) else "must be a number"
    if annotation is str:
        return "must be a string (on the command line, quote it: 'true')" if isinstance(value, bool) else None
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        names = [m.value for m in annotation]
        return None if value in names else f"expected one of {names}"
    if origin is list and isinstance(value, (list, tuple)):
        errors = (_type_error(args[0], v) for v in value)
        return next((f"each entry {e}" for e in errors if e), None)
    if origin is dict and isinstance(value, dict):
        errors = (_type_error(args[1], v) for v in value.values())
        return next((f"each value {e}" for e in errors if e), None)
    if origin in (list, dict):
        return f"must be a {origin.__name__}"
    return None


def check_types(cfg: Any, key: str = "") -> None:
    """ValueError naming the full key and value of the first field of the config dataclass `cfg`
    (nested ones included) whose value is not of its declared type (`_type_error`): the Python API's
    counterpart of what Hydra's composition and `check_overrides` refuse on the command line."""
    hints = typing.get_type_hints(type(cfg))
    for f in fields(cfg):
        value, name = getattr(cfg, f.name), f"{key}{f.name}"
        if is_dataclass(value):
            check_types(value, f"{name}.")
            continue
        error = _type_error(hints[f.name], value)
        if error:
            raise ValueError(f"{name}={value!r} is not allowed: {error}")


def check_overrides(schema: type, overrides: Sequence[str]) -> None:
    """ValueError naming the first command-line override (`key=value`, as Hydra parses it) that sets
    a key of the config dataclass `schema` to a value of another type (`_type_error`), before
    OmegaConf converts it: `export=2`, `export=yes` and `progress=1` would each become true, and
    `robot.name=true` "True". Overrides of groups, of keys outside `schema` (hydra.*), sweeps and
    interpolations are left to Hydra."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    for o in OverridesParser.create().parse_overrides(list(overrides)):
        if o.is_delete() or o.is_sweep_override():
            continue
        annotation: Any = schema
        for part in o.key_or_group.split("."):
            origin = typing.get_origin(annotation)
            if is_dataclass(annotation):
                hints = typing.get_type_hints(annotation)
                annotation = hints.get(part)
            elif origin is dict:
                annotation = typing.get_args(annotation)[1]
            else:
                annotation = None
            if annotation is None:
                break
        value = o.value()
        if annotation is None or is_dataclass(annotation) or (isinstance(value, str) and "${" in value):
            continue
        error = _type_error(annotation, value)
        if error:
            line = o.input_line or f"{o.key_or_group}={value!r}"
            raise ValueError(f"{line} is not allowed: {error}")


def _check_sensing(rate: float | None, counts: list[float], key: str) -> None:
    """`key`.control_rate (Hz or null) and `key`.encoder_counts, the robot's facts and the loop's."""
    _need(rate is None or (finite(rate) and rate > 0), f"{key}.control_rate", rate, "must be > 0 Hz or null")
    _need(
        all(finite(c) and c >= 1 for c in counts),
        f"{key}.encoder_counts",
        list(counts),
        "counts per revolution (per metre for a prismatic joint) >= 1, one per chain joint, or empty (exact)",
    )


AOT_CHOICES = ("auto", "true", "false")  # control.aot, online.aot (a bool from the command line reads as one)


def _check_aot(value: Any, key: str) -> None:
    _need(str(value).lower() in AOT_CHOICES, key, value, f"choose from {list(AOT_CHOICES)}")


def _need(ok: bool, key: str, value: Any, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{key}={value!r} is not allowed: {allowed}")


def finite(x: Any) -> bool:
    """Whether `x` is a finite int or float (not a bool): the check every numeric setting passes."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def validate_device(device: str, num_threads: int, prefix: str = "") -> None:
    """`device` is cpu or an available cuda[:N]; `num_threads` in [0, MAX_THREADS_PER_CPU x the
    machine's CPUs] (torch's thread pool crashes the process far above that: 100 000 segfaults)."""
    most = MAX_THREADS_PER_CPU * (os.cpu_count() or 1)
    _need(
        isinstance(num_threads, int) and 0 <= num_threads <= most,
        f"{prefix}num_threads",
        num_threads,
        f"use 0 (torch's default) or a number of threads up to {most} ({MAX_THREADS_PER_CPU} x this machine's "
        f"{os.cpu_count() or 1} CPUs)",
    )
    d = str(device)
    ok = d == "cpu" or d == "cuda" or (d.startswith("cuda:") and d[5:].isdigit())
    _need(ok, f"{prefix}device", device, "use 'cpu', 'cuda' or 'cuda:N'")
    if d != "cpu":
        import torch  # a runtime fact, not a schema one

        if not torch.cuda.is_available():
            raise ValueError(
                f"{prefix}device={device!r}: no CUDA device is available to this torch "
                f"(torch {torch.__version__}, built for CUDA {torch.version.cuda}); use device=cpu"
            )
        n = torch.cuda.device_count()
        if d.startswith("cuda:") and int(d[5:]) >= n:
            raise ValueError(f"{prefix}device={device!r}: only {n} CUDA device(s) (cuda:0..cuda:{n - 1})")


MAX_THREADS_PER_CPU = 4  # num_threads' ceiling: more threads than that only contend for the CPUs


def _seed(key: str, seed: Any) -> None:
    _need(isinstance(seed, int) and 0 <= seed <= MAX_SEED, key, seed, f"use an integer in [0, {MAX_SEED}]")


def plain(cfg: Any) -> dict:
    """A config dataclass as plain JSON data (choices as strings), for checkpoints and logs."""
    return json.loads(json.dumps(asdict(cfg)))


def register_configs() -> None:
    """Register the schemas with Hydra's ConfigStore (imported here so the library stays Hydra-free)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)
    cs.store(group="centers", name="centers_schema", node=CentersConfig)
    cs.store(name="evaluate_schema", node=EvalConfig)
    cs.store(group="gains", name="gains_schema", node=GainsConfig)
    cs.store(group="robot", name="robot_schema", node=RobotConfig)
    cs.store(group="loop", name="loop_schema", node=LoopConfig)
