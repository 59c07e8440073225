"""Every configuration schema and every allowed name, in one place; validation done once at the edge.

This module is the bottom layer of the package: it imports nothing from `rbfn`. train.py and
evaluate.py register the schemas with Hydra's ConfigStore (`register_configs`), so a mistyped
value or an unknown choice (an Enum field) fails when the config is composed, naming the options;
`validate_train` / `validate_evaluate` then check ranges and combinations and raise ValueError
naming the full key, the bad value and what is allowed, before any work starts.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from enum import Enum
from typing import Any, Optional

__all__ = [
    "Choice", "Method", "Colony", "Objective", "WidthRule", "WidthSearch", "RefineMode", "RefineLoss", "Solver",
    "InputScaling", "Integrator", "Friction", "Dtype", "Robust", "PathName", "Learner", "Target", "Trajectory",
    "SELECTORS", "BASE_CONTROLLERS", "CONTROL_CENTER_METHODS", "MAX_SEED", "ROBOT_PRESETS", "validate_robot",
    "RobotConfig", "DataConfig", "ACOConfig", "RefineConfig", "CentersConfig", "GrowthConfig",
    "RBFNConfig", "TrainConfig", "GainsConfig", "NetworkConfig", "ControlConfig", "OnlineConfig",
    "EvalConfig", "validate_train", "validate_evaluate", "validate_control", "validate_online",
    "validate_device", "finite", "plain", "register_configs",
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


class WidthRule(Choice):
    paper = "paper"
    vars()["global"] = "global"        # a keyword, so set through the class namespace
    per_center = "per_center"


class WidthSearch(Choice):
    per_center = "per_center"
    scale = "scale"
    none = "none"


class RefineMode(Choice):
    auto = "auto"              # full where N P^2 <= 2e9
    full = "full"
    minibatch = "minibatch"


class RefineLoss(Choice):      # minibatch: the error J(q) dq, or dq itself
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
    euler = "euler"            # semi-implicit


class Friction(Choice):
    sign = "sign"
    smooth = "smooth"          # tanh(qd / 0.01)


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


class Target(Choice):          # IK input
    position = "position"      # (B, 3) m
    pose = "pose"              # (B, 7) m + quaternion


class Trajectory(Choice):      # the desired joint path of the closed loop
    paper = "paper"
    sinusoid = "sinusoid"


# Presets of the `centers` group (conf/centers/NAME.yaml); a label, recorded with every run.
SELECTORS = ("aco", "aco_paper", "kmeans", "kmeans_refine", "random", "ols")
# Controllers by name; the adaptive RBFN is arbfn_<one of CONTROL_CENTER_METHODS>.
BASE_CONTROLLERS = ("pd", "ctc", "smc", "smc_obs")
CONTROL_CENTER_METHODS = ("aco", "aco_cluster", "kmeans", "random", "grid")
# Robots whose URDF ships with the package (conf/robot/NAME.yaml; rbfn/robots/NAME.urdf).
ROBOT_PRESETS = ("scara", "ur5", "panda")
# Seeds feed scikit-learn's random_state (< 2**32) and derive data streams seed * 1000 + k.
MAX_SEED = 2**32 - 1
# Useful widths, as multiples of a width rule's base (the paper's d_max / sqrt(2M), or the mean
# distance to the nearest centres): validation chooses among 0.25 .. 64 (rbfn.widths.SCALE_GRID).
# Below 1/16, a Gaussian is exp(-128) ~ 3e-56 half-way to the next centre: the network is its bias
# alone between centres (and float32 features underflow to zero).
MIN_WIDTH_SCALE = 1.0 / 16.0
MAX_WIDTH_SCALE = 1024.0
PILOT_STRIDE = 10          # the control network's pilot run is sampled every 10 control periods


# ----------------------------------------------------------------------------------------- train
@dataclass
class RobotConfig:
    """The robot (group `robot`: scara, ur5, panda; or any serial URDF with `urdf` and `end_link`).

    Joint values are in the URDF's units (rad, or m for prismatic joints), in the URDF's joint
    order along the chain root -> end link, `locked` joints excluded from the box and the IK output.
    """

    name: str = "scara"                # the preset's label; with `urdf` empty, its packaged URDF
    urdf: str = ""                     # a URDF file; empty: the packaged URDF of `name`
    end_link: str = "quill"
    target: Target = Target.position           # position (B, 3) | pose (B, 7)
    joint_low: list[float] = field(default_factory=lambda: [0.0, 0.3, 0.5])   # the IK branch's box
    joint_high: list[float] = field(default_factory=lambda: [2.0, 2.0, 1.5])
    locked: dict[str, float] = field(default_factory=dict)   # joint name -> held value (redundant arms)
    rotation_scale: float = 0.3        # m per unit of the rotation features (pose targets)
    gravity: Optional[float] = None    # m/s^2 along -z of the root; null: 9.8 for the scara, else 9.81
    trajectory: Trajectory = Trajectory.paper  # closed loop's desired joints
    home: list[float] = field(default_factory=list)   # sinusoid centre per joint; empty: the box centre
    amplitude: float = 0.1             # sinusoid amplitude, a fraction of each joint's half range
    rated_payload: float = 20.0        # kg: control payload cases default to 0, half and all of it


@dataclass
class DataConfig:
    n_train: int = 2000
    n_val: int = 1000
    n_test: int = 5000


@dataclass
class ACOConfig:
    colony: Colony = Colony.acor
    objective: Objective = Objective.fit
    iterations: int = 100              # NC_max
    ants: int = 20                     # ants per iteration
    archive_size: int = 20             # ACO_R archive k
    q: float = 0.2                     # ACO_R rank locality
    xi: float = 0.85                   # ACO_R spread
    init_spread: float = 0.3           # ACO_R seed perturbation, in nearest-centre distances
    search_widths: WidthSearch = WidthSearch.per_center  # ACO_R also searches widths
    rho: float = 0.9                   # Ant System evaporation
    Q: float = 100.0                   # Ant System deposit
    alpha: float = 1.0                 # Ant System pheromone exponent
    beta: float = 0.0                  # Ant System heuristic exponent (visibility: local data density)
    candidates: int = 500              # Ant System / OLS candidate pool
    fit_rows: int = 2048               # fit objective: the colony ranks ants on at most max(fit_rows, 50 P) training
                                       # and validation rows (a seeded subset; 0: every row); the final fit uses all


@dataclass
class RefineConfig:
    enabled: bool = False
    mode: RefineMode = RefineMode.auto  # full (weights solved in the loss) | minibatch
    steps: int = 300                   # full: Adam steps on the whole training set
    lr: float = 0.01                   # full: Adam step size
    epochs: int = 300                  # minibatch: passes over the training set
    batch: int = 256                   # minibatch: rows per Adam step
    batch_lr: float = 0.003            # minibatch: first Adam step size, decayed to 0 on a cosine
    loss: RefineLoss = RefineLoss.task  # minibatch: task error (m; rotation x robot.rotation_scale) | joint error
    huber: float = 0.005               # minibatch: pseudo-Huber threshold on a row's error norm (m for task);
                                       # 0: squared
    learn_input_scale: bool = True
    min_ridge: float = 1e-11           # floor on the relative ridge inside the loss (conditioning)


@dataclass
class CentersConfig:
    name: str = "aco"                  # the preset's label, one of SELECTORS
    method: Method = Method.aco
    width_rule: WidthRule = WidthRule.per_center
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
    input_scaling: InputScaling = InputScaling.metres
    tail: bool = True                  # linear tail A z + b beside the Gaussians
    solver: Solver = Solver.lstsq
    lms_alpha0: float = 0.5
    lms_epochs: int = 50
    max_width: float = 2.0             # cap on widths, scaled units (float32 conditioning)
    # float32 deployment: a fit's rounding scale may reach this fraction of its own validation RMS
    # error per output where that exceeds the absolute 2e-6 (rad, m); 0: the absolute bound alone
    round_rel: float = 0.0
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


# -------------------------------------------------------------------------------------- evaluate
@dataclass
class GainsConfig:
    """Feedback and adaptation gains shared by every controller of a comparison (group `gains`: the
    robot's `paper` or `tuned` set, conf/gains/robot/<robot>_<set>.yaml). The torque gains K,
    epsilon, pd_kp, pd_kd and gamma act on joint j times `control.joint_scale` s_j (1 on the SCARA)."""

    K: float = 50.0                # N m s / rad (N s / m): s feedback
    Lambda: float = 20.0           # 1/s: sliding-surface slope
    epsilon: float = 0.05          # N m (N): robust term amplitude
    robust: Robust = Robust.sat    # sign | sat
    boundary: float = 0.01         # rad/s (m/s): saturation boundary layer width of sat(s / boundary)
    observer_gain: float = 1000.0  # 1/s: momentum-observer bandwidth
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
    aco: ACOConfig = field(default_factory=ACOConfig)


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
    controllers: list[str] = field(default_factory=lambda: ["pd", "ctc", "smc", "smc_obs", "arbfn_aco",
                                                            "arbfn_kmeans"])
    payloads: list[float] = field(default_factory=list)   # kg; empty: 0, half and all of robot.rated_payload
    payload_link: str = ""             # the link whose origin carries the payload; empty: robot.end_link
    duration: float = 10.0
    dt: float = 1e-3
    integrator: Integrator = Integrator.rk4
    payload_on: float = 1.0
    payload_off: float = 4.0
    friction: Friction = Friction.sign
    viscous: float = 12.0              # N m s/rad (N s/m) per unit joint scale
    coulomb: float = 0.2               # N m (N) per unit joint scale
    disturbance: float = 5.0           # N m (N) per unit joint scale
    disturbance_freq: float = 2.0      # rad/s
    joint_scale: list[float] = field(default_factory=list)   # per joint; empty: derived (see above)
    dtype: Dtype = Dtype.float64
    compile: bool = False              # torch.compile the fused step (slow to compile; for long runs)
    aot: bool = False                  # the step compiled ahead of time, cached on disk (minutes once per
                                       # configuration)
    figure_payload: Optional[float] = None   # kg, the case drawn in the figures; null: half the rated payload
    network: NetworkConfig = field(default_factory=NetworkConfig)


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
    duration: float = 20.0             # s
    dt: float = 1e-3                   # s
    path: Optional[PathName] = None    # null: paper (SCARA), sinusoid (URDF arms)
    amplitude: float = 0.25            # sinusoid path: per joint amplitude / half the trained box range
    link_error: list[float] = field(default_factory=lambda: [0.03, -0.02])    # relative, links 1, 2, ...
    offset_error: list[float] = field(default_factory=lambda: [0.02, 0.0, 0.0])  # joints 1, 2, ... (rad or m)
    sizes: list[float] = field(default_factory=lambda: [0.0, 0.01, 0.03, 0.05])  # link-1 errors
    learner: Learner = Learner.nlms
    alpha0: float = 0.5                # NLMS step alpha(0)
    decay: float = 0.0                 # s; alpha(t) = alpha0 / (1 + t / decay); 0: constant
    forgetting: float = 0.9995         # RLS forgetting factor
    update_every: int = 10             # control periods per update (the pairs of one mini-batch)
    aot: bool = False                  # the closed-loop chunk compiled ahead of time, cached on disk (as control.aot)
    save_checkpoint: bool = True       # write checkpoint_online.pt (the configured perturbation's network)


@dataclass
class EvalConfig:
    checkpoint: Optional[str] = None   # null: the newest checkpoint.pt under outputs_dir
    outputs_dir: str = "outputs"
    ik: bool = True                    # the IK accuracy part (needs a checkpoint)
    n_test: int = 10000
    seed: Optional[int] = None         # null: the checkpoint's training seed; the test stream is derived
    device: str = "cpu"
    num_threads: int = 0               # torch threads; 0: torch's default, or one per process while the parts
                                       # run side by side
    parallel: bool = True              # checkpoint parts, half the control figures in forked processes
                                       # (fork, CPU, >= 2 cores)
    robot: RobotConfig = field(default_factory=RobotConfig)   # the control part's robot (IK: the checkpoint's)
    gains: GainsConfig = field(default_factory=GainsConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    online: OnlineConfig = field(default_factory=OnlineConfig)


# ------------------------------------------------------------------------------------ validation
def _need(ok: bool, key: str, value: Any, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{key}={value!r} is not allowed: {allowed}")


def finite(x: Any) -> bool:
    """Whether `x` is a finite int or float (not a bool): the check every numeric setting passes."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def validate_device(device: str, num_threads: int, prefix: str = "") -> None:
    """`device` is cpu or an available cuda[:N]; `num_threads` >= 0."""
    _need(isinstance(num_threads, int) and num_threads >= 0, f"{prefix}num_threads", num_threads,
          "use 0 (torch's default) or a positive number of threads")
    d = str(device)
    ok = d == "cpu" or d == "cuda" or (d.startswith("cuda:") and d[5:].isdigit())
    _need(ok, f"{prefix}device", device, "use 'cpu', 'cuda' or 'cuda:N'")
    if d != "cpu":
        import torch  # a runtime fact, not a schema one

        if not torch.cuda.is_available():
            raise ValueError(f"{prefix}device={device!r}: no CUDA device is available to this torch "
                             f"(torch {torch.__version__}, built for CUDA {torch.version.cuda}); use device=cpu")
        n = torch.cuda.device_count()
        if d.startswith("cuda:") and int(d[5:]) >= n:
            raise ValueError(f"{prefix}device={device!r}: only {n} CUDA device(s) (cuda:0..cuda:{n - 1})")


def _seed(key: str, seed: Any) -> None:
    _need(isinstance(seed, int) and 0 <= seed <= MAX_SEED, key, seed, f"use an integer in [0, {MAX_SEED}]")


def validate_train(cfg: TrainConfig) -> None:
    """Raise ValueError naming the first bad value of a training config."""
    c, r, d, a = cfg.centers, cfg.rbfn, cfg.data, cfg.centers.aco
    _need(c.name in SELECTORS, "centers.name", c.name, f"choose one of {list(SELECTORS)}")
    _need(d.n_train >= 2, "data.n_train", d.n_train, "must be >= 2 (widths come from distances between samples)")
    for name in ("n_val", "n_test"):
        _need(getattr(d, name) > 0, f"data.{name}", getattr(d, name), "must be > 0")
    _need(r.num_centers > 0, "rbfn.num_centers", r.num_centers, "must be > 0")
    _need(r.num_centers <= d.n_train, "rbfn.num_centers", r.num_centers,
          f"exceeds the training set size data.n_train={d.n_train}; use at most {d.n_train} centres")
    _need(c.width_scale is None or (finite(c.width_scale) and MIN_WIDTH_SCALE <= c.width_scale <= MAX_WIDTH_SCALE),
          "centers.width_scale", c.width_scale,
          f"must be null (chosen on validation) or in [{MIN_WIDTH_SCALE:g}, {MAX_WIDTH_SCALE:g}] times the width "
          f"rule's base: narrower Gaussians vanish between the centres, and the network returns its bias alone")
    _need(c.kmeans_restarts >= 1, "centers.kmeans_restarts", c.kmeans_restarts, "must be >= 1")
    _need(finite(r.max_width) and r.max_width > 0, "rbfn.max_width", r.max_width, "must be > 0")
    _need(finite(r.round_rel) and 0 <= r.round_rel < 1, "rbfn.round_rel", r.round_rel, "must be in [0, 1)")
    if c.method == Method.ols or (c.method == Method.aco and a.colony == Colony.ant_system):
        _need(a.candidates >= r.num_centers, "centers.aco.candidates", a.candidates,
              f"must be >= rbfn.num_centers={r.num_centers}")
    _validate_aco(a, "centers.aco")
    rf = c.refine
    _need(rf.steps >= 0, "centers.refine.steps", rf.steps, "must be >= 0")
    _need(finite(rf.lr) and rf.lr > 0, "centers.refine.lr", rf.lr, "must be > 0")
    _need(rf.epochs >= 0, "centers.refine.epochs", rf.epochs, "must be >= 0")
    _need(rf.batch >= 1, "centers.refine.batch", rf.batch, "must be >= 1")
    _need(finite(rf.batch_lr) and rf.batch_lr > 0, "centers.refine.batch_lr", rf.batch_lr, "must be > 0")
    _need(finite(rf.huber) and rf.huber >= 0, "centers.refine.huber", rf.huber, "must be >= 0 (0: squared error)")
    _need(finite(rf.min_ridge) and rf.min_ridge >= 0, "centers.refine.min_ridge", rf.min_ridge, "must be >= 0")
    _need(0 < r.lms_alpha0 < 2, "rbfn.lms_alpha0", r.lms_alpha0, "must be in (0, 2)")
    _need(r.lms_epochs >= 1, "rbfn.lms_epochs", r.lms_epochs, "must be >= 1")
    validate_robot(cfg.robot)
    g = r.growth
    _need(g.start >= 0, "rbfn.growth.start", g.start, "must be >= 0 (0: no growth)")
    _need(finite(g.factor) and g.factor > 1.0, "rbfn.growth.factor", g.factor, "must be > 1")
    _need(finite(g.goal) and g.goal >= 0, "rbfn.growth.goal", g.goal, "must be >= 0")
    _seed("seed", cfg.seed)
    validate_device(cfg.device, cfg.num_threads)
    _train_fits(cfg)


def _train_fits(cfg: TrainConfig) -> None:
    """The training set and the least-squares design matrix (float64) fit in memory."""
    from .memory import FLOAT64, check_fits  # a runtime fact, not a schema one

    d, n_q = cfg.data, len(cfg.robot.joint_low)
    pose = cfg.robot.target == Target.pose
    row = (7 if pose else 3) + n_q                         # target and joints of one sample
    p = cfg.rbfn.num_centers + (9 if pose else 3) + 1      # design columns: M Gaussians, the tail, a bias
    parts = {"n_train": d.n_train * (row + p), "n_val": d.n_val * row, "n_test": d.n_test * row}
    key = max(parts, key=lambda k: parts[k])
    check_fits(f"data.{key}", getattr(d, key), sum(parts.values()) * FLOAT64, cfg.device,
               f"float64 samples of data.n_train + n_val + n_test and the data.n_train x {p} least-squares "
               f"design matrix of rbfn.num_centers={cfg.rbfn.num_centers}")
    if cfg.centers.method == Method.aco:
        _colony_fits(cfg.centers.aco, "centers.aco", cfg.rbfn.num_centers, 9 if pose else 3, cfg.device,
                     pool=min(cfg.centers.aco.candidates, d.n_train))


def _colony_fits(a: ACOConfig, key: str, m: int, d: int, device: str, pool: int) -> None:
    """One colony iteration fits in memory: every ant's M centres (d) and widths, and for the Ant
    System its choice probabilities over the `pool` candidates, at once. (With the fit objective
    ACO_R's ants are bounded by its budget; the objective ranks ants in batches of bounded memory.)"""
    from .memory import FLOAT64, check_fits

    if a.colony == Colony.ant_system:
        check_fits(f"{key}.ants", a.ants, a.ants * (pool + m * (d + 1)) * FLOAT64, device,
                   f"one iteration's choice probabilities over {pool} candidates and M = {m} centres and widths "
                   "per ant, in float64")
    elif a.objective != Objective.fit:     # (the fit objective's budget bounds ACO_R's ants)
        check_fits(f"{key}.ants", a.ants, a.ants * m * (d + 1) * FLOAT64, device,
                   f"one iteration's M = {m} centres and widths per ant, in float64")


def validate_robot(r: RobotConfig) -> None:
    """Raise ValueError naming the first bad value of `robot.*` (the URDF itself is checked on load)."""
    lo, hi = r.joint_low, r.joint_high
    _need(len(lo) == len(hi) and len(lo) > 0, "robot.joint_low", list(lo),
          f"robot.joint_low and robot.joint_high ({list(hi)}) need one value per joint each")
    for i, (l, h) in enumerate(zip(lo, hi)):
        if not (finite(l) and finite(h) and l < h):
            raise ValueError(f"robot.joint_low/joint_high: empty or invalid range for joint {i + 1}: "
                             f"[{l}, {h}] (robot.joint_low < robot.joint_high required)")
    _need(r.urdf != "" or r.name in ROBOT_PRESETS, "robot.name", r.name,
          f"with robot.urdf empty, choose a packaged robot: {list(ROBOT_PRESETS)} (or give robot.urdf=PATH)")
    for j, v in r.locked.items():
        _need(finite(v), f"robot.locked.{j}", v, "must be a finite joint value")
    _need(finite(r.rotation_scale) and r.rotation_scale > 0, "robot.rotation_scale", r.rotation_scale, "must be > 0 m")
    _need(r.gravity is None or (finite(r.gravity) and r.gravity >= 0), "robot.gravity", r.gravity,
          "must be >= 0 m/s^2 or null")
    _need(len(r.home) in (0, len(lo)) and all(finite(v) for v in r.home), "robot.home", list(r.home),
          f"empty (the box centre) or one finite value per joint ({len(lo)})")
    _need(finite(r.amplitude) and 0 <= r.amplitude <= 1, "robot.amplitude", r.amplitude, "must be in [0, 1]")
    _need(finite(r.rated_payload) and r.rated_payload >= 0, "robot.rated_payload", r.rated_payload, "must be >= 0 kg")


def _validate_aco(a: ACOConfig, key: str) -> None:
    _need(a.iterations >= 0, f"{key}.iterations", a.iterations, "must be >= 0")
    _need(a.ants >= 1, f"{key}.ants", a.ants, "must be >= 1")
    _need(a.archive_size >= 2, f"{key}.archive_size", a.archive_size, "must be >= 2")
    _need(finite(a.q) and a.q > 0, f"{key}.q", a.q, "must be > 0")
    _need(finite(a.xi) and a.xi > 0, f"{key}.xi", a.xi, "must be > 0")
    _need(finite(a.init_spread) and a.init_spread >= 0, f"{key}.init_spread", a.init_spread, "must be >= 0")
    _need(finite(a.rho) and 0 < a.rho < 1, f"{key}.rho", a.rho, "must be in (0, 1)")
    _need(finite(a.Q) and a.Q > 0, f"{key}.Q", a.Q, "must be > 0")
    _need(finite(a.alpha) and a.alpha >= 0, f"{key}.alpha", a.alpha, "must be >= 0")
    _need(finite(a.beta) and a.beta >= 0, f"{key}.beta", a.beta, "must be >= 0")
    _need(a.candidates >= 1, f"{key}.candidates", a.candidates, "must be >= 1")
    _need(a.fit_rows >= 0, f"{key}.fit_rows", a.fit_rows, "must be >= 0 (0: every row)")


def validate_control(c: ControlConfig, gains: GainsConfig) -> None:
    """Raise ValueError naming the first bad value of the control part (`control.*`, `gains.*`)."""
    arbfn = [f"arbfn_{m}" for m in CONTROL_CENTER_METHODS]
    for name in c.controllers:
        _need(name in BASE_CONTROLLERS or name in arbfn, "control.controllers", name,
              f"choose from {list(BASE_CONTROLLERS + tuple(arbfn))}")
    _need(len(set(c.controllers)) == len(c.controllers), "control.controllers", list(c.controllers),
          "each controller may appear once")
    _need(not (c.compile and c.aot), "control.aot", c.aot, "choose one of control.compile and control.aot")
    for k, v in vars(gains).items():
        if isinstance(v, float):
            _need(math.isfinite(v), f"gains.{k}", v, "must be finite")
    for k in ("K", "Lambda", "boundary", "observer_gain", "gamma_decay"):
        _need(getattr(gains, k) > 0, f"gains.{k}", getattr(gains, k), "must be > 0")
    for k in ("epsilon", "gamma", "leakage", "pd_kp", "pd_kd"):
        _need(getattr(gains, k) >= 0, f"gains.{k}", getattr(gains, k), "must be >= 0")
    _need(finite(c.dt) and c.dt > 0, "control.dt", c.dt, "must be a positive number of seconds")
    _need(finite(c.duration) and c.duration >= c.dt, "control.duration", c.duration,
          f"must be finite and >= control.dt={c.dt}")
    _need(finite(c.payload_on) and finite(c.payload_off) and 0 <= c.payload_on < c.payload_off <= c.duration,
          "control.payload_on/payload_off", [c.payload_on, c.payload_off],
          f"need 0 <= payload_on < payload_off <= control.duration={c.duration}")
    _need(0.5 < c.duration, "control.duration", c.duration, "must exceed 0.5 s (errors are measured after 0.5 s)")
    _need(all(finite(p) and p >= 0 for p in c.payloads), "control.payloads",
          list(c.payloads), "a list of masses >= 0 kg (empty: 0, half and all of robot.rated_payload)")
    _need(len(set(c.payloads)) == len(c.payloads), "control.payloads", list(c.payloads),
          "each payload case may appear once (cases are keyed by mass)")
    _need(c.figure_payload is None or finite(c.figure_payload), "control.figure_payload", c.figure_payload,
          "must be a finite mass in kg or null")
    for k in ("viscous", "coulomb", "disturbance", "disturbance_freq"):
        _need(finite(getattr(c, k)) and getattr(c, k) >= 0, f"control.{k}", getattr(c, k), "must be finite and >= 0")
    _need(all(finite(v) and v > 0 for v in c.joint_scale), "control.joint_scale", list(c.joint_scale),
          "positive finite factors, one per joint (empty: derived from the robot)")
    n = c.network
    _need(n.num_centers >= 1, "control.network.num_centers", n.num_centers, "must be >= 1")
    if any(name.startswith("arbfn_") for name in c.controllers):
        steps = int(round(c.duration / c.dt))
        n_train = (steps // PILOT_STRIDE + 1) // 2      # even pilot samples train the network
        _need(n.num_centers <= n_train, "control.network.num_centers", n.num_centers,
              f"exceeds the pilot run's {n_train} training samples (control.duration={c.duration} s, "
              f"one sample per {PILOT_STRIDE} periods, half of them for training)")
        _seed("control.network.seed", n.seed)
        _validate_aco(n.aco, "control.network.aco")
        # (desired states of one joint at least: d >= 2; candidates at most the pilot's training samples)
        _colony_fits(n.aco, "control.network.aco", n.num_centers, 2, "cpu", pool=min(n.aco.candidates, n_train))


def _trajectory_fits(key: str, duration: float, dt: float, batch: int, columns: int, device: str) -> None:
    """A run of duration / dt steps recording `columns` float64 values per step for `batch`
    environments fits in memory."""
    from .memory import FLOAT64, check_fits

    steps = duration / dt + 1
    check_fits(key, duration, steps * batch * columns * FLOAT64, device,
               f"{steps:.3g} steps of {dt:g} s, each recording {columns} float64 values for {batch} run(s)")


def validate_online(c: OnlineConfig) -> None:
    """Raise ValueError naming the first bad value of the online part (`online.*`)."""
    _need(finite(c.dt) and c.dt > 0, "online.dt", c.dt, "must be a positive number of seconds")
    _need(finite(c.duration) and c.duration >= 4.0, "online.duration", c.duration,
          "must be >= 4 s (the metrics use the first and last 2 s)")
    _need(len(c.link_error) > 0 and all(finite(v) and v > -1 for v in c.link_error), "online.link_error",
          list(c.link_error), "relative errors > -1 of links 1, 2, ... (at least link 1)")
    _need(all(finite(v) for v in c.offset_error), "online.offset_error", list(c.offset_error),
          "finite joint offsets (rad or m) of joints 1, 2, ...")
    _need(finite(c.amplitude) and 0 < c.amplitude <= 0.5, "online.amplitude", c.amplitude,
          "must be in (0, 0.5] (the sinusoid path's two terms then stay inside the trained box)")
    _need(len(c.sizes) > 0 and all(finite(s) for s in c.sizes), "online.sizes", list(c.sizes),
          "a non-empty list of link-1 errors")
    ref = c.link_error[0]
    _need(ref != 0 or all(s == 0 for s in c.sizes), "online.sizes", list(c.sizes),
          "sizes scale the configured perturbation by its link-1 error, and online.link_error[0] is 0")
    _need(any(math.isclose(s, ref, rel_tol=1e-9, abs_tol=1e-12) for s in c.sizes), "online.sizes",
          list(c.sizes), f"must include online.link_error[0]={ref}, the configured perturbation")
    _need(0 <= c.alpha0 < 2, "online.alpha0", c.alpha0, "must be in [0, 2)")
    _need(finite(c.decay) and c.decay >= 0, "online.decay", c.decay, "must be >= 0")
    _need(0 < c.forgetting <= 1, "online.forgetting", c.forgetting, "must be in (0, 1]")
    _need(c.update_every >= 1, "online.update_every", c.update_every, "must be >= 1")


def validate_evaluate(cfg: EvalConfig) -> None:
    """Raise ValueError naming the first bad value of an evaluation config (every part)."""
    _need(cfg.n_test > 0, "n_test", cfg.n_test, "must be > 0")
    if cfg.seed is not None:
        _seed("seed", cfg.seed)
    validate_device(cfg.device, cfg.num_threads)
    validate_robot(cfg.robot)
    if cfg.control.enabled:
        validate_control(cfg.control, cfg.gains)
    if cfg.online.enabled:
        validate_online(cfg.online)
    _evaluate_fits(cfg)


def _evaluate_fits(cfg: EvalConfig) -> None:
    """The test set, the recorded closed loops and the online runs fit in memory (lower bounds)."""
    from .memory import FLOAT64, check_fits

    if cfg.ik:    # targets (up to 7), joints (up to 7 free ones assumed), FK poses (16) per sample
        check_fits("n_test", cfg.n_test, cfg.n_test * (7 + 7 + 16) * FLOAT64, cfg.device,
                   "float64 test targets, joints and forward-kinematics poses")
    n = len(cfg.robot.joint_low)
    c = cfg.control
    if c.enabled:   # q, qd and tau (n each) recorded every step, for each payload case at least
        _trajectory_fits("control.duration", c.duration, c.dt, max(1, len(c.payloads)), 3 * n, cfg.device)
    o = cfg.online
    if o.enabled:   # joints and task position recorded every step, for each perturbation size
        _trajectory_fits("online.duration", o.duration, o.dt, len(o.sizes), 3 + 3, cfg.device)


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
