"""The realistic loop's sensor and actuator models, each on its own (rbfn.control.loop) and inside
the simulator: quantisation steps, the velocity filter's response, delays in whole periods,
saturation and the time spent saturated; with every part off it is the ideal loop."""

import math
from dataclasses import replace

import pytest
import torch

from rbfn.config import GainsConfig, LoopConfig
from rbfn.control import Plant, Scenario, make_controller, paper_trajectory, simulate
from rbfn.control.controllers import Controller
from rbfn.control.loop import RealLoop, filter_gain, filtered_velocity, quantise, real_loop, saturate, velocity_lag
from rbfn.control.models import NominalModel
from rbfn.robots.scara import ScaraTerms

from ..conftest import compose_config

SCARA_MODEL = NominalModel(ScaraTerms())  # the paper's nominal model of the SCARA


class Echo(Controller):
    """Commands what it is asked to test: the reference's q_d (a sequence of known values), or
    the measured positions it was given (mode "measured")."""

    def __init__(self, mode: str = "reference") -> None:
        super().__init__(GainsConfig(), 1e-3)
        self.mode = mode

    def torque(self, ref, q, qd, state, *, h=None, alpha=None, applied=None, forces=None):
        return (ref.q_d.expand_as(q) if self.mode == "reference" else q).clone(), state


def _compare(*overrides: str, derive: bool = False):
    """evaluate.py's closed-loop comparison for `overrides` (its robot checked first; `derive`: the
    robot=urdf keys filled in as evaluate.py does): (ControlComparison, ControlRobot)."""
    from rbfn.control.comparison import compare_controllers
    from rbfn.robots.derive import derive_evaluate
    from rbfn.studies.control import check_control

    cfg = compose_config("evaluate", *overrides)
    cfg = derive_evaluate(cfg) if derive else cfg
    setup = check_control(cfg.control, cfg.robot)
    return compare_controllers(cfg.control, cfg.gains, "cpu", setup=setup, loop=cfg.loop), setup


def _run(loop: RealLoop, ctrl: Controller, steps: int = 20, dt: float = 1e-3, ref=None, q0=None):
    sc = Scenario(duration=steps * dt, dt=dt, payload_on=0.0, payload_off=steps * dt, metrics_after=0.0)
    t = sc.times()
    if ref is None:  # q_d = k, the step's index, on every joint: a command names its period
        k = torch.arange(t.shape[0], dtype=torch.float64)[:, None].expand(-1, 3)
        ref = (k, torch.zeros_like(k), torch.zeros_like(k))
    q0 = torch.tensor([[1.0, 1.0, 1.0]], dtype=torch.float64) if q0 is None else q0
    return simulate(
        Plant(ScaraTerms()),
        ctrl,
        sc,
        ref,
        q0=q0,
        qd0=torch.zeros_like(q0),
        payload=torch.zeros(1, dtype=torch.float64),
        loop=loop,
    )


def test_quantise_rounds_to_whole_counts():
    res = torch.tensor([2 * math.pi / 4096, 1e-3], dtype=torch.float64)
    q = torch.tensor([[0.12345, 0.5004], [-1.0, -0.0004]], dtype=torch.float64)
    y = quantise(q, res)
    counts = y / res
    assert torch.allclose(counts, counts.round(), atol=1e-9)
    assert ((y - q).abs() <= res / 2 + 1e-15).all()


def test_encoder_counts_are_per_revolution_or_per_metre():
    loop = real_loop(LoopConfig(encoder_counts=[4096, 1000]), 1e-3, [False, True], torch.tensor([1.0, 1.0]), None)
    assert loop is not None and loop.resolution is not None
    assert loop.resolution.tolist() == pytest.approx([2 * math.pi / 4096, 1e-3])


