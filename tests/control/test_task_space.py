"""The online scenario on any robot: the SCARA through its URDF agrees with its closed form, a
URDF arm with a locked joint adapts in the closed loop, and settings that do not suit the
checkpoint's robot are named before any work."""

from dataclasses import replace

import pytest
import torch

from rbfn.checkpoint import model_from_checkpoint
from rbfn.config import GainsConfig, OnlineConfig
from rbfn.control.task_space import check_online, online_robot, path_name, record_closed_form, run_online
from rbfn.robots.robot import load_robot

from ..conftest import PANDA_REDUNDANT, TINY_TRAIN, compose_config

KW = {"dtype": torch.float64, "device": "cpu"}


def _record(robot: str, **change) -> dict:
    return {**load_robot(compose_config("train", f"robot={robot}").robot).record(), **change}


def test_scara_through_its_urdf_equals_its_closed_form():
    """The same sinusoid path and perturbations: desired targets and the nominal IK's error on
    the real robots agree between the closed form and the URDF chain."""
    cfg = OnlineConfig(path="sinusoid", link_error=[0.04, -0.03], offset_error=[0.02, -0.01, 0.005])
    t = torch.linspace(0.0, 6.0, 301, **KW)
    closed = online_robot(_record("scara"), cfg, GainsConfig(), [0.0, 0.02, 0.04], t, **KW)
    record = _record("scara")
    copy = record["urdf"].replace('<robot name="scara">', '<robot name="my_scara">')  # not the packaged text
    urdf = online_robot({**record, "urdf": copy}, cfg, GainsConfig(), [0.0, 0.02, 0.04], t, **KW)
    assert type(urdf.plant.dynamics).__name__ == "ArmTerms" and type(closed.plant.dynamics).__name__ == "ScaraTerms"
    assert torch.allclose(urdf.x_d, closed.x_d, atol=1e-12, rtol=0)
    q = closed.full(closed.q_nominal)[:, None].expand(-1, 6, 3)  # [adapted, frozen] x 3 sizes
    e_closed, e_urdf = closed.errors(*closed.measure(q)), urdf.errors(*urdf.measure(q))
    assert torch.allclose(e_urdf[0], e_closed[0], atol=1e-9, rtol=0)
    assert e_closed[0][:, 0].abs().max() < 1e-9 and e_closed[0][:, 2].mean() > 10.0  # mm


def test_panda_adapts_online_with_its_locked_joint_held(panda_ckpt):
    """A 3 s closed loop on the Panda (joint 3 locked) with a coarse 40-centre network: pose
    errors reported for the six free joints, the adapted rows far below their frozen twins, the
    size-0 row's nominal IK exact."""
    cfg = OnlineConfig(
        duration=3.0, dt=0.002, sizes=[0.0, 0.03], link_error=[0.03, 0.02, -0.02], offset_error=[0.02, 0.0, 0.0, 0.01]
    )
    r = run_online(model_from_checkpoint(panda_ckpt), panda_ckpt["robot"], cfg, GainsConfig(), list(cfg.sizes))
    assert r.q_adapt.shape[1:] == (2, 6) and r.rot_adapt is not None and r.q_real is None
    assert r.err_analytic[:, 0].abs().max() < 1e-9 and r.err_analytic[:, 1].mean() > 1.0
    late = r.t >= 2.0
    adapt, frozen = r.err_adapt[late].mean(0), r.err_frozen[late].mean(0)
    assert (adapt < 0.2 * frozen).all(), (adapt, frozen)
    assert (r.rot_adapt[late].mean(0) < 0.5 * r.rot_frozen[late].mean(0)).all()
    assert r.dw[-1].min() > 0


def test_a_network_with_a_redundant_joint_takes_its_measured_value_online(tmp_path):
    """The Panda with joint 3 an input of the network: the desired inputs carry the path's value of
    it, the measured ones the robot's, and a 3 s closed loop adapts all seven joints."""
    import train
    from rbfn.checkpoint import read_checkpoint
    from rbfn.robots.derive import derive_train

    cfg = derive_train(compose_config("train", *PANDA_REDUNDANT, *TINY_TRAIN, "rbfn.num_centers=40"))
    train.run(cfg, tmp_path)
    ckpt = read_checkpoint(tmp_path / "checkpoint.pt")
    online = OnlineConfig(duration=3.0, dt=0.002, sizes=[0.0, 0.03], link_error=[0.03, 0.02, -0.02])
    t = torch.linspace(0.0, 3.0, 1501, **KW)
    rob = online_robot(ckpt["robot"], online, GainsConfig(), [0.0, 0.03], t, **KW)
    assert rob.x_d.shape == (1501, 8) and rob.redundant == 2
    assert torch.equal(rob.x_d[:, 7], rob.q_nominal[:, 2])
    q = rob.full(rob.q_nominal)[:, None].expand(-1, 4, 7)
    assert torch.equal(rob.targets(*rob.measure(q), q)[..., 7], q[..., 2])
    r = run_online(model_from_checkpoint(ckpt), ckpt["robot"], online, GainsConfig(), list(online.sizes))
    late = r.t >= 2.0
    assert r.q_adapt.shape[1:] == (2, 7) and (r.err_adapt[late].mean(0) < r.err_frozen[late].mean(0)).all()


def test_settings_that_do_not_suit_the_robot_are_named():
    ur5 = _record("ur5")
    with pytest.raises(ValueError, match=r"online.path='circle' is a path of the SCARA's workspace.*sinusoid"):
        check_online(OnlineConfig(path="circle"), ur5)
    with pytest.raises(
        ValueError, match=r"online.offset_error=.* has 7 entries; the chain to 'ee_link' .* has 6 joints"
    ):
        check_online(OnlineConfig(offset_error=[0.0] * 7), ur5)
    with pytest.raises(ValueError, match=r"online.link_error=.* has 3 entries; the SCARA .* has 2 links"):
        check_online(OnlineConfig(link_error=[0.03, 0.0, 0.01]), _record("scara"))
    assert check_online(OnlineConfig(), ur5) == (6, 6)
    assert check_online(replace(OnlineConfig(), path=None), _record("scara")) == (2, 3)


def test_the_registry_alone_chooses_the_closed_form():
    """The packaged SCARA runs in closed form under any name, on its default path (paper); its URDF
    text changed, locked joints or pose targets, it is a URDF arm (default path sinusoid)."""
    scara = _record("scara", name="any label")
    assert path_name(replace(OnlineConfig(), path=None), scara) == "paper"
    assert record_closed_form(scara) is not None
    for change in ({"urdf": scara["urdf"] + "\n<!-- a copy -->"}, {"locked": {"joint3": 1.0}}, {"target": "pose"}):
        assert record_closed_form({**scara, **change}) is None
        assert path_name(replace(OnlineConfig(), path=None), {**scara, **change}) == "sinusoid"


def test_a_diverged_online_run_names_its_row_and_step(panda_ckpt):
    """A step far too coarse for the observer (K_o dt = 50): the run stops as a diverged
    simulation, which the entry points print as one line, naming the row, the step and its state."""
    from rbfn.control.simulator import SimulationDiverged

    cfg = OnlineConfig(duration=4.0, dt=0.05, sizes=[0.0, 0.03], update_every=2)
    gains = replace(GainsConfig(), observer_gain=1000.0)
    with pytest.raises(SimulationDiverged, match=r"online run diverged, adapted network.* by step \d+ \(t = .* s\)"):
        run_online(model_from_checkpoint(panda_ckpt), panda_ckpt["robot"], cfg, gains, list(cfg.sizes))
