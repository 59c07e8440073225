"""Shared fixtures: the SCARA chain, a small data set, and Hydra composition of the two entry points."""

import os
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from rbfn.config import RobotConfig
from rbfn.robots import load_serial_chain, scara
from rbfn.studies.cli import register_configs

torch.set_num_threads(1)
register_configs()
# control.aot and online.aot default to auto, which compiles the closed loop ahead of time on a CPU
# (a minute or more per package on a cold cache); the suite runs eagerly unless a test asks for
# compilation (its tests of compilation pass aot=True), and subprocesses inherit the setting.
os.environ.setdefault("ACO_RBFN_AOT", "0")

CONF = str(Path(__file__).resolve().parents[1] / "conf")
ROOT = Path(__file__).resolve().parents[1]


def compose_config(name: str, *overrides: str, hydra: bool = False):
    """The composed `name` config ("train" or "evaluate") as its dataclass (or, with `hydra`, the
    DictConfig including the hydra node)."""
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(name, overrides=list(overrides), return_hydra_config=hydra)
    return cfg if hydra else OmegaConf.to_object(cfg)


@pytest.fixture(autouse=True)
def _seeded():
    """Every test starts from the same global random state, whatever ran before it."""
    torch.manual_seed(0)


@pytest.fixture(autouse=True)
def _signals_as_they_were():
    """Every test leaves this process's stop-signal handlers as it found them, and rbfn.studies.stop
    not stopping: an entry point run in this process installs stop's handlers, and with the suite
    spread over worker processes any test may follow any other (a part forked with stop's handler
    can drop a SIGTERM sent before its start-up, which `Beside` re-sends; test_beside's timings
    assume the default handler where they do not set one)."""
    import signal

    from rbfn.files import STOP_SIGNALS
    from rbfn.studies import stop

    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    yield
    for s, handler in before.items():
        signal.signal(s, handler)
    stop._stopping = False


@pytest.fixture(scope="session")
def chain():
    return load_serial_chain(scara.URDF_PATH, scara.END_LINK, torch.float64)


@pytest.fixture(scope="session")
def scara_robot():
    from rbfn.robots.robot import load_robot

    return load_robot(RobotConfig())


@pytest.fixture(scope="session")
def small_data(scara_robot):
    from rbfn.data import make_dataset

    return make_dataset(scara_robot, (600, 300, 300), seed=3)


# The Panda preset with joint 3 held at 0 (robot.locked) and a box of the six others: the robot.locked path
PANDA_HELD = [
    "robot=panda",
    "robot.workspace=box",
    'robot.redundancy=""',
    "+robot.locked.panda_joint3=0.0",
    "robot.joint_low=[-1.0,-1.7628,-3.0718,-1.0,0.571,-0.215]",
    "robot.joint_high=[1.0,0.215,-1.356,1.0,2.571,1.785]",
    "robot.home=[0.0,-0.785,-2.356,0.0,1.571,0.785]",
]


@pytest.fixture(scope="session")
def panda_ckpt(tmp_path_factory):
    """A coarse Panda box network (40 centres, joint 3 locked: `PANDA_HELD`) as a checkpoint dict."""
    import train
    from rbfn.checkpoint import read_checkpoint

    out = tmp_path_factory.mktemp("panda")
    train.run(
        compose_config(
            "train",
            *PANDA_HELD,
            "centers=kmeans",
            "rbfn.num_centers=40",
            "rbfn.growth.start=0",
            "data.n_train=1500",
            "data.n_val=500",
            "data.n_test=200",
            "progress=false",
            "export=false",
            "num_threads=1",
        ),
        out,
    )
    return read_checkpoint(out / "checkpoint.pt")


def error_line(capsys, main, prog: str, *argv, status: int = 2) -> str:
    """The one stderr line of a command-line tool's refused `main(argv)`, `PROG: error: ...`, its
    exit status checked."""
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    assert e.value.code == status
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{prog}: error: "), err
    return err


# A training run of a few seconds (k-means, M = 10, one thread, no export): the studies' tests.
# The Panda with all 7 joints free, joint 3 the network's input beside the pose, in a +-1 rad box
# around the ready pose (robot=urdf on the shipped URDF, every derived key given)
PANDA_REDUNDANT = [
    "robot=urdf",
    "robot.urdf=rbfn/robots/panda/panda.urdf",
    "robot.end_link=panda_hand",
    "robot.redundancy=panda_joint3",
    "robot.joint_low=[-1.0,-1.7628,-1.0,-3.0718,-1.0,0.571,-0.215]",
    "robot.joint_high=[1.0,0.215,1.0,-1.356,1.0,2.571,1.785]",
    "robot.home=[0.0,-0.785,0.0,-2.356,0.0,1.571,0.785]",
]

TINY_TRAIN = [
    "robot.workspace=box",
    "data.n_train=300",
    "data.n_val=200",
    "data.n_test=200",
    "rbfn.num_centers=10",
    "centers=kmeans",
    "progress=false",
    "export=false",
    "num_threads=1",
]
