"""train.py's schemas: the data, the centres (one schema per colony, one per refinement mode), the
network and its growth, and `TrainConfig`, which holds them with the robot."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from .base import Choice, _need, _seed, check_types, finite, validate_device
from .robot import RobotConfig


class Method(Choice):
    aco = "aco"
    kmeans = "kmeans"
    random = "random"
    ols = "ols"
    cmaes = "cmaes"


class Colony(Choice):
    acor = "acor"
    ant_system = "ant_system"


class Objective(Choice):
    fit = "fit"
    cluster = "cluster"


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


# Presets of the `centers` group (conf/centers/NAME.yaml); a label, recorded with every run.
SELECTORS = ("aco", "aco_paper", "kmeans", "kmeans_refine", "random", "ols", "cmaes")
# Useful widths, as multiples of a width rule's base (the paper's d_max / sqrt(2M), or the mean
# distance to the nearest centres): validation chooses among 0.25 .. 64 (rbfn.widths.SCALE_GRID).
# Below 1/16, a Gaussian is exp(-128) ~ 3e-56 half-way to the next centre: the network is its bias
# alone between centres (and float32 features underflow to zero).
MIN_WIDTH_SCALE = 1.0 / 16.0
MAX_WIDTH_SCALE = 1024.0


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


def validate_train(cfg: TrainConfig) -> None:
    """Raise ValueError naming the first bad value of a training config (`TrainConfig.check`)."""
    cfg.check()
