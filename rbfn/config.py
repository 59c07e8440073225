"""Configuration schemas (plain dataclasses) and their validation, done once at the edge.

train.py and evaluate.py register these with Hydra's ConfigStore (`register_configs`), so a
mistyped value fails when the config is composed; `validate_train` then checks ranges and names
and raises ValueError naming the bad value and what is allowed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

__all__ = ["RobotConfig", "DataConfig", "ACOConfig", "RefineConfig", "CentersConfig", "GrowthConfig",
           "RBFNConfig", "TrainConfig", "validate_train", "register_configs",
           "GainsConfig", "NetworkConfig", "ControlConfig", "OnlineConfig", "validate_control", "validate_online", "SELECTORS", "COLONIES", "OBJECTIVES", "SOLVERS", "INPUT_SCALINGS"]

SELECTORS = ("aco", "aco_paper", "kmeans", "kmeans_refine", "random", "ols")
METHODS = ("aco", "kmeans", "random", "ols")
COLONIES = ("acor", "ant_system")
OBJECTIVES = ("fit", "cluster")
SOLVERS = ("lstsq", "lms")
INPUT_SCALINGS = ("metres", "standard")
WIDTH_RULES = ("paper", "global", "per_center")
WIDTH_SEARCH = ("per_center", "scale", "none")


@dataclass
class RobotConfig:
    urdf: str = ""                     # empty: the packaged SCARA URDF
    end_link: str = "quill"
    joint_low: list[float] = field(default_factory=lambda: [0.0, 0.3, 0.5])   # rad, rad, m
    joint_high: list[float] = field(default_factory=lambda: [2.0, 2.0, 1.5])


@dataclass
class DataConfig:
    n_train: int = 2000
    n_val: int = 1000
    n_test: int = 5000


@dataclass
class ACOConfig:
    colony: str = "acor"               # acor | ant_system
    objective: str = "fit"             # fit | cluster
    iterations: int = 100              # NC_max
    ants: int = 20                     # ants per iteration
    archive_size: int = 20             # ACO_R archive k
    q: float = 0.2                     # ACO_R rank locality
    xi: float = 0.85                   # ACO_R spread
    init_spread: float = 0.3           # ACO_R seed perturbation, in nearest-centre distances
    search_widths: str = "per_center"  # ACO_R also searches: per_center log widths | scale (one global) | none
    rho: float = 0.9                   # Ant System evaporation
    Q: float = 100.0                   # Ant System deposit
    alpha: float = 1.0                 # Ant System pheromone exponent
    beta: float = 0.0                  # Ant System heuristic exponent
    candidates: int = 500              # Ant System / OLS candidate pool (k-means pre-clustered)


@dataclass
class RefineConfig:
    enabled: bool = False
    steps: int = 300
    lr: float = 0.01
    learn_input_scale: bool = True
    min_ridge: float = 1e-11           # floor on the relative ridge inside the loss (conditioning)


@dataclass
class CentersConfig:
    name: str = "aco"
    method: str = "aco"                # aco | kmeans | random | ols
    width_rule: str = "per_center"     # paper | global | per_center
    width_scale: Optional[float] = None  # fixed scale of the rule's width; null: chosen on validation
    kmeans_restarts: int = 10
    aco: ACOConfig = field(default_factory=ACOConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)


@dataclass
class GrowthConfig:
    start: int = 0                     # first M; 0 disables growth (fit at num_centers only)
    factor: float = 2.0                # next M = ceil(M * factor), capped at num_centers
    goal: float = 0.0                  # E goal: validation 1/2 mean ||y - d||^2 (rad^2, m^2)


@dataclass
class RBFNConfig:
    num_centers: int = 40
    input_scaling: str = "metres"      # metres (centred) | standard
    tail: bool = True                  # linear tail A z + b beside the Gaussians
    solver: str = "lstsq"              # lstsq (ridge on validation) | lms
    lms_alpha0: float = 0.5
    lms_epochs: int = 50
    max_width: float = 2.0             # cap on widths, scaled units (float32 conditioning)
    growth: GrowthConfig = field(default_factory=GrowthConfig)


@dataclass
class TrainConfig:
    robot: RobotConfig = field(default_factory=RobotConfig)
    data: DataConfig = field(default_factory=DataConfig)
    centers: CentersConfig = field(default_factory=CentersConfig)
    rbfn: RBFNConfig = field(default_factory=RBFNConfig)
    seed: int = 0
    device: str = "cpu"
    num_threads: int = 0               # torch threads; 0 leaves torch's default
    progress: bool = True
    export: bool = True                # write ik.onnx and ik.pt2 next to checkpoint.pt


@dataclass
class GainsConfig:
    """Feedback and adaptation gains shared by every controller of a comparison (group `gains`)."""

    K: float = 50.0                # N m s / rad (N s / m): s feedback
    Lambda: float = 20.0           # 1/s: sliding-surface slope
    epsilon: float = 0.05          # N m (N): robust term amplitude
    robust: str = "sat"            # sign | sat
    boundary: float = 0.01         # rad/s (m/s): saturation boundary layer width of sat(s / boundary)
    observer_gain: float = 1000.0   # 1/s: momentum-observer bandwidth
    gamma: float = 500.0           # adaptation rate Gamma of dW/dt = Gamma h s^T (alpha = gamma dt)
    gamma_decay: float = 1e9       # s: Gamma(t) = gamma / (1 + t / gamma_decay)
    leakage: float = 0.0           # 1/s: sigma-modification
    pd_kp: float = 0.0             # PD gains; 0: K Lambda and K, the same feedback as smc's K s
    pd_kd: float = 0.0


@dataclass
class NetworkConfig:
    """The adaptive controller's RBF network (controllers arbfn_<method>)."""

    num_centers: int = 25
    observer: bool = True              # combine the network with the momentum observer
    warm_start: bool = False           # start W at the ridge fit of the pilot run's residual torque
    seed: int = 0
    aco: ACOConfig = field(default_factory=lambda: ACOConfig(iterations=100, ants=20))


