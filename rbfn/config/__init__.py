"""Every configuration schema and every allowed name; validation done once at the edge.

The package is the bottom layer of `rbfn`: it imports nothing else from it, nor Hydra. One module
per concern, each schema's `check` method beside its fields (raising ValueError that names the
full key, the bad value and what is allowed):

- `base`: the named option `Choice`, the type check of a whole config (`check_types`), the device
  and thread check, the small checks the schemas share;
- `robot`: `RobotConfig` (group `robot`);
- `training`: train.py's `TrainConfig` and its parts (data, centres, colonies, refinement, growth,
  network);
- `control`: the closed loop's gains, adaptive network and its methods, tuning,
  pick-and-place and scenario (`ControlConfig`);
- `loop`: how real the loop is (`LoopConfig`, group `loop`);
- `online`: the online part (`OnlineConfig`);
- `evaluation`: evaluate.py's `EvalConfig`.

train.py and evaluate.py register the schemas with Hydra's ConfigStore
(`rbfn.studies.cli.register_configs`), so a mistyped value or an unknown choice (an Enum field)
fails when the config is composed, naming the options; `validate_train` / `validate_evaluate` run
the checks once, before any work starts. Everything is importable from `rbfn.config` itself.
"""

from .base import (
    MAX_SEED,
    MAX_THREADS_PER_CPU,
    Choice,
    Dtype,
    check_types,
    finite,
    from_mapping,
    plain,
    validate_device,
)
from .control import (
    ADAPTIVE,
    BASE_CONTROLLERS,
    CLOSED_LOOP_SEARCHES,
    CONTROL_CENTER_METHODS,
    NETWORK_METHODS,
    PILOT_STRIDE,
    ControlConfig,
    Feedforward,
    Friction,
    GainsConfig,
    Integrator,
    NetworkConfig,
    NetworkLaw,
    NetworkMethod,
    NetworkObjective,
    PickAndPlaceConfig,
    Robust,
    Trajectory,
    TuneConfig,
    network_method,
)
from .evaluation import EvalConfig, validate_evaluate
from .loop import LoopConfig
from .online import Learner, OnlineConfig, PathName
from .robot import ROBOT_PRESETS, RobotConfig, Target, Workspace
from .training import (
    MAX_WIDTH_SCALE,
    MIN_WIDTH_SCALE,
    SELECTORS,
    ACOConfig,
    ACORConfig,
    AntSystemConfig,
    CentersConfig,
    Colony,
    DataConfig,
    FullRefineConfig,
    GrowthConfig,
    InputScaling,
    Method,
    MinibatchRefineConfig,
    Objective,
    OLSConfig,
    RBFNConfig,
    RefineConfig,
    RefineLoss,
    RefineMode,
    Solver,
    TrainConfig,
    WidthRule,
    WidthSearch,
    validate_train,
)

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
    "ADAPTIVE",
    "NETWORK_METHODS",
    "NetworkMethod",
    "network_method",
    "MAX_SEED",
    "MAX_THREADS_PER_CPU",
    "MIN_WIDTH_SCALE",
    "MAX_WIDTH_SCALE",
    "PILOT_STRIDE",
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
    "Feedforward",
    "TuneConfig",
    "ControlConfig",
    "PickAndPlaceConfig",
    "OnlineConfig",
    "LoopConfig",
    "EvalConfig",
    "validate_train",
    "validate_evaluate",
    "check_types",
    "from_mapping",
    "validate_device",
    "finite",
    "plain",
]