def test_the_velocity_filter_is_first_order_at_its_cutoff():
    period, cutoff = 1e-4, 50.0
    a = filter_gain(cutoff, period)
    assert a == pytest.approx(1 - math.exp(-2 * math.pi * cutoff * period))
    # A ramp of 1 rad/s: the filtered difference rises as 1 - (1 - a)^k, reaching 63 % in one time constant.
    v, prev = torch.zeros(1, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)
    out = []
    for k in range(1, 2000):
        y = torch.tensor([k * period], dtype=torch.float64)
        v = filtered_velocity(v, y, prev, period, a)
        prev = y
        out.append(float(v))
    assert out[0] == pytest.approx(a)
    assert out[49] == pytest.approx(1 - (1 - a) ** 50, rel=1e-12)
    tau_periods = 1 / (2 * math.pi * cutoff * period)  # the time constant in periods
    assert out[round(tau_periods) - 1] == pytest.approx(1 - math.exp(-1), abs=0.05)
    assert out[-1] == pytest.approx(1.0, abs=1e-6)


def test_saturate_clips_each_joint_at_its_own_limit():
    limit = torch.tensor([1.0, 10.0, math.inf])
    tau = torch.tensor([[5.0, -50.0, 1e9], [-0.5, 3.0, -1e9]])
    assert saturate(tau, limit).tolist() == [[1.0, -10.0, 1e9], [-0.5, 3.0, -1e9]]


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_command_acts_after_the_actuation_delay(delay):
    roll = _run(RealLoop(actuation_delay=delay), Echo())
    applied = roll.tau[:-1, 0, 0]  # per period: the torque applied during it
    expected = torch.clamp(torch.arange(applied.shape[0], dtype=torch.float64) - delay, min=0)
    expected[:delay] = 0.0  # nothing was commanded before the start
    assert torch.equal(applied, expected)


@pytest.mark.parametrize("delay", [0, 2])
def test_the_controller_sees_positions_sensing_delay_periods_old(delay):
    ref = paper_trajectory(torch.arange(21, dtype=torch.float64) * 1e-3)
    roll = _run(RealLoop(sensing_delay=delay), Echo("measured"), ref=ref, q0=ref.q_d[:1].clone())
    seen = roll.tau[:-1, 0]  # what the controller measured, commanded back
    true = roll.q[:-1, 0]
    assert torch.equal(seen[delay:], true[: true.shape[0] - delay])
    assert torch.equal(seen[:delay], true[:1].expand(delay, -1))  # before that: the initial position


def test_the_control_period_holds_the_torque_over_its_substeps():
    roll = _run(RealLoop(substeps=4, period=4e-3), Echo(), steps=40)
    assert roll.t.shape[0] == 11 and torch.allclose(
        roll.t[1:] - roll.t[:-1], torch.full((10,), 4e-3, dtype=torch.float64)
    )
    assert roll.tau[:-1, 0, 0].tolist() == [4.0 * k for k in range(10)]  # q_d at each period's first step


def test_saturation_clips_and_counts_the_time_at_the_limit():
    limit = torch.tensor([5.0, 5.0, 1e9], dtype=torch.float64)
    roll = _run(RealLoop(torque_limit=limit), Echo(), steps=20)  # commands 0, 1, ..., 19
    assert roll.tau[:-1, 0, 0].tolist() == [min(k, 5.0) for k in range(20)]
    assert roll.saturated is not None
    assert roll.saturated[0].tolist() == pytest.approx([14 / 20, 14 / 20, 0.0])  # k = 6 .. 19


def test_noise_is_seeded_and_encoders_quantise_what_the_controller_sees():
    res = torch.tensor([1e-3, 1e-3, 1e-3], dtype=torch.float64)
    loop = RealLoop(resolution=res, position_noise=1e-3, seed=7)
    a, b = _run(loop, Echo("measured")), _run(loop, Echo("measured"))
    assert torch.equal(a.tau, b.tau)
    counts = a.tau[:-1, 0] / 1e-3
    assert torch.allclose(counts, counts.round(), atol=1e-9)
    assert not torch.equal(a.tau, _run(RealLoop(resolution=res, position_noise=1e-3, seed=8), Echo("measured")).tau)


