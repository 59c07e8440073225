"""Every config option composes; bad values fail early with a message naming the full key and value."""

import re
import subprocess
import sys

import pytest
import torch
from hydra.errors import MissingConfigException

import train
from rbfn.config import SELECTORS, EvalConfig, validate_evaluate, validate_train
from rbfn.data import check_finite
from rbfn.memory import check_evaluate, check_train

from .conftest import PANDA_HELD, compose_config


def _cfg(*overrides: str):
    return compose_config("train", *overrides)


@pytest.mark.parametrize("name", SELECTORS)
def test_every_centers_option_composes_and_validates(name):
    cfg = _cfg(f"centers={name}")
    assert cfg.centers.name == name
    validate_train(cfg)


def test_evaluate_config_composes():
    cfg = compose_config("evaluate", "checkpoint=x.pt")
    assert cfg.checkpoint == "x.pt"
    validate_evaluate(cfg)


def test_unknown_selector_names_it():
    with pytest.raises(MissingConfigException, match="foo"):
        _cfg("centers=foo")


@pytest.mark.parametrize(
    "override,options",
    [
        ("rbfn.num_centers=many", "num_centers"),
        ("centers.aco.colony=magic", "expected one of [acor, ant_system]"),
        ("centers.width_rule=wide", "expected one of [paper, global, per_center]"),
        ("rbfn.solver=adam", "expected one of [lstsq, lms]"),
        ("centers.refine.mode=sgd", "expected one of [auto, full, minibatch]"),
        ("centers.refine.minibatch.loss=mse", "expected one of [task, joint]"),
    ],
)
def test_mistyped_value_fails_at_composition(override, options):
    with pytest.raises(Exception) as e:
        _cfg(override)
    assert options in f"{e.value} {e.value.__cause__}"


@pytest.mark.parametrize(
    "override,match",
    [
        ("rbfn.num_centers=0", "rbfn.num_centers=0"),
        ("rbfn.num_centers=-3", "rbfn.num_centers=-3"),
        ("rbfn.num_centers=5000", "rbfn.num_centers=5000 is not allowed: exceeds"),
        ("centers.width_scale=-1.0", "centers.width_scale=-1.0"),
        ("centers.name=bogus", "centers.name='bogus'"),
        ("robot.joint_high=[2.0,0.3,1.5]", "joint 2"),
        ("robot.joint_high=[2.0,2.0]", "robot.joint_low"),
        ("centers.aco.ant_system.rho=1.5", "centers.aco.ant_system.rho=1.5"),
        ("centers.aco.acor.q=0", "centers.aco.acor.q=0"),
        ("centers.aco.ant_system.beta=-1", "centers.aco.ant_system.beta=-1"),
        ("centers.refine.full.lr=0", "centers.refine.full.lr=0"),
        ("centers.refine.minibatch.batch=0", "centers.refine.minibatch.batch=0"),
        ("centers.refine.minibatch.lr=-1", "centers.refine.minibatch.lr=-1"),
        ("centers.refine.minibatch.epochs=-1", "centers.refine.minibatch.epochs=-1"),
        ("centers.refine.minibatch.huber=-0.1", "centers.refine.minibatch.huber=-0.1"),
        ("centers.aco.fit_rows=-5", "centers.aco.fit_rows=-5"),
        ("rbfn.growth.factor=1.0", "rbfn.growth.factor=1.0"),
        ("device=tpu", "device='tpu'"),
        ("seed=-1", "seed=-1 is not allowed: use an integer in [0, 4294967295]"),
        ("seed=5000000000", "seed=5000000000"),
        ("num_threads=-2", "num_threads=-2"),
    ],
)
def test_bad_values_fail_with_message(override, match):
    with pytest.raises(ValueError, match=re.escape(match)):
        validate_train(_cfg(override))


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message on a machine without a GPU")
def test_cuda_without_a_gpu_is_named():
    with pytest.raises(ValueError, match="device='cuda': no CUDA device is available"):
        validate_train(_cfg("device=cuda"))


@pytest.mark.parametrize(
    "field,value,match",
    [
        ("n_test", 0, "n_test=0"),
        ("seed", -4, "seed=-4"),
        ("device", "gpu", "device='gpu'"),
        ("num_threads", -1, "num_threads=-1"),
    ],
)
def test_bad_evaluate_values(field, value, match):
    cfg = EvalConfig(**{field: value})
    with pytest.raises(ValueError, match=match):
        validate_evaluate(cfg)


