"""The two-phase adaptive law: its payload estimate, its inputs, and its refusals."""

import pytest
import torch

from rbfn.config import ControlConfig, GainsConfig, RobotConfig
from rbfn.control.controllers import TwoPhase, make_controller, observer_factor
from rbfn.control.models import model_scales
from rbfn.control.network import ControlNet, desired_states, model_payload_torque, payload_basis, payload_residuals
from rbfn.control.plants import Plant
from rbfn.control.robot_setup import control_robot
from rbfn.control.simulator import Scenario
from rbfn.control.trajectory import Reference

KW = {"dtype": torch.float64}


def _two_phase(held: float, seconds: float = 1.5):
    """The SCARA under the two-phase law in the ideal loop (no disturbance), carrying `held` kg
    from the start: the law's payload estimate after `seconds`, and the largest tracking error."""
    cfg = ControlConfig(duration=seconds, disturbance=0.0)
    gains = GainsConfig(inertia_scaling=True)
    rob = control_robot(RobotConfig(), cfg)
    sc = Scenario(seconds, cfg.dt, "rk4", 0.2, 0.8)
    ref = Reference(*rob.trajectory(sc.times(torch.float64))).to(**KW)
    model = rob.nominal_model(0.0, model_scales(gains))
    rates = rob.joint_rates(gains)
    payloads = [0.0, 12.5, 25.0]
    x, y = payload_residuals(rob.plant, sc, ref, gains, model, payloads, stride=10)
    g = torch.Generator().manual_seed(0)
    z = (x - x.mean(0)) / x.std(0)
    net = ControlNet(
        x.mean(0), x.std(0), z[torch.randperm(z.shape[0], generator=g)[:20]], torch.full((20,), 1.0, **KW), None, 0.0
    )
    basis = payload_basis(net, x, y, payloads)
    feats = basis.outputs(net.features(desired_states(ref, acceleration=True)), model_payload_torque(model, ref))
    ctrl = make_controller(
        "arbfn_kmeans",
        gains,
        sc.dt,
        model=model,
        features=feats,
        law="two_phase",
        schedule=rob.inertia_schedule(gains),
        rates=rates,
    )
    assert isinstance(ctrl, TwoPhase)
    plant = Plant(rob.dynamics, disturbance=0.0)
    q, qd = ref.q_d[:1].clone(), ref.qd_d[:1].clone()
    state = ctrl.init_state(q, qd)
    load = plant.load(torch.full((1,), held, **KW))
    dist = torch.zeros(3, **KW)
    worst = 0.0
    for k in range(ref.q_d.shape[0] - 1):
        r = Reference(ref.q_d[k], ref.qd_d[k], ref.qdd_d[k])
        tau, state = ctrl.torque(r, q, qd, state, h=feats[k], alpha=torch.tensor(0.0, **KW))
        q, qd = plant.step(q, qd, tau, dist, sc.dt, load, "rk4")
        worst = max(worst, float((ref.q_d[k + 1] - q).abs().max()))
    return float(state.m_hat[0]), worst


@pytest.mark.parametrize("held", [0.0, 8.0, 20.0])
def test_the_estimate_finds_the_payload_the_law_is_not_told(held):
    m_hat, worst = _two_phase(held)
    assert abs(m_hat - held) < 0.5 + 0.05 * held, (held, m_hat)
    assert worst < 0.1, worst  # stable from the first period, the payload unknown


def test_feedforward_drops_the_networks_torque_on_the_joints_it_names():
    """With a joint's feedforward 0 the law's first command lacks exactly the network's predicted
    torque h^T W0 + m_hat (h^T V - Y) there; the other joints' commands are unchanged."""
    gains = GainsConfig(inertia_scaling=True)
    rob = control_robot(RobotConfig(), ControlConfig())
    model = rob.nominal_model(0.0, model_scales(gains))
    g = torch.Generator().manual_seed(3)
    feats = torch.randn(4, 9, generator=g, **KW)  # [h^T W0, h^T V, h^T V - Y], n = 3
    q, qd = torch.tensor([[0.3, -0.2, 0.1]], **KW), torch.tensor([[0.1, 0.2, -0.1]], **KW)
    ref = Reference(q[0] + 0.01, qd[0], torch.zeros(3, **KW))

    def command(feedforward):
        ctrl = make_controller(
            "arbfn_kmeans", gains, 1e-3, model=model, features=feats, law="two_phase",
            schedule=rob.inertia_schedule(gains), feedforward=feedforward,
        )  # fmt: skip
        state = ctrl.init_state(q, qd)
        return ctrl.torque(ref, q, qd, state, h=feats[0], alpha=torch.tensor(0.0, **KW))[0][0]

    every, some = command(None), command(torch.tensor([1.0, 0.0, 1.0], **KW))
    predicted = feats[0, :3] + float(model.payload) * feats[0, 6:]
    assert torch.allclose(every - some, torch.tensor([0.0, 1.0, 0.0], **KW) * predicted, atol=1e-12)
    assert torch.equal(command(torch.ones(3, **KW)), every)