def test_with_every_part_off_the_realistic_loop_is_the_ideal_one():
    """A RealLoop that senses exactly and acts at once every step reproduces the ideal loop (the
    same law, told the torque it applied; the operations' order differs: to rounding)."""
    cfg = compose_config("evaluate", "loop=ideal")
    assert real_loop(cfg.loop, 1e-3, [False] * 3, torch.ones(3)) is None  # loop=ideal: the ideal path
    sc = Scenario(duration=1.0, dt=1e-3, payload_on=0.2, payload_off=0.8)
    ref = paper_trajectory(sc.times())
    q0, qd0 = ref.q_d[:1].clone(), ref.qd_d[:1].clone()
    payload = torch.tensor([10.0], dtype=torch.float64)
    runs = []
    for loop in (None, RealLoop()):
        ctrl = make_controller("smc_obs", cfg.gains, sc.dt, model=SCARA_MODEL)
        runs.append(simulate(Plant(ScaraTerms()), ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, loop=loop))
    ideal, real = runs
    assert torch.allclose(ideal.q, real.q, rtol=0, atol=1e-10)
    assert torch.allclose(ideal.tau, real.tau, rtol=1e-9, atol=1e-7)


@pytest.mark.parametrize(
    "override,key",
    [
        ("loop.control_rate=300", "loop.control_rate"),
        ("loop.actuation_delay=-1", "loop.actuation_delay"),
        ("loop.velocity_cutoff=0", "loop.velocity_cutoff"),
        ("loop.encoder_counts=[0.5]", "loop.encoder_counts"),
    ],
)
def test_bad_loop_settings_are_refused_by_key(override, key):
    cfg = compose_config("evaluate", *override.split())
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        cfg.check()


@pytest.mark.parametrize("robot", ["scara", "ur5", "panda"])
def test_the_default_loop_is_realistic_with_its_gains_and_ideal_keeps_the_tuned_set(robot):
    """evaluate.py's default: loop=realistic with the robot's realistic gains; loop=ideal is one
    override back to the tuned set; an explicit gains= wins in either loop."""
    default, ideal = (
        compose_config("evaluate", f"robot={robot}"),
        compose_config("evaluate", f"robot={robot}", "loop=ideal"),
    )
    assert default.loop.name == "realistic" and not default.loop.ideal
    assert default.gains == compose_config("evaluate", f"robot={robot}", "loop=realistic", "gains=realistic").gains
    assert ideal.loop.ideal and ideal.gains == compose_config("evaluate", f"robot={robot}", "gains=tuned").gains
    assert ideal.gains != default.gains
    paper = compose_config("evaluate", f"robot={robot}", "gains=paper")
    assert (
        paper.loop.name == "realistic"
        and paper.gains == compose_config("evaluate", f"robot={robot}", "loop=ideal", "gains=paper").gains
    )


def test_the_realistic_preset_takes_the_robots_rate_and_encoders():
    cfg = compose_config("evaluate", "robot=ur5", "loop=realistic")
    assert cfg.loop.control_rate == cfg.robot.control_rate == 500.0
    assert cfg.loop.encoder_counts == cfg.robot.encoder_counts and len(cfg.loop.encoder_counts) == 6
    assert cfg.loop.torque_limits and cfg.loop.actuation_delay == 1 and not cfg.loop.ideal


def test_the_perfect_knowledge_ceiling_and_the_gap_each_controller_closes():
    """smc_exact knows every force: with exact state it tracks far better than smc, and in the
    realistic loop it sets the ceiling each controller's gap closure is read against (smc 0,
    smc_exact 1 on every joint)."""
    from rbfn.studies.control import control_table

    for loop in ("ideal", "realistic"):
        res, setup = _compare(
            f"loop={loop}",
            "control.duration=2.0",
            "control.payload_off=1.5",
            "control.payloads=[0.0,10.0]",
            "control.controllers=[smc,smc_obs,smc_exact]",
            "gains.observer_gain=30",
        )
        for case in ("0kg", "10kg"):
            smc, exact = res.runs["smc"].metrics[case], res.runs["smc_exact"].metrics[case]
            assert all(e < s / 5 for e, s in zip(exact["rms_err"], smc["rms_err"])), (loop, case)
            assert smc["gap_closure"] == [0.0] * 3 and exact["gap_closure"] == [1.0] * 3
            assert all(0 < g <= 1.5 for g in res.runs["smc_obs"].metrics[case]["gap_closure"])
        table = control_table({k: r.metrics for k, r in res.runs.items()}, setup.units)
        assert "gap min" in table and ("sat max" in table) == (loop == "realistic")


