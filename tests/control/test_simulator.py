import itertools

import pytest
import torch

from rbfn.control import Plant, Scenario, SimulationDiverged, make_controller, paper_trajectory, simulate
from rbfn.control.batch import Stacked
from rbfn.control.controllers import Gains, NominalModel
from rbfn.control.models import ModelScales
from rbfn.control.simulator import (
    Carry,
    Loop,
    Periods,
    make_chunk,
    payload_schedule,
    pick_and_place,
    stage_disturbances,
)
from rbfn.robots.scara import (
    ScaraTerms,
    coriolis,
    gravity,
    inertia_params,
    m_solve,
    m_times,
    mass_matrix,
    mass_matrix_dot,
)

SCARA_MODEL = NominalModel(ScaraTerms())  # the paper's nominal model of the SCARA


def _states(b, seed, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    q = torch.rand(b, 3, generator=g, dtype=dtype) * 3
    qd = torch.randn(b, 3, generator=g, dtype=dtype)
    return q, qd


def test_elementwise_mass_products_match_the_matrix():
    q, v = _states(50, 0)
    pay = torch.linspace(0, 20, 50, dtype=torch.float64)
    co = inertia_params(pay)
    m = mass_matrix(q, pay)
    c2 = torch.cos(q[:, 1])
    assert torch.allclose(m_times(c2, co, v), (m @ v[..., None])[..., 0], atol=1e-12)
    assert torch.allclose(m_solve(c2, co, v), torch.linalg.solve(m, v), atol=1e-12)


def test_nominal_model_terms_match_the_matrices():
    """The controllers' elementwise M_hat v, C_hat y, G_hat and dM_hat/dt qd - C_hat qd - G_hat
    against the SCARA's matrices scaled 0.9, 0.8, 0.85."""
    q, qd = _states(40, 5)
    y = _states(40, 6)[1]
    at = NominalModel(ScaraTerms()).at(q, qd)
    m, c = 0.9 * mass_matrix(q), 0.8 * coriolis(q, qd)
    g = 0.85 * gravity(q)
    assert torch.allclose(at.m_times(y), (m @ y[..., None])[..., 0], atol=1e-12)
    assert torch.allclose(at.c_times(y), (c @ y[..., None])[..., 0], atol=1e-12)
    assert torch.allclose(at.gravity().expand_as(g), g, atol=1e-12)
    rate = ((0.9 * mass_matrix_dot(q, qd) - c) @ qd[..., None])[..., 0] - g
    assert torch.allclose(at.momentum_rate(), rate, atol=1e-12)


@pytest.mark.parametrize("payload", [0.0, 10.0])
def test_energy_conserved_without_friction_disturbance_and_gravity(payload):
    plant = Plant(ScaraTerms(), viscous=0.0, coulomb=0.0, disturbance=0.0, gravity=False)
    q, qd = _states(64, 1)
    pay = torch.full((64,), payload, dtype=torch.float64)
    co = plant.load(pay)
    e0 = plant.energy(q, qd, pay)
    zero, dist = torch.zeros_like(q), torch.zeros(3, dtype=torch.float64)
    drift = []
    for dt in (1e-3, 5e-4, 2.5e-4):  # 1 s each
        q1, qd1 = q, qd
        for _ in range(round(1.0 / dt)):
            q1, qd1 = plant.step(q1, qd1, zero, dist, dt, co)
        drift.append(float(((plant.energy(q1, qd1, pay) - e0).abs() / e0).max()))
    assert drift[-1] < 1e-9
    # RK4: the drift is truncation error, falling about 2^4-fold per halving of dt (order 4).
    assert drift[0] / drift[1] > 10 and drift[1] / drift[2] > 10


def test_gravity_energy_exchange_is_conserved():
    # With gravity on (potential energy included) and no losses, total energy stays constant.
    plant = Plant(ScaraTerms(), viscous=0.0, coulomb=0.0, disturbance=0.0)
    q, qd = _states(16, 2)
    pay = torch.zeros(16, dtype=torch.float64)
    co = plant.load(pay)
    e0 = plant.energy(q, qd, pay)
    for _ in range(500):
        q, qd = plant.step(q, qd, torch.zeros_like(q), torch.zeros(3, dtype=torch.float64), 1e-3, co)
    assert torch.allclose(plant.energy(q, qd, pay), e0, rtol=0, atol=1e-9)


def test_observer_estimates_the_model_gravity_error():
    # Only unmodelled effect: G_hat = 0.85 G, so the observer must find 0.15 * (-m3 g) on joint 3.
    plant = Plant(ScaraTerms(), viscous=0.0, coulomb=0.0, disturbance=0.0)
    model = NominalModel(ScaraTerms(), ModelScales(1.0, 1.0, 0.85))
    sc = Scenario(duration=1.0, payload_on=0.0, payload_off=1.0, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    ctrl = make_controller("smc_obs", Gains(), sc.dt, model=model)
    roll = simulate(
        plant,
        ctrl,
        sc,
        ref,
        q0=ref.q_d[:1].clone(),
        qd0=ref.qd_d[:1].clone(),
        payload=torch.zeros(1, dtype=torch.float64),
    )
    err = (ref.q_d[-1] - roll.q[-1, 0]).abs()
    assert float(err.max()) < 1e-5  # with the bias observed and cancelled, tracking is tight


@pytest.mark.parametrize("integrator", ["rk4", "euler"])
def test_batched_run_matches_single_runs(integrator):
    sc = Scenario(duration=0.3, payload_on=0.1, payload_off=0.2, integrator=integrator, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    plant = Plant(ScaraTerms(), friction="smooth")
    pay = torch.tensor([0.0, 10.0, 20.0], dtype=torch.float64)
    q0, qd0 = ref.q_d[:1].expand(3, 3).clone(), ref.qd_d[:1].expand(3, 3).clone()
    ctrl = make_controller("smc_obs", Gains(), sc.dt, model=SCARA_MODEL)
    batch = simulate(plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=pay, chunk=7)
    for i in range(3):
        one = simulate(plant, ctrl, sc, ref, q0=q0[i : i + 1], qd0=qd0[i : i + 1], payload=pay[i : i + 1])
        assert torch.allclose(batch.q[:, i], one.q[:, 0], atol=1e-12)
    assert batch.q.shape == (sc.steps + 1, 3, 3) and batch.t.shape == (sc.steps + 1,)
    # The payload changes the response only inside and after its window.
    k_on = round(0.1 / sc.dt)
    assert torch.equal(batch.q[: k_on + 1, 0], batch.q[: k_on + 1, 2])
    assert not torch.equal(batch.q[k_on + 5, 0], batch.q[k_on + 5, 2])


def test_stacked_controllers_equal_their_separate_runs():
    """One batch of several controllers (one with adaptive features) gives each controller's own run."""
    sc = Scenario(duration=0.2, payload_on=0.05, payload_off=0.15, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    plant = Plant(ScaraTerms())
    pay = torch.tensor([0.0, 10.0], dtype=torch.float64)
    q0, qd0 = ref.q_d[:1].expand(2, 3).clone(), ref.qd_d[:1].expand(2, 3).clone()
    gen = torch.Generator().manual_seed(0)
    feats = torch.rand(sc.steps + 1, 4, generator=gen, dtype=torch.float64)
    other = torch.rand(sc.steps + 1, 3, generator=gen, dtype=torch.float64)
    w0 = torch.randn(3, 3, generator=gen, dtype=torch.float64)
    # pd alone; then one batched sliding-mode unit of four (two networks of different sizes, one
    # warm-started, with and without the observer); then ctc alone.
    parts = [
        make_controller("pd", Gains(), sc.dt, model=SCARA_MODEL),
        make_controller("arbfn", Gains(), sc.dt, model=SCARA_MODEL, features=feats),
        make_controller("smc_obs", Gains(), sc.dt, model=SCARA_MODEL),
        make_controller("smc", Gains(), sc.dt, model=SCARA_MODEL),
        make_controller("arbfn", Gains(), sc.dt, model=SCARA_MODEL, features=other, w0=w0, observer=False),
        make_controller("ctc", Gains(), sc.dt, model=SCARA_MODEL),
    ]
    stacked = Stacked(parts, [2] * len(parts))
    assert len(stacked.units) == 3 and stacked.unit_sizes == [2, 8, 2]
    k = len(parts)
    both = simulate(plant, stacked, sc, ref, q0=q0.repeat(k, 1), qd0=qd0.repeat(k, 1), payload=pay.repeat(k))
    for i, ctrl in enumerate(parts):
        one = simulate(plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=pay)
        assert torch.allclose(both.q[:, 2 * i : 2 * i + 2], one.q, rtol=0, atol=1e-12)
        assert torch.allclose(both.tau[:, 2 * i : 2 * i + 2], one.tau, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="one batch size per controller"):
        Stacked(parts, [2, 2])


def test_adaptive_law_moves_the_weights():
    """dW/dt = Gamma h s^T: after a second of tracking under a payload, W has left zero."""
    n, dt = 1000, 1e-3
    t = torch.arange(n, dtype=torch.float64) * dt
    ref = paper_trajectory(t)
    h = torch.rand(n, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    ctrl = make_controller("arbfn_x", Gains(), dt, model=NominalModel(ScaraTerms()), features=h)
    plant = Plant(ScaraTerms())
    q, qd = ref.q_d[:1].clone(), ref.qd_d[:1].clone()
    periods = Periods(
        ref=ref,
        h=h,
        alpha=ctrl.alphas(t),
        dist=stage_disturbances(plant, n, dt, dtype=torch.float64),
        load=plant.load(torch.full((n, 1), 10.0, dtype=torch.float64)),
    )
    out = make_chunk(plant, ctrl, dt, "rk4", n)(Loop(q, qd, ctrl.init_state(q, qd)), periods)
    assert out.q.shape == out.tau.shape == (n, 1, 3)
    w = out.loop.controller.w
    assert w.shape == (1, 5, 3) and float(w.abs().max()) > 1e-3


def test_divergence_stops_with_step_and_state():
    sc = Scenario(duration=2.0, dt=0.05, payload_on=0.5, payload_off=1.0, integrator="euler")
    ref = paper_trajectory(sc.times())
    ctrl = make_controller("pd", Gains(pd_kp=1e6, pd_kd=1e5), sc.dt, model=SCARA_MODEL)
    with pytest.raises(SimulationDiverged, match=r"diverged by step \d+ \(t = .* s\) in environment 0: q = "):
        simulate(
            Plant(ScaraTerms()),
            ctrl,
            sc,
            ref,
            q0=ref.q_d[:1].clone(),
            qd0=ref.qd_d[:1].clone(),
            payload=torch.zeros(1, dtype=torch.float64),
        )


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"dt": 0.0}, "dt=0.0 must be a positive"),
        ({"dt": -1e-3}, "dt=-0.001 must be a positive"),
        ({"payload_on": 5.0, "payload_off": 12.0}, r"payload window \[5.0, 12.0\]"),
        ({"integrator": "rk45"}, "integrator='rk45' is not allowed"),
        ({"carries": (Carry(1.0, 3.0, 0.5), Carry(2.0, 4.0, 0.5))}, "not overlapping"),
        ({"carries": (Carry(1.0, 11.0, 0.5),)}, "on < off <= duration=10.0"),
        ({"carries": (Carry(1.0, 2.0, -0.5),)}, "share >= 0"),
    ],
)
def test_bad_scenarios_fail_early(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Scenario(**kwargs).validate()


def test_bad_inputs_fail_early():
    sc = Scenario(duration=0.1, payload_on=0.0, payload_off=0.05, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    ctrl = make_controller("smc", Gains(), sc.dt, model=SCARA_MODEL)
    q0 = ref.q_d[:1].clone()
    with pytest.raises(ValueError, match="initial state"):
        simulate(
            Plant(ScaraTerms()),
            ctrl,
            sc,
            ref,
            q0=q0 * float("nan"),
            qd0=ref.qd_d[:1].clone(),
            payload=torch.zeros(1, dtype=torch.float64),
        )
    with pytest.raises(ValueError, match="payload masses"):
        simulate(
            Plant(ScaraTerms()),
            ctrl,
            sc,
            ref,
            q0=q0,
            qd0=ref.qd_d[:1].clone(),
            payload=torch.tensor([-1.0], dtype=torch.float64),
        )
    with pytest.raises(ValueError, match="friction='coulomb' is not allowed"):
        Plant(ScaraTerms(), friction="coulomb")
    with pytest.raises(ValueError, match="unknown controller 'lqr'"):
        make_controller("lqr", Gains(), 1e-3, model=SCARA_MODEL)


@pytest.mark.slow
def test_compiled_step_equals_eager():
    """control.compile=true (torch.compile of the fused chunk) gives the eager result."""
    import shutil

    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("torch.compile's CPU backend needs a C++ compiler")
    sc = Scenario(duration=0.02, dt=1e-3, payload_on=0.005, payload_off=0.015, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    q0, qd0 = ref.q_d[:1].expand(2, 3).clone(), ref.qd_d[:1].expand(2, 3).clone()
    payload = torch.tensor([0.0, 10.0], dtype=torch.float64)
    ctrl = make_controller("smc_obs", Gains(), sc.dt, model=SCARA_MODEL)
    eager = simulate(Plant(ScaraTerms()), ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, chunk=5)
    compiled = simulate(Plant(ScaraTerms()), ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, compile=True, chunk=5)
    assert torch.allclose(compiled.q, eager.q, rtol=0, atol=1e-12)
    assert torch.allclose(compiled.tau, eager.tau, rtol=0, atol=1e-9)


def test_control_metrics_count_the_time_and_distance_beyond_the_joint_limits():
    from rbfn.control.simulator import Rollout, control_metrics

    t = torch.linspace(0.0, 1.0, 11, dtype=torch.float64)
    q = torch.zeros(11, 2, 2, dtype=torch.float64)  # (T, B, n)
    q[3:5, 0, 0] = 1.3  # env 0, joint 1: 2 of 11 rows past its upper limit 1.0, by 0.3
    q[7, 1, 1] = -2.5  # env 1, joint 2: 1 row past its lower limit -2.0, by 0.5
    roll = Rollout(t, q, torch.zeros_like(q), torch.zeros_like(q))
    sc = Scenario(duration=1.0, dt=0.1)
    limits = (torch.tensor([-1.0, -2.0]), torch.tensor([1.0, 2.0]))
    m = control_metrics(roll, torch.zeros(11, 2, dtype=torch.float64), sc, limits)
    assert m[0]["limit_breach"] == pytest.approx([2 / 11, 0.0]) and m[0]["limit_excess"] == pytest.approx([0.3, 0.0])
    assert m[1]["limit_breach"] == pytest.approx([0.0, 1 / 11]) and m[1]["limit_excess"] == pytest.approx([0.0, 0.5])
    unlimited = (torch.full((2,), -float("inf")), torch.full((2,), float("inf")))
    assert control_metrics(roll, q[:, 0], sc, unlimited)[0]["limit_breach"] == [0.0, 0.0]
    assert "limit_breach" not in control_metrics(roll, q[:, 0], sc)[0]


def test_pick_and_place_carries_drawn_masses_in_turn():
    carries = pick_and_place(60.0, 4, seed=3)
    assert carries == pick_and_place(60.0, 4, seed=3) != pick_and_place(60.0, 4, seed=4)
    assert len(carries) == 4 and carries[0].on == 1.0 and carries[-1].off < 60.0
    assert all(0 <= c.share <= 1 for c in carries) and len({c.share for c in carries}) == 4
    assert all(a.off < b.on for a, b in itertools.pairwise(carries))
    Scenario(duration=60.0, carries=carries).validate()
    with pytest.raises(ValueError, match="picks=0 must be >= 1"):
        pick_and_place(60.0, 0, seed=0)


def test_payload_schedule_carries_each_share_of_the_payload_in_its_window():
    sc = Scenario(duration=1.0, dt=0.1, carries=(Carry(0.2, 0.4, 0.5), Carry(0.6, 0.9, 1.0)))
    m = payload_schedule(sc, sc.steps, torch.tensor([10.0, 2.0]), dtype=torch.float64)
    assert m.shape == (10, 2)
    assert m[:, 0].tolist() == [0, 0, 5, 5, 0, 0, 10, 10, 10, 0]
    assert torch.equal(m[:, 1], m[:, 0] / 5)
    # without carries, the one window at the whole payload
    one = payload_schedule(
        Scenario(duration=1.0, dt=0.1, payload_on=0.3, payload_off=0.5), 10, torch.tensor([4.0]), dtype=torch.float64
    )
    assert one[:, 0].tolist() == [0, 0, 0, 4, 4, 0, 0, 0, 0, 0]