def test_the_law_compares_the_measured_velocity_with_the_references_as_the_loop_lags_it():
    """With velocity_lag L the law's velocity error is qd_d - L qdd_d - qd: its first command drops
    by exactly (M(m_hat) Lambda + K s_j) L qdd_d, the feedback's answer to that much velocity error
    (epsilon 0, so the robust term stays out of it)."""
    gains = GainsConfig(inertia_scaling=True, epsilon=0.0)
    rob = control_robot(RobotConfig(), ControlConfig())
    model = rob.nominal_model(0.0, model_scales(gains))
    feats = torch.randn(4, 9, generator=torch.Generator().manual_seed(3), **KW)
    q, qd = torch.tensor([[0.3, -0.2, 0.1]], **KW), torch.tensor([[0.1, 0.2, -0.1]], **KW)
    ref = Reference(q[0] + 0.01, qd[0] + 0.02, torch.tensor([1.5, -2.0, 0.7], **KW))
    scale = rob.joint_scale(**KW)

    def command(lag):
        ctrl = make_controller(
            "arbfn_kmeans", gains, 1e-3, model=model, features=feats, law="two_phase",
            schedule=rob.inertia_schedule(gains), joint_scale=scale, velocity_lag=lag,
        )  # fmt: skip
        state = ctrl.init_state(q, qd)
        return ctrl.torque(ref, q, qd, state, h=feats[0], alpha=torch.tensor(0.0, **KW))[0], state.m_hat

    lag = 3.3e-3
    (plain, m_hat), (lagged, _) = command(0.0), command(lag)
    at = model.at(q, qd, payload=m_hat)
    one = 1.0 if scale is None else scale
    expected = lag * (at.m_times(gains.Lambda * ref.qdd_d[None]) + gains.K * one * ref.qdd_d)
    assert torch.allclose(plain - lagged, expected, atol=1e-9)


def test_observer_factor_is_the_feedback_bandwidth_over_the_observers():
    gains = GainsConfig(K=50.0, observer_gain=100.0)
    f = observer_factor(gains, torch.tensor([1.0, 2.0]), torch.tensor([[0.1, 4.0], [1.0, 1.0]]))
    assert torch.allclose(f, torch.tensor([[1.0, 0.25], [0.5, 1.0]]))


def test_the_two_phase_law_needs_its_schedule_and_a_known_law_name():
    cfg, gains = ControlConfig(), GainsConfig()
    rob = control_robot(RobotConfig(), cfg)
    model = rob.nominal_model(0.0, model_scales(gains))
    feats = torch.zeros(10, 9, **KW)
    with pytest.raises(ValueError, match="inertia schedule"):
        make_controller("arbfn_aco", gains, 1e-3, model=model, features=feats, law="two_phase")
    with pytest.raises(ValueError, match="unknown adaptive law 'fast'"):
        make_controller("arbfn_aco", gains, 1e-3, model=model, features=feats, law="fast")


def test_the_two_phase_state_can_enter_a_compiled_package():
    """An AOT package stores its inputs' tree spec: the law's state must serialise (it is
    registered beside the simulator's other named states)."""
    import torch.utils._pytree as pytree

    import rbfn.control.simulator  # noqa: F401  (registers the named states)
    from rbfn.control.controllers import SlidingState, TwoPhaseState

    z = torch.zeros(2, 3, **KW)
    state = TwoPhaseState(SlidingState(z, z, z, None, z, z), z, z, z, z, torch.zeros(2, **KW))
    spec = pytree.tree_flatten(state)[1]
    assert pytree.treespec_loads(pytree.treespec_dumps(spec)) == spec
