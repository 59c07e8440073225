"""The closed loop on URDF arms: the SCARA through its URDF equals its closed form, energy is
conserved, batches equal single runs, divergence is reported, and bad robots fail early."""

from dataclasses import replace

import pytest
import torch

from rbfn.config import ControlConfig, RobotConfig
from rbfn.control import (
    Plant,
    Scenario,
    SimulationDiverged,
    control_robot,
    make_controller,
    paper_trajectory,
    simulate,
    sinusoid_trajectory,
)
from rbfn.control.controllers import Gains, NominalModel
from rbfn.control.robot_setup import payload_cases
from rbfn.robots.arm_terms import ArmTerms
from rbfn.robots.dynamics import load_arm
from rbfn.robots.scara import ScaraTerms

from ..conftest import PANDA_HELD, compose_config

UR5 = compose_config("evaluate", "robot=ur5").robot
PANDA = compose_config("evaluate", "robot=panda").robot
PANDA_LOCKED = compose_config("evaluate", *PANDA_HELD).robot  # joint 3 held at 0


def _run(plant, model, name, sc, ref, payload, **kw):
    b, n = payload.shape[0], ref.q_d.shape[1]
    q0, qd0 = ref.q_d[:1].expand(b, n).clone(), ref.qd_d[:1].expand(b, n).clone()
    ctrl = make_controller(name, Gains(), sc.dt, model=model, **kw)
    return simulate(plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload)