def test_every_controller_meets_the_same_noise_in_a_case():
    """noise_envs = the payload cases: environment b and b + noise_envs see the same measurement
    noise (common random numbers), so controllers are compared on equal terms."""
    loop = RealLoop(position_noise=1e-3, noise_envs=2, seed=3)
    sc = Scenario(duration=0.01, dt=1e-3, payload_on=0.0, payload_off=0.01, metrics_after=0.0)
    k = torch.arange(11, dtype=torch.float64)[:, None].expand(-1, 3)
    q0 = torch.tensor([[1.0, 1.0, 1.0], [0.5, 0.5, 0.5]] * 2, dtype=torch.float64)
    roll = simulate(
        Plant(ScaraTerms()),
        Echo("measured"),
        sc,
        (k, 0 * k, 0 * k),
        q0=q0,
        qd0=torch.zeros_like(q0),
        payload=torch.zeros(4),
        loop=loop,
    )
    noise = roll.tau[:-1] - roll.q[:-1]  # what the controller saw less the truth
    assert torch.equal(noise[:, 0], noise[:, 2]) and torch.equal(noise[:, 1], noise[:, 3])
    assert not torch.equal(noise[:, 0], noise[:, 1])


@pytest.mark.parametrize("robot", ["scara", "ur5"])
def test_the_nominal_model_can_carry_a_payload(robot):
    """gains.nominal_payload: 0 is the unloaded model itself; a payload adds its inertia (the
    closed form's and the URDF model's alike)."""
    cfg = compose_config("evaluate", f"robot={robot}")
    from rbfn.studies.control import check_control

    setup = check_control(cfg.control, cfg.robot)
    assert setup.nominal_model(0.0) is setup.model
    q = torch.tensor([setup.home], dtype=torch.float64)
    qd = torch.zeros_like(q)
    v = torch.ones_like(q)
    light, heavy = (setup.nominal_model(p).at(q, qd) for p in (0.0, 5.0))
    assert (heavy.m_times(v) - light.m_times(v)).abs().max() > 1e-3
    assert (heavy.gravity() - light.gravity()).abs().max() > 1e-3


def test_inertia_scaling_slows_each_joints_integrators_by_its_rated_inertia():
    """gains.inertia_scaling: per joint, the observer no faster than K / Mr_jj and Gamma divided by
    Mr_jj / M0_jj (the nominal inertia at home carrying the rated payload, and unloaded). On the
    SCARA's prismatic joint M_33 is 0.9 times the quill's mass, so its factor is the masses' ratio."""
    from rbfn.robots.scara import ScaraParams, inertia_params
    from rbfn.studies.control import check_control

    cfg = compose_config("evaluate")  # the default: loop=realistic, its gains
    assert (
        cfg.loop.name == "realistic"
        and cfg.gains.inertia_scaling
        and not compose_config("evaluate", "loop=ideal").gains.inertia_scaling
    )
    setup = check_control(cfg.control, cfg.robot)
    rates = setup.joint_rates(cfg.gains, dtype=torch.float64)
    assert rates is not None and rates.observer.shape == rates.gamma.shape == (3,)
    m3, m3_rated = (inertia_params(p, ScaraParams())[3] for p in (0.0, cfg.robot.rated_payload))
    assert rates.gamma[2].item() == pytest.approx(m3 / m3_rated, rel=1e-12)
    k_over = cfg.gains.K / (cfg.gains.observer_gain * 0.9 * m3_rated)
    assert rates.observer[2].item() == pytest.approx(min(1.0, k_over), rel=1e-12)
    assert bool(((rates.observer > 0) & (rates.observer <= 1) & (rates.gamma > 0) & (rates.gamma <= 1)).all())
    off = compose_config("evaluate", "loop=realistic", "gains=realistic", "gains.inertia_scaling=false")
    assert setup.joint_rates(off.gains) is None