@dataclass
class ControlConfig:
    """The closed-loop scenario of evaluate.py (times in s, masses in kg)."""

    enabled: bool = True
    controllers: list[str] = field(default_factory=lambda: ["pd", "ctc", "smc", "smc_obs", "arbfn_aco",
                                                            "arbfn_kmeans"])
    payloads: list[float] = field(default_factory=lambda: [0.0, 10.0, 20.0])
    duration: float = 10.0
    dt: float = 1e-3
    integrator: str = "rk4"            # rk4 | euler (semi-implicit)
    payload_on: float = 1.0
    payload_off: float = 4.0
    friction: str = "sign"             # sign | smooth (tanh(qd / 0.01))
    dtype: str = "float64"             # float64 | float32
    compile: bool = False              # torch.compile the fused step (slow to compile; for long runs)
    figure_payload: float = 10.0       # the payload case drawn in the 3x3 figures
    network: NetworkConfig = field(default_factory=NetworkConfig)


@dataclass
class OnlineConfig:
    """Online IK adaptation in the closed loop (evaluate.py's `online` part; needs a checkpoint)."""

    enabled: bool = True
    duration: float = 20.0             # s
    dt: float = 1e-3                   # s
    path: str = "paper"                # paper (FK of the paper's joint trajectory) | circle | figure8
    link_error: list[float] = field(default_factory=lambda: [0.03, -0.02])    # relative, l1 and l2
    offset_error: list[float] = field(default_factory=lambda: [0.02, 0.0, 0.0])  # rad, rad, m
    sizes: list[float] = field(default_factory=lambda: [0.0, 0.01, 0.03, 0.05])  # sweep: link-1 error
    learner: str = "nlms"              # nlms | rls
    alpha0: float = 0.5                # NLMS step alpha(0)
    decay: float = 0.0                 # s; alpha(t) = alpha0 / (1 + t / decay); 0: constant
    forgetting: float = 0.9995         # RLS forgetting factor
    update_every: int = 10             # control periods per update (the pairs of one mini-batch)
    save_checkpoint: bool = True       # write checkpoint_online.pt (the default perturbation's network)


def _allowed(name: str, value: Any, allowed: tuple) -> None:
    if value not in allowed:
        raise ValueError(f"{name}={value!r} is not allowed; choose one of {list(allowed)}")


def validate_train(cfg: TrainConfig) -> None:
    """Raise ValueError naming the first bad value in a training config."""
    c, r, d, a = cfg.centers, cfg.rbfn, cfg.data, cfg.centers.aco
    _allowed("centers.name", c.name, SELECTORS)
    _allowed("centers.method", c.method, METHODS)
    _allowed("centers.width_rule", c.width_rule, WIDTH_RULES)
    _allowed("centers.aco.colony", a.colony, COLONIES)
    _allowed("centers.aco.objective", a.objective, OBJECTIVES)
    _allowed("centers.aco.search_widths", a.search_widths, WIDTH_SEARCH)
    _allowed("rbfn.solver", r.solver, SOLVERS)
    _allowed("rbfn.input_scaling", r.input_scaling, INPUT_SCALINGS)
    for name in ("n_train", "n_val", "n_test"):
        if getattr(d, name) <= 0:
            raise ValueError(f"data.{name}={getattr(d, name)} must be > 0")
    if r.num_centers <= 0:
        raise ValueError(f"rbfn.num_centers={r.num_centers} must be > 0")
    if r.num_centers > d.n_train:
        raise ValueError(f"rbfn.num_centers={r.num_centers} exceeds the training set size "
                         f"data.n_train={d.n_train}; use at most {d.n_train} centres")
    if c.width_scale is not None and not (math.isfinite(c.width_scale) and c.width_scale > 0):
        raise ValueError(f"centers.width_scale={c.width_scale} must be a positive finite number or null")
    if not r.max_width > 0:
        raise ValueError(f"rbfn.max_width={r.max_width} must be > 0")
    if c.method == "ols" and a.candidates < r.num_centers:
        raise ValueError(f"centers.aco.candidates={a.candidates} must be >= rbfn.num_centers={r.num_centers}")
    if a.iterations < 0 or a.ants < 1 or a.archive_size < 2:
        raise ValueError(f"centers.aco needs iterations >= 0, ants >= 1, archive_size >= 2; got "
                         f"{a.iterations}, {a.ants}, {a.archive_size}")
    if not 0 < a.rho < 1:
        raise ValueError(f"centers.aco.rho={a.rho} must be in (0, 1)")
    if not 0 < r.lms_alpha0 < 2:
        raise ValueError(f"rbfn.lms_alpha0={r.lms_alpha0} must be in (0, 2)")
    lo, hi = cfg.robot.joint_low, cfg.robot.joint_high
    if len(lo) != len(hi):
        raise ValueError(f"robot.joint_low {list(lo)} and robot.joint_high {list(hi)} differ in length")
    for i, (l, h) in enumerate(zip(lo, hi)):
        if not (math.isfinite(l) and math.isfinite(h) and l < h):
            raise ValueError(f"empty or invalid joint range for joint {i + 1}: "
                             f"[{l}, {h}] (robot.joint_low < robot.joint_high required)")
    g = r.growth
    if g.start < 0 or g.factor <= 1.0 or g.goal < 0:
        raise ValueError(f"rbfn.growth needs start >= 0, factor > 1, goal >= 0; "
                         f"got start={g.start}, factor={g.factor}, goal={g.goal}")
    if cfg.num_threads < 0:
        raise ValueError(f"num_threads={cfg.num_threads} must be >= 0")
    if not (cfg.device == "cpu" or cfg.device.startswith("cuda")):
        raise ValueError(f"device={cfg.device!r} is not allowed; use 'cpu' or 'cuda[:N]'")