def test_nan_in_data_is_named():
    x = torch.zeros(5, 3)
    x[2, 1] = float("nan")
    with pytest.raises(ValueError, match=r"train positions contains non-finite values .first at row 2"):
        check_finite("train positions", x)


def test_nan_in_training_data_stops_run_before_any_write(tmp_path, monkeypatch):
    import rbfn.studies.training

    real = rbfn.studies.training.make_dataset

    def poisoned(*a, **k):
        d = real(*a, **k)
        d.train.x[7, 0] = float("nan")
        return d

    monkeypatch.setattr(rbfn.studies.training, "make_dataset", poisoned)
    cfg = _cfg("data.n_train=50", "data.n_val=20", "data.n_test=20", "rbfn.num_centers=5", "progress=false")
    with pytest.raises(ValueError, match=r"train positions contains non-finite values .first at row 7"):
        train.run(cfg, tmp_path / "run")
    assert list((tmp_path / "run").iterdir()) == []


def test_joint_range_outside_urdf_limits():
    from rbfn.robots.robot import load_robot

    with pytest.raises(ValueError, match=r"joint2 .* leaves the URDF limits"):
        load_robot(_cfg("robot.joint_high=[2.0,3.0,1.5]").robot)


@pytest.mark.parametrize("experiment", ["paper", "aco_vs_kmeans"])
def test_experiment_presets_compose(experiment):
    validate_train(_cfg(f"experiment={experiment}"))
    cfg = compose_config("train", f"experiment={experiment}", hydra=True)
    if experiment == "paper":
        assert cfg.centers.aco.colony == "ant_system" and cfg.centers.width_rule == "paper"
        assert (cfg.centers.aco.ant_system.rho, cfg.centers.aco.ant_system.Q, cfg.centers.aco.iterations) == (
            0.9,
            100.0,
            100,
        )
    else:
        assert cfg.hydra.sweeper.params["seed"] == "0,1,2,3,4"


@pytest.mark.parametrize("launcher,target", [("joblib", "JoblibLauncher"), ("slurm", "SlurmLauncher")])
def test_launchers_compose(launcher, target):
    pytest.importorskip(
        "hydra_plugins.hydra_joblib_launcher" if launcher == "joblib" else "hydra_plugins.hydra_submitit_launcher"
    )
    cfg = compose_config("train", f"hydra/launcher={launcher}", hydra=True)
    assert cfg.hydra.launcher._target_.endswith(target)


# --- settings that make a useless network, or cannot fit in memory, fail before any work ----------
@pytest.mark.parametrize(
    "override,key",
    [
        ("centers.width_scale=1e-30", "centers.width_scale"),
        ("centers.width_scale=0.01", "centers.width_scale"),
        ("centers.width_scale=1e9", "centers.width_scale"),
        ("data.n_train=1", "data.n_train"),
    ],
)
def test_settings_that_make_a_useless_network_are_refused_by_key(override, key):
    with pytest.raises(ValueError, match=re.escape(key)):
        validate_train(_cfg(override, "rbfn.num_centers=1"))


def test_a_useful_width_scale_is_accepted():
    validate_train(_cfg("centers.width_scale=0.25"))
    validate_train(_cfg("centers.width_scale=64"))


@pytest.mark.parametrize(
    "override,key",
    [
        ("data.n_train=1000000000000", "data.n_train"),
        ("data.n_val=1000000000000", "data.n_val"),
        ("data.n_test=1000000000000", "data.n_test"),
    ],
)
def test_training_sizes_that_cannot_fit_name_the_key_the_estimate_and_the_limit(override, key):
    # 1e12 rows need terabytes: more than any machine this runs on.
    with pytest.raises(
        ValueError,
        match=rf"{re.escape(key)}=1000000000000 needs at least [\d.]+ TiB .*"
        r"more than this machine's available memory \([\d.]+ \w+\)",
    ):
        check_train(_cfg(override))


