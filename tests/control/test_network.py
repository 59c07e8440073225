"""Phase 1 of the two-phase law: the residual recorded at several payloads and its fit W0 + m V."""

import torch

from rbfn.config import ControlConfig, GainsConfig, RobotConfig
from rbfn.control.models import model_scales
from rbfn.control.network import (
    ControlNet,
    desired_states,
    model_payload_torque,
    payload_basis,
    payload_residuals,
)
from rbfn.control.robot_setup import control_robot
from rbfn.control.simulator import Scenario
from rbfn.control.trajectory import Reference

KW = {"dtype": torch.float64}


def _net(d: int, m: int, seed: int) -> ControlNet:
    g = torch.Generator().manual_seed(seed)
    centers = torch.randn(m, d, generator=g, **KW)
    return ControlNet(torch.zeros(d, **KW), torch.ones(d, **KW), centers, torch.full((m,), 1.5, **KW), None, 0.0)


def test_the_fit_recovers_weights_affine_in_the_payload():
    """Residuals that are exactly h^T (W0 + m V) give back W0 and V, with no fit error."""
    net = _net(d=4, m=12, seed=0)
    g = torch.Generator().manual_seed(1)
    x = torch.randn(400, 4, generator=g, **KW)
    w0, per_kg = torch.randn(12, 3, generator=g, **KW), torch.randn(12, 3, generator=g, **KW)
    payloads = [0.0, 2.0, 5.0, 7.5]
    h = net.features(x)
    y = torch.stack([h @ (w0 + m * per_kg) for m in payloads], 1)  # (N, C, n)
    basis = payload_basis(net, x, y, payloads)
    pred = torch.stack([h @ (basis.w0 + m * basis.per_kg) for m in payloads], 1)
    assert torch.allclose(pred, y, atol=1e-6 * y.abs().max())
    assert basis.fit_error.shape == (4,) and float(basis.fit_error.max()) < 1e-5
    assert basis.joint_error.shape == (3,) and float(basis.joint_error.max()) < 1e-5


def test_each_joint_has_its_own_fit_error():
    """A joint whose residual the Gaussians cannot carry (noise) fits badly, the others do not."""
    net = _net(d=4, m=12, seed=0)
    g = torch.Generator().manual_seed(2)
    x = torch.randn(400, 4, generator=g, **KW)
    w0, per_kg = torch.randn(12, 3, generator=g, **KW), torch.randn(12, 3, generator=g, **KW)
    y = torch.stack([net.features(x) @ (w0 + m * per_kg) for m in (0.0, 1.0, 2.0)], 1)  # (N, C, n)
    y[..., 2] = torch.randn(400, 3, generator=g, **KW)
    basis = payload_basis(net, x, y, [0.0, 1.0, 2.0])
    assert float(basis.joint_error[:2].max()) < 0.3 and float(basis.joint_error[2]) > 0.8


def test_an_arm_rated_for_no_payload_gets_no_payload_direction():
    """robot.rated_payload 0: every condition at 0 kg, so the fit is W0 alone, V = 0 (not 0 / 0)."""
    net = _net(d=4, m=12, seed=0)
    x = torch.randn(400, 4, generator=torch.Generator().manual_seed(1), **KW)
    y = (net.features(x) @ torch.ones(12, 3, **KW))[:, None].expand(-1, 3, -1)
    basis = payload_basis(net, x, y, [0.0, 0.0, 0.0])
    assert torch.equal(basis.per_kg, torch.zeros_like(basis.per_kg)) and bool(torch.isfinite(basis.w0).all())
    assert float(basis.fit_error.max()) < 1e-5


def _scara(duration: float):
    cfg = ControlConfig(duration=duration)
    gains = GainsConfig()
    rob = control_robot(RobotConfig(), cfg)
    sc = Scenario(duration, cfg.dt, str(cfg.integrator), 0.2, 0.8)
    ref = Reference(*rob.trajectory(sc.times(torch.float64))).to(**KW)
    return rob, gains, sc, ref, rob.nominal_model(0.0, model_scales(gains))


def test_phase_one_records_what_the_model_misses_at_each_payload():
    """The calibration runs' residual, against the plant's own inverse dynamics along the reference
    carrying the same payload (the runs track the reference to ~1e-4)."""
    rob, gains, sc, ref, model = _scara(1.0)
    payloads = [0.0, 12.5, 25.0]
    x, y = payload_residuals(rob.plant, sc, ref, gains, model, payloads, stride=10)
    assert x.shape == (y.shape[0], 9) and y.shape[1:] == (3, 3)
    assert torch.equal(x, desired_states(ref, acceleration=True)[: 10 * x.shape[0] : 10])
    plant, n = rob.plant, rob.n
    q, qd, qdd = (r[: 10 * x.shape[0] : 10] for r in ref)
    for i, kg in enumerate(payloads):
        load = plant.load(torch.full((q.shape[0],), kg, **KW))
        a0 = plant.accel(q, qd, torch.zeros_like(q), load)
        cols = [plant.accel(q, qd, torch.eye(n, **KW)[j].expand_as(q), load) - a0 for j in range(n)]
        needed = torch.linalg.solve(torch.stack(cols, -1), qdd - a0)
        at = model.at(q, qd)
        exact = needed - at.m_times(qdd) - at.c_times(qd) - at.gravity()
        rel = (y[5:, i] - exact[5:]).norm() / exact[5:].norm()  # after the first steps' transient
        assert rel < 0.02, (kg, float(rel))


def test_the_model_carrying_a_payload_is_affine_in_it():
    rob, _, _, ref, model = _scara(0.5)
    per_kg = model_payload_torque(model, ref)
    q, qd, qdd = ref

    def torque(kg):
        at = model.at(q, qd, payload=torch.full(q.shape[:1], kg, **KW))
        return at.m_times(qdd) + at.c_times(qd) + at.gravity()

    assert torch.allclose(torque(7.0) - torque(0.0), 7.0 * per_kg, atol=1e-9)
    # A payload per environment is the model built carrying each.
    kg = torch.linspace(0.0, 20.0, q.shape[0], **KW)
    mixed = model.at(q, qd, payload=kg).gravity()
    for k in (0, q.shape[0] // 2, q.shape[0] - 1):
        own = rob.nominal_model(float(kg[k]), model_scales(GainsConfig())).at(q[k : k + 1], qd[k : k + 1])
        assert torch.allclose(mixed[k], own.gravity().expand(1, rob.n)[0], atol=1e-12)