def validate_control(c: ControlConfig, gains: GainsConfig) -> None:
    """Raise ValueError naming the first bad value in the control part of evaluate's config."""
    from .control.controllers import CONTROLLERS, ROBUST_TERMS
    from .control.network import CENTER_METHODS

    for name in c.controllers:
        if name in CONTROLLERS[:-1]:
            continue
        if not (name.startswith("arbfn_") and name[6:] in CENTER_METHODS):
            raise ValueError(f"control.controllers: unknown controller {name!r}; choose from "
                             f"{list(CONTROLLERS[:-1])} or arbfn_<{'|'.join(CENTER_METHODS)}>")
    for k, v in vars(gains).items():
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"gains.{k}={v} must be finite")
    for k in ("K", "Lambda", "boundary", "observer_gain", "gamma_decay"):
        if not getattr(gains, k) > 0:
            raise ValueError(f"gains.{k}={getattr(gains, k)} must be > 0")
    for k in ("epsilon", "gamma", "leakage", "pd_kp", "pd_kd"):
        if getattr(gains, k) < 0:
            raise ValueError(f"gains.{k}={getattr(gains, k)} must be >= 0")
    _allowed("gains.robust", gains.robust, ROBUST_TERMS)
    _allowed("control.dtype", c.dtype, ("float64", "float32"))
    _allowed("control.friction", c.friction, ("sign", "smooth"))
    if any(not (math.isfinite(p) and p >= 0) for p in c.payloads) or not c.payloads:
        raise ValueError(f"control.payloads={list(c.payloads)} must be a non-empty list of masses >= 0 kg")
    if c.network.num_centers < 1:
        raise ValueError(f"control.network.num_centers={c.network.num_centers} must be >= 1")


def validate_online(c: OnlineConfig) -> None:
    """Raise ValueError naming the first bad value in the `online` part of evaluate's config."""
    from .control.task_space import PATHS
    from .online import LEARNERS

    _allowed("online.path", c.path, PATHS)
    _allowed("online.learner", c.learner, LEARNERS)
    if not (math.isfinite(c.dt) and c.dt > 0) or not (math.isfinite(c.duration) and c.duration >= 4.0):
        raise ValueError(f"online.dt={c.dt} must be > 0 and online.duration={c.duration} >= 4 s "
                         "(the metrics use the first and last 2 s)")
    if len(c.link_error) != 2 or len(c.offset_error) != 3:
        raise ValueError(f"online.link_error needs 2 values (l1, l2) and online.offset_error 3 "
                         f"(joints 1-3); got {list(c.link_error)} and {list(c.offset_error)}")
    if 0.03 not in c.sizes:
        raise ValueError(f"online.sizes={list(c.sizes)} must include 0.03, the default perturbation")
    if not 0 <= c.alpha0 < 2 or c.decay < 0 or not 0 < c.forgetting <= 1 or c.update_every < 1:
        raise ValueError(f"online needs 0 <= alpha0 < 2, decay >= 0, 0 < forgetting <= 1, "
                         f"update_every >= 1; got {c.alpha0}, {c.decay}, {c.forgetting}, {c.update_every}")


def register_configs() -> None:
    """Register the schemas with Hydra's ConfigStore (imported here so the library stays Hydra-free)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="train_schema", node=TrainConfig)
    cs.store(group="centers", name="centers_schema", node=CentersConfig)