def test_the_memory_estimate_is_held_against_what_is_available(monkeypatch):
    import rbfn.memory

    cfg = _cfg("data.n_train=100000", "rbfn.num_centers=1000")  # 100000 x 1004 float64: 0.75 GiB
    check_train(cfg)
    monkeypatch.setattr(rbfn.memory, "available_bytes", lambda device="cpu": 512 << 20)
    with pytest.raises(ValueError, match=r"data.n_train=100000 needs at least 7\d\d MiB .*\(512 MiB\)"):
        check_train(cfg)


@pytest.mark.parametrize(
    "override,key",
    [
        ("n_test=1000000000000", "n_test"),
        ("control.duration=1e12", "control.duration"),
        ("online.duration=1e12", "online.duration"),
    ],
)
def test_evaluation_sizes_that_cannot_fit_name_the_key(override, key):
    with pytest.raises(ValueError, match=rf"{re.escape(key)}=1.*needs at least .* more than this machine's"):
        check_evaluate(compose_config("evaluate", override))


def test_an_ant_system_colony_that_cannot_fit_names_its_ants():
    with pytest.raises(ValueError, match=r"centers\.aco\.ants=100000000000 needs at least .* TiB .*300 candidates"):
        check_train(
            _cfg("centers=aco_paper", "data.n_train=300", "rbfn.num_centers=10", "centers.aco.ants=100000000000")
        )
    check_train(_cfg("centers=aco", "centers.aco.ants=100000000000"))  # ACO_R's ants are bounded by its budget


def test_the_centers_presets_are_the_files_of_the_group():
    """SELECTORS (the labels TensorBoard's hparams domain lists) names exactly conf/centers/*.yaml,
    and each preset's `name` is its file's."""
    from .conftest import ROOT

    files = sorted(p.stem for p in (ROOT / "conf" / "centers").glob("*.yaml"))
    assert files == sorted(SELECTORS)
    for name in files:
        assert _cfg(f"centers={name}").centers.name == name