@pytest.mark.parametrize("name,integrator", [("smc_obs", "rk4"), ("ctc", "euler"), ("pd", "rk4")])
def test_scara_urdf_path_equals_closed_form(name, integrator):
    """The same controller on the SCARA's URDF (the URDF recursion) and its closed form, with the
    payload switched on and off inside the run."""
    sc = Scenario(duration=0.25, payload_on=0.05, payload_off=0.15, integrator=integrator, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    payload = torch.tensor([0.0, 10.0], dtype=torch.float64)
    closed = _run(Plant(ScaraTerms()), NominalModel(ScaraTerms()), name, sc, ref, payload)
    plant = Plant(ArmTerms(load_arm("scara")))
    urdf = _run(plant, NominalModel(plant.dynamics), name, sc, ref, payload)
    assert float((closed.q - urdf.q).abs().max()) < 1e-9
    assert float((closed.tau - urdf.tau).abs().max()) < 1e-6
    assert float((closed.q[-1, 1] - closed.q[-1, 0]).abs().max()) > 1e-6  # the payload mattered


@pytest.mark.parametrize("robot", ["ur5", "panda"])
def test_energy_conserved_without_friction_disturbance_and_gravity(robot):
    plant = Plant(ArmTerms(load_arm(robot)), viscous=0.0, coulomb=0.0, disturbance=0.0, gravity=False)
    g = torch.Generator().manual_seed(0)
    q = torch.rand(8, plant.n, generator=g, dtype=torch.float64) * 2 - 1
    qd = torch.randn(8, plant.n, generator=g, dtype=torch.float64)
    pay = torch.linspace(0.0, 3.0, 8, dtype=torch.float64)
    co, zero, dist = plant.load(pay), torch.zeros_like(q), torch.zeros(3, dtype=torch.float64)
    e0 = plant.energy(q, qd, pay)
    drift = []
    for dt in (2e-3, 1e-3):  # 0.2 s each
        q1, qd1 = q, qd
        for _ in range(round(0.2 / dt)):
            q1, qd1 = plant.step(q1, qd1, zero, dist, dt, co)
        drift.append(float(((plant.energy(q1, qd1, pay) - e0).abs() / e0).max()))
    assert drift[1] < 1e-7 and drift[0] / drift[1] > 10  # RK4: truncation error of order 4


def test_energy_conserved_with_gravity():
    plant = Plant(ArmTerms(load_arm("ur5")), viscous=0.0, coulomb=0.0, disturbance=0.0)
    g = torch.Generator().manual_seed(1)
    q, qd = torch.rand(4, 6, generator=g, dtype=torch.float64), torch.randn(4, 6, generator=g, dtype=torch.float64)
    pay = torch.full((4,), 2.5, dtype=torch.float64)
    co = plant.load(pay)
    e0 = plant.energy(q, qd, pay)
    for _ in range(200):
        q, qd = plant.step(q, qd, torch.zeros_like(q), torch.zeros(3, dtype=torch.float64), 5e-4, co)
    assert torch.allclose(plant.energy(q, qd, pay), e0, rtol=0, atol=1e-7)


def _ur5(cfg: ControlConfig | None = None):
    return control_robot(UR5, cfg or ControlConfig())


@pytest.mark.parametrize("integrator", ["rk4", "euler"])
def test_ur5_batched_run_matches_single_runs(integrator):
    setup = _ur5()
    sc = Scenario(duration=0.1, payload_on=0.02, payload_off=0.06, integrator=integrator, metrics_after=0.0)
    ref = setup.trajectory(sc.times())
    scale = setup.joint_scale(dtype=torch.float64)
    pay = torch.tensor(setup.payloads, dtype=torch.float64)
    assert setup.payloads == [0.0, 2.5, 5.0]
    ctrl = make_controller("smc_obs", Gains(), sc.dt, model=setup.model, joint_scale=scale)
    q0, qd0 = ref.q_d[:1].expand(3, 6).clone(), ref.qd_d[:1].expand(3, 6).clone()
    batch = simulate(setup.plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=pay, chunk=7)
    for i in range(3):
        one = simulate(setup.plant, ctrl, sc, ref, q0=q0[i : i + 1], qd0=qd0[i : i + 1], payload=pay[i : i + 1])
        assert torch.allclose(batch.q[:, i], one.q[:, 0], atol=1e-12, rtol=0)
    assert batch.q.shape == (sc.steps + 1, 3, 6)
    k_on = round(0.02 / sc.dt)
    assert torch.equal(batch.q[: k_on + 1, 0], batch.q[: k_on + 1, 2])
    assert not torch.equal(batch.q[k_on + 5, 0], batch.q[k_on + 5, 2])


def test_ur5_divergence_stops_with_step_and_state():
    setup = _ur5()
    sc = Scenario(duration=1.0, dt=0.01, payload_on=0.1, payload_off=0.3, integrator="euler")
    ref = setup.trajectory(sc.times())
    ctrl = make_controller("pd", Gains(pd_kp=1e6, pd_kd=1e5), sc.dt, model=setup.model)
    with pytest.raises(SimulationDiverged, match=r"diverged by step \d+ \(t = .* s\) in environment 0: q = \["):
        simulate(
            setup.plant,
            ctrl,
            sc,
            ref,
            q0=ref.q_d[:1].clone(),
            qd0=ref.qd_d[:1].clone(),
            payload=torch.zeros(1, dtype=torch.float64),
        )


def test_sinusoid_trajectory_is_differentiated_exactly():
    t = torch.linspace(0.0, 7.0, 7001, dtype=torch.float64)
    home, amp = torch.tensor([0.1, -1.0, 2.0, 0.0]), torch.tensor([0.1, 0.2, 0.0, 0.05])
    q, qd, qdd = sinusoid_trajectory(t, home, amp)
    assert q.shape == (7001, 4) and torch.equal(q[:, 2], torch.full_like(t, 2.0))
    dt = float(t[1] - t[0])
    assert torch.allclose(torch.gradient(q, spacing=dt, dim=0)[0][1:-1], qd[1:-1], atol=1e-5)
    assert torch.allclose(torch.gradient(qd, spacing=dt, dim=0)[0][1:-1], qdd[1:-1], atol=1e-4)
    # The paper's pairs (1, 2), (2, 3), (3, 4) cycled over the joints: joint 4 uses (1, 2).
    expected = 0.05 * (torch.sin(t) + torch.sin(2 * t))
    assert torch.allclose(q[:, 3], expected, atol=1e-15)
    assert torch.allclose(q[-1], sinusoid_trajectory(t[-1:] - 2 * torch.pi, home, amp)[0][0], atol=1e-12)


def test_robot_setup_derives_cases_scale_and_path():
    scara = control_robot(RobotConfig(), ControlConfig())
    assert scara.payloads == [0.0, 10.0, 20.0] and scara.scale is None
    assert scara.units == [("rad", "N m"), ("rad", "N m"), ("m", "N")]
    ur5 = _ur5()
    assert ur5.n == 6 and len(ur5.scale) == 6 and ur5.scale[1] > 1.0 and ur5.scale[5] < 1e-3
    assert ur5.amplitude == pytest.approx([0.1] * 6) and ur5.home == UR5.home
    # Explicit settings win; a payload of 0 rated gives one case.
    assert payload_cases(ControlConfig(payloads=[1.0]), 5.0) == [1.0]
    assert payload_cases(ControlConfig(), 0.0) == [0.0]
    # The Panda's locked joint 3 is controlled, held at its locked value.
    panda = control_robot(PANDA, ControlConfig())
    assert panda.n == 7 and panda.amplitude[2] > 0.0 and panda.home[2] == 0.0  # all 7 joints move
    held = control_robot(PANDA_LOCKED, ControlConfig())
    assert held.n == 7 and held.amplitude[2] == 0.0 and held.home[2] == PANDA_LOCKED.locked["panda_joint3"]
    assert panda.payloads == [0.0, 1.5, 3.0]


BAD_URDF = """<robot name="bad">
  <link name="base"/>
  <link name="l1"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <joint name="j1" type="floating"><parent link="base"/><child link="l1"/></joint>
  <link name="l2"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="10" velocity="1"/></joint>
</robot>
"""


def test_unsupported_joint_type_fails_naming_the_urdf_and_joint(tmp_path):
    path = tmp_path / "bad.urdf"
    path.write_text(BAD_URDF)
    robot = RobotConfig(name="bad", urdf=str(path), end_link="l2", joint_low=[-1.0], joint_high=[1.0])
    with pytest.raises(ValueError, match=r"robot.urdf='.*bad.urdf'.*joint 'j1' on the chain.*'floating'"):
        control_robot(robot, ControlConfig())


@pytest.mark.parametrize(
    "robot,change,match",
    [
        (UR5, {"payload_link": "ghost"}, r"control.payload_link='ghost': payload link 'ghost' is not a link"),
        (UR5, {"joint_scale": [1.0, 2.0]}, r"control.joint_scale=\[1.0, 2.0\] needs one factor per joint"),
        (UR5, {"trajectory": "paper"}, r"control.trajectory='paper' is the SCARA's 3-joint path"),
        (replace(UR5, locked={"elbow": 0.0}), {}, r"robot.locked names \['elbow'\]"),
        (replace(UR5, joint_low=[0.0] * 5, joint_high=[1.0] * 5), {}, r"robot.joint_low/joint_high give 5 joints"),
    ],
)
def test_bad_robot_settings_fail_naming_the_key(robot, change, match):
    with pytest.raises(ValueError, match=match):
        control_robot(robot, ControlConfig(**change))


def test_a_payload_on_another_link_moves_it():
    base = _ur5()
    other = _ur5(ControlConfig(payload_link="forearm_link"))
    q = torch.tensor([base.home], dtype=torch.float64)
    pay = torch.tensor([2.5], dtype=torch.float64)
    g_end = base.plant.dynamics.at(q, pay).gravity()
    g_fore = other.plant.dynamics.at(q, pay).gravity()
    assert not torch.allclose(g_end, g_fore) and float(g_end[0, 3].abs()) > float(g_fore[0, 3].abs())


def test_per_joint_friction_and_disturbance():
    plant = Plant(ArmTerms(load_arm("ur5")), viscous=[1.0, 2, 3, 4, 5, 6], coulomb=0.5, disturbance=[0, 1, 0, 0, 0, 2])
    qd = torch.ones(2, 6, dtype=torch.float64)
    assert torch.equal(plant.friction_torque(qd)[0], torch.tensor([1.5, 2.5, 3.5, 4.5, 5.5, 6.5], dtype=torch.float64))
    d = plant.disturbance(torch.tensor([torch.pi / 4], dtype=torch.float64))
    assert d.shape == (1, 6) and torch.allclose(d[0], torch.tensor([0, 1.0, 0, 0, 0, 2.0], dtype=torch.float64))
    with pytest.raises(ValueError, match=r"viscous=\[1.0, 2.0\] needs one value per joint \(6\)"):
        Plant(ArmTerms(load_arm("ur5")), viscous=[1.0, 2.0])


@pytest.mark.slow
def test_ur5_compiled_step_equals_eager():
    """simulate(compile=True) traces the batch-last dynamics (its solve written out) and keeps the
    environments last in memory; it gives the eager result (a minute or two to compile)."""
    import shutil

    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("torch.compile's CPU backend needs a C++ compiler")
    setup = _ur5()
    sc = Scenario(duration=0.01, payload_on=0.002, payload_off=0.008, integrator="euler", metrics_after=0.0)
    ref = setup.trajectory(sc.times())
    scale = setup.joint_scale(dtype=torch.float64)
    ctrl = make_controller("smc_obs", Gains(), sc.dt, model=setup.model, joint_scale=scale)
    pay = torch.tensor([0.0, 2.5], dtype=torch.float64)
    q0, qd0 = ref.q_d[:1].expand(2, 6).clone(), ref.qd_d[:1].expand(2, 6).clone()
    eager = simulate(setup.plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=pay)
    compiled = simulate(setup.plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=pay, compile=True)
    assert torch.allclose(compiled.q, eager.q, rtol=0, atol=1e-12)
    assert torch.allclose(compiled.tau, eager.tau, rtol=0, atol=1e-8)


def test_payload_cases_beyond_the_rated_payload_are_run_and_warned_of(caplog):
    import logging

    with caplog.at_level(logging.WARNING, logger="rbfn.control.robot_setup"):
        control_robot(RobotConfig(), ControlConfig())  # 0, 10, 20 kg of the SCARA's rated 20
    assert not caplog.messages
    with caplog.at_level(logging.WARNING, logger="rbfn.control.robot_setup"):
        setup = control_robot(RobotConfig(), ControlConfig(payloads=[0.0, 30.0]))
    assert setup.payloads == [0.0, 30.0]
    assert any("[30.0] kg exceed robot.rated_payload=20 kg" in m for m in caplog.messages), caplog.messages