def test_joint_rates_scale_the_observer_and_the_adaptation_per_joint_alone_and_batched():
    """A controller with JointRates: d_hat and the weights' step are the unscaled ones times each
    joint's factor, and a batch of such controllers (SlidingModeBatch) does exactly what each does."""
    from rbfn.control.batch import Stacked
    from rbfn.control.controllers import JointRates
    from rbfn.control.trajectory import Reference

    gains, dt = GainsConfig(observer_gain=30.0, gamma=100.0), 1e-3
    rates = JointRates(torch.tensor([0.5, 1.0, 0.1], dtype=torch.float64), torch.tensor([1.0, 0.25, 0.5]).double())
    feats = torch.rand(5, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    ref = Reference(*(torch.tensor(v, dtype=torch.float64) for v in ([0.3, 0.2, 0.1], [0.1, 0.0, 0.2], [0.0] * 3)))
    q0, qd0 = torch.zeros(2, 3, dtype=torch.float64), torch.zeros(2, 3, dtype=torch.float64)
    q, qd = torch.tensor([[0.1, -0.2, 0.05]] * 2).double(), torch.tensor([[0.3, 0.1, -0.2]] * 2).double()
    alpha = torch.tensor(gains.gamma * dt, dtype=torch.float64)

    def step(r):
        c = make_controller("arbfn_x", gains, dt, model=SCARA_MODEL, features=feats, rates=r)
        st = c.init_state(q0, qd0)
        _, st = c.torque(ref, q0, qd0, st, h=feats[0], alpha=alpha)  # the observer integrates a period
        return c.torque(ref, q, qd, st, h=feats[1], alpha=alpha)[1]

    plain, scaled = step(None), step(rates)
    assert torch.allclose(scaled.d_hat, plain.d_hat * rates.observer, rtol=1e-12, atol=0)
    w0 = torch.zeros_like(plain.w)
    assert torch.allclose(scaled.w - w0, (plain.w - w0) * rates.gamma, rtol=1e-12, atol=1e-15)
    parts = [
        make_controller(f"arbfn_{k}", gains, dt, model=SCARA_MODEL, features=feats, rates=rates) for k in ("a", "b")
    ]
    batch = Stacked(parts, [2, 2])
    assert len(batch.units) == 1  # one SlidingModeBatch
    st = batch.init_state(q0.repeat(2, 1), qd0.repeat(2, 1))
    h = torch.cat([feats, feats], -1)
    _, st = batch.torque(ref, q0.repeat(2, 1), qd0.repeat(2, 1), st, h=h[0], alpha=alpha[None])
    _, st = batch.torque(ref, q.repeat(2, 1), qd.repeat(2, 1), st, h=h[1], alpha=alpha[None])
    assert torch.allclose(st[0].d_hat, scaled.d_hat.repeat(2, 1), rtol=1e-12, atol=1e-15)
    assert not torch.equal(batch.units[0].rates.observer, torch.ones(3).double())


def test_the_rated_payload_no_longer_drives_the_integrators_into_the_limits():
    """The SCARA at its rated 20 kg in the realistic loop: with the realistic gains' per-joint rates
    the observer and the adaptive network stay off the torque limits; without them (one K_o and
    Gamma for every joint) the observer's loop oscillates into the prismatic joint's 500 N."""

    def saturated(*extra):
        res, _ = _compare(
            "control.duration=3.0",
            "control.payload_on=0.5",
            "control.payload_off=3.0",
            "control.payloads=[20.0]",
            "control.controllers=[smc_obs,arbfn_kmeans]",
            *extra,
        )
        return {k: max(r.metrics["20kg"]["saturated"]) for k, r in res.runs.items()}

    assert all(v <= 0.01 for v in saturated().values())
    assert saturated("gains.inertia_scaling=false", "gains.gamma=500")["smc_obs"] > 0.05


def test_the_crossover_limit_keeps_the_phase_margin_against_the_loops_lag():
    """crossover_limit: with exact velocity and no delay the lag is the hold's w T / 2, so the
    limit is (90 - margin) deg / (T / 2); with delay and the filter the lag at the limit is
    90 - margin deg, lower limits for more delay, and the Nyquist frequency where nothing lags."""
    from rbfn.control.loop import crossover_limit

    t = 2e-3
    assert crossover_limit(RealLoop(period=t), 30.0) == pytest.approx(math.radians(60.0) / (t / 2), rel=1e-9)
    loop = RealLoop(period=t, actuation_delay=1, velocity_gain=filter_gain(50.0, t))
    w = crossover_limit(loop, 30.0)
    a, x = loop.velocity_gain, w * t
    lag = 2.0 * x + math.atan2((1 - a) * math.sin(x), 1 - (1 - a) * math.cos(x))
    assert lag == pytest.approx(math.radians(60.0), abs=1e-9)
    assert crossover_limit(RealLoop(period=t, actuation_delay=3, velocity_gain=a), 30.0) < w
    assert crossover_limit(loop, 60.0) < w < crossover_limit(loop, 10.0)


@pytest.mark.parametrize("robot", ["scara", "ur5"])
def test_feedback_scale_caps_only_joints_whose_apparent_inertia_is_too_light(robot):
    """feedback_scale: s_j min(1, w Me_jj / (K s_j)) with Me_jj = 1 / (M_hat^-1)_jj at home; the
    joint scale itself where no joint reaches the limit, and the ideal loop's (no limit) always."""
    from rbfn.studies.control import check_control

    cfg = compose_config("evaluate", f"robot={robot}")
    setup = check_control(cfg.control, cfg.robot)
    assert setup.feedback_scale(cfg.gains, None) is setup.scale
    apparent = 1.0 / torch.linalg.inv(setup.home_inertia()).diagonal()
    s = torch.ones(setup.n, dtype=torch.float64) if setup.scale is None else torch.tensor(setup.scale)
    bandwidth = cfg.gains.K * s / apparent  # rad/s per joint
    w = 0.5 * float(bandwidth.max() + bandwidth.min())  # between the slowest and the fastest joint
    capped = torch.tensor(setup.feedback_scale(cfg.gains, w), dtype=torch.float64)
    fast = bandwidth > w
    assert bool(fast.any()) and not bool(fast.all())
    assert torch.allclose(capped[fast], w * apparent[fast] / cfg.gains.K, rtol=1e-12)
    assert torch.equal(capped[~fast], s[~fast])
    assert setup.feedback_scale(cfg.gains, float(bandwidth.max()) * 1.01) is setup.scale


@pytest.mark.parametrize("robot", ["scara", "ur5", "panda"])
def test_the_ideal_loop_caps_only_feedback_its_step_cannot_follow(robot):
    """gain_factors in the ideal loop: the joint scale capped at integration_limit(dt); no shipped
    arm's joint reaches it at 1 kHz (their ideal-loop results stay as they were), at 10 ms the
    fastest joint is capped to it."""
    from rbfn.control.loop import integration_limit
    from rbfn.studies.control import check_control

    cfg = compose_config("evaluate", f"robot={robot}", "loop=ideal")
    setup = check_control(cfg.control, cfg.robot)
    assert setup.gain_factors(cfg.gains, None, dt=1e-3).listed is setup.scale
    apparent = 1.0 / torch.linalg.inv(setup.home_inertia()).diagonal()
    s = torch.ones(setup.n, dtype=torch.float64) if setup.scale is None else torch.tensor(setup.scale)
    bandwidth = cfg.gains.K * s / apparent
    dt = 1.5 * 0.5 / float(bandwidth.max())  # the fastest joint 1.5x beyond what this step follows
    capped = torch.tensor(setup.gain_factors(cfg.gains, None, dt=dt).listed, dtype=torch.float64)
    fastest = int(bandwidth.argmax())
    assert float(cfg.gains.K * capped[fastest] / apparent[fastest]) == pytest.approx(integration_limit(dt))


def test_a_coupled_arm_keeps_off_its_torque_limits_with_the_phase_margin():
    """The Unitree Z1 (example-robot-data, robot=urdf): its elbow's apparent inertia is a tenth of
    M_33, so the joint-scaled feedback crosses over at about 470 rad/s, beyond what one period of
    delay at 500 Hz allows, and cycles between its limits; capped for the phase margin it does not."""
    from importlib import metadata
    from pathlib import Path

    try:
        root = Path(str(metadata.distribution("example-robot-data").locate_file("")))
    except metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    found = list((root / "cmeel.prefix").rglob("z1_description/urdf/z1.urdf"))
    if not found:
        pytest.skip("example-robot-data holds no Z1")
    over = ["robot=urdf", f"robot.urdf={found[0]}", "robot.end_link=link06", "control.duration=1.5"]
    over += ["control.payload_on=0.3", "control.payload_off=1.2", "control.controllers=[smc,smc_obs]"]

    def saturated(*extra):
        res, _ = _compare(*over, *extra, derive=True)
        return max(max(m["saturated"]) for r in res.runs.values() for m in r.metrics.values())

    assert saturated() <= 0.01
    assert saturated("gains.phase_margin=0") > 0.2


def _realistic_scara(chunk: int, **kw):
    """evaluate.py's realistic loop on the SCARA (noise, encoders, delays, saturation, two
    integration steps per period; torque noise too), `smc_obs` at its gains, two payloads, 0.3 s in
    chunks of `chunk`."""
    cfg = compose_config("evaluate", "loop=realistic")
    sc = Scenario(duration=0.3, dt=1e-3, payload_on=0.05, payload_off=0.2, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    loop = real_loop(cfg.loop, sc.dt, [False, False, True], torch.tensor([80.0, 40.0, 300.0], dtype=torch.float64))
    assert loop is not None and loop.substeps > 1 and loop.position_noise
    loop = replace(loop, torque_noise=torch.full((3,), 0.05, dtype=torch.float64))  # both noise streams
    ctrl = make_controller("smc_obs", cfg.gains, loop.period, model=SCARA_MODEL)
    payload = torch.tensor([0.0, 10.0], dtype=torch.float64)
    q0, qd0 = ref.q_d[:1].expand(2, 3).clone(), ref.qd_d[:1].expand(2, 3).clone()
    return simulate(Plant(ScaraTerms()), ctrl, sc, ref, q0=q0, qd0=qd0, payload=payload, loop=loop, chunk=chunk, **kw)


def test_the_realistic_run_does_not_depend_on_its_chunk_length():
    """The noise is drawn in blocks of fixed length whatever the chunk, so the chunk length (1, 7,
    the default 100) changes nothing, bit for bit (torch draws 16 or more numbers by another
    algorithm than fewer: draws per chunk made the run depend on it)."""
    runs = [_realistic_scara(chunk) for chunk in (1, 7, 0)]
    for other in runs[1:]:
        assert torch.equal(other.q, runs[0].q) and torch.equal(other.tau, runs[0].tau)


@pytest.mark.slow
def test_the_compiled_realistic_loop_equals_the_eager_one(tmp_path, monkeypatch):
    """`compile=True` serves the realistic loop: the same run as eagerly, to rounding."""
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    eager, compiled = _realistic_scara(1), _realistic_scara(1, compile=True)  # one period per call: the smallest graph
    assert torch.allclose(compiled.q, eager.q, rtol=0, atol=1e-12)
    assert torch.allclose(compiled.tau, eager.tau, rtol=1e-9, atol=1e-9)


def test_velocity_lag_is_how_far_the_filtered_velocity_trails_a_slow_motion():
    """A joint at q = sin(w t), w far below the 50 Hz cutoff, measured every period through the
    backward difference and the filter: its velocity matches cos(w (t - lag)) to within 0.3 % of
    w, and trails cos(w t) itself by about w^2 lag."""
    period, w = 2e-3, 3.0
    loop = real_loop(
        LoopConfig(name="realistic", control_rate=1 / period, velocity_cutoff=50.0), 1e-3, [False], torch.ones(1)
    )
    assert loop is not None and loop.velocity_gain is not None
    lag = velocity_lag(loop)
    assert lag == pytest.approx(period * (0.5 + (1 - loop.velocity_gain) / loop.velocity_gain))
    t = torch.arange(0, 4.0, period, dtype=torch.float64)
    y, v = torch.sin(w * t), torch.zeros(())
    out = []
    for k in range(1, t.shape[0]):
        v = filtered_velocity(v, y[k], y[k - 1], period, loop.velocity_gain)
        out.append(v)
    measured, late = torch.stack(out)[1000:], t[1:][1000:]  # after the filter's start
    assert float((measured - w * torch.cos(w * (late - lag))).abs().max()) < 3e-3 * w
    assert float((measured - w * torch.cos(w * late)).abs().max()) > 0.5 * w * w * lag
    assert velocity_lag(None) == 0.0
    assert (
        velocity_lag(real_loop(LoopConfig(name="realistic", velocity_cutoff=None), 1e-3, [False], torch.ones(1))) == 0.0
    )