def test_the_python_api_checks_every_field_type():
    from dataclasses import replace

    from rbfn.config import DataConfig, TrainConfig

    cfg = _cfg()
    validate_train(cfg)
    for bad, message in [
        (replace(cfg, export=2), "export=2 is not allowed: must be true or false"),
        (replace(cfg, progress="yes"), "progress='yes' is not allowed: must be true or false"),
        (replace(cfg, data=DataConfig(n_train=1500.5)), "data.n_train=1500.5 is not allowed: must be an integer"),
        (replace(cfg, seed=True), "seed=True is not allowed: must be an integer"),
        (replace(cfg, robot=replace(cfg.robot, gravity=True)), "robot.gravity=True is not allowed: must be a number"),
        (replace(cfg, robot=replace(cfg.robot, home=[1.0, "a", 2.0])), "robot.home=[1.0, 'a', 2.0] is not allowed"),
        (replace(cfg, centers=replace(cfg.centers, method="magic")), "centers.method='magic' is not allowed: expected"),
        (replace(cfg, robot=replace(cfg.robot, locked={"j": None})), "robot.locked={'j': None} is not allowed"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            validate_train(bad)
    assert isinstance(TrainConfig(), TrainConfig)
    for key, value in [("control", "yes"), ("online", 1)]:
        part = getattr(EvalConfig(), key)
        with pytest.raises(ValueError, match=re.escape(f"{key}.aot={value!r} is not allowed: choose from ['auto'")):
            validate_evaluate(replace(EvalConfig(), **{key: replace(part, aot=value)}))


@pytest.mark.parametrize(
    "script,override", [("train.py", "export=2"), ("evaluate.py", "ik=yes"), ("evaluate.py", "control.enabled=1")]
)
def test_the_entry_points_refuse_a_bool_given_as_anything_else(tmp_path, script, override):
    import subprocess
    import sys

    from .conftest import ROOT

    r = subprocess.run(
        [sys.executable, script, override, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 1 and r.stderr.strip().splitlines() == [
        f"error: {override} is not allowed: must be true or false"
    ], r.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "overrides,message",
    [
        (
            ["robot=ur5", "robot.home=[0,-1.2,1.5,-1.9,9.0,0]"],
            "robot.home=[0.0, -1.2, 1.5, -1.9, 9.0, 0.0] is not allowed: joint wrist_2_joint at 9 lies outside "
            "its URDF limits [-6.28319, 6.28319]",
        ),
        (
            [*(o for o in PANDA_HELD if "locked" not in o), "+robot.locked.panda_joint3=3.5"],
            "robot.locked.panda_joint3=3.5 is not allowed: joint panda_joint3 at 3.5 lies outside its URDF limits "
            "[-2.8973, 2.8973]",
        ),
    ],
)
def test_joint_values_outside_the_urdf_limits_are_named(overrides, message):
    """Every joint-valued key (robot.home, robot.locked.*, the box) lies within the URDF's limits:
    training (load_robot) and the closed loop (check_control) refuse it naming the key, the joint,
    the value and the limits."""
    from rbfn.robots.robot import load_robot
    from rbfn.studies.control import check_control

    with pytest.raises(ValueError, match=re.escape(message)):
        load_robot(_cfg(*overrides).robot)
    cfg = compose_config("evaluate", "ik=false", "online.enabled=false", *overrides)
    with pytest.raises(ValueError, match=re.escape(message)):
        check_control(cfg.control, cfg.robot)


def test_the_closed_loop_checks_the_box_against_the_urdf_limits_too():
    from rbfn.studies.control import check_control

    cfg = compose_config("evaluate", "ik=false", "online.enabled=false", "robot.joint_high=[2.0,3.0,1.5]")
    with pytest.raises(
        ValueError, match=re.escape("robot.joint_high=[2.0, 3.0, 1.5] is not allowed: joint joint2 at 3")
    ):
        check_control(cfg.control, cfg.robot)


def test_num_threads_beyond_what_the_machine_can_run_is_refused():
    """torch's thread pool crashed the process (a segfault) at num_threads=100000."""
    import os

    from rbfn.config import MAX_THREADS_PER_CPU, validate_device

    most = MAX_THREADS_PER_CPU * (os.cpu_count() or 1)
    validate_device("cpu", most)
    with pytest.raises(ValueError, match=rf"num_threads=100000 is not allowed: .* up to {most} "):
        validate_device("cpu", 100_000)


def test_from_mapping_builds_a_schema_as_composition_does():
    """A YAML mapping becomes the schema Hydra would compose: choices from their names, integers
    as floats where a float is declared, the rest at its defaults; a key the schema lacks or a
    value of another type is named with its full key."""
    from rbfn.config import RobotConfig, Target, TrainConfig, from_mapping

    cfg = from_mapping(RobotConfig, {"target": "pose", "home": [0, 1], "rated_payload": 5, "locked": {"j": 1}})
    assert cfg.target is Target.pose and cfg.home == [0.0, 1.0] and isinstance(cfg.home[0], float)
    assert cfg.rated_payload == 5.0 and isinstance(cfg.rated_payload, float) and cfg.locked == {"j": 1.0}
    assert cfg.end_link == RobotConfig().end_link
    nested = from_mapping(TrainConfig, {"robot": {"name": "ur5"}, "seed": 3})
    assert nested.robot.name == "ur5" and nested.seed == 3
    for data, message in [
        ({"end_links": "x"}, "end_links is not a key of RobotConfig"),
        ({"target": "posture"}, "target='posture' is not allowed: expected one of ['position', 'pose']"),
        ({"home": [0, "a"]}, "home=[0, 'a'] is not allowed: each entry must be a number"),
        ({"derive": 1}, "derive=1 is not allowed: must be true or false"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            from_mapping(RobotConfig, data)
    with pytest.raises(ValueError, match=re.escape("robot.seed is not a key of RobotConfig")):
        from_mapping(TrainConfig, {"robot": {"seed": 1}})


def test_the_library_below_the_studies_imports_neither_hydra_nor_omegaconf():
    """Every module of rbfn outside rbfn.studies imports without Hydra or OmegaConf loading."""
    code = (
        "import importlib, pkgutil, sys, rbfn\n"
        "names = [m.name for m in pkgutil.walk_packages(rbfn.__path__, 'rbfn.') if not m.name.startswith('rbfn.studies')]\n"
        "[importlib.import_module(n) for n in names]\n"
        "print(len(names), sorted({k.split('.')[0] for k in sys.modules} & {'hydra', 'omegaconf'}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert int(out[0]) > 40 and out[1:] == ["[]"]
