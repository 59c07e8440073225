"""The closed-loop tuning of the adaptive network: one batch is the candidates' separate runs, its
scenarios are never the evaluation's, every search spends the same budget, bad keys are refused."""

import json
import math
from dataclasses import replace

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from torch.utils.tensorboard import SummaryWriter

from rbfn.config import (
    ACOConfig,
    Colony,
    ControlConfig,
    GainsConfig,
    LoopConfig,
    NetworkConfig,
    NetworkLaw,
    NetworkObjective,
    Objective,
    RobotConfig,
    TuneConfig,
)
from rbfn.control.comparison import compare_controllers
from rbfn.control.loop import real_loop
from rbfn.control.network import control_network, pilot_residuals
from rbfn.control.robot_setup import control_robot
from rbfn.control.simulator import Plant, Scenario, stage_disturbances
from rbfn.control.trajectory import Reference
from rbfn.control.tuning import ClosedLoopCost, tune_network, tuning_scenarios
from rbfn.robots.scara import ScaraTerms
from rbfn.studies.control import evaluate_control

from ..conftest import compose_config

TUNE = TuneConfig(scenarios=2, duration=0.8, payload_on=0.2, payload_off=0.6, population=4, iterations=2)
SEARCHES = ["arbfn_aco", "arbfn_random", "arbfn_cmaes"]
# The realistic loop of the SCARA (500 Hz, encoders, one period of delay, noise, torque limits).
REAL = LoopConfig(
    name="realistic",
    control_rate=500.0,
    actuation_delay=1,
    encoder_counts=[10485760.0, 10485760.0, 11377800.0],
    position_noise=1e-5,
    velocity_cutoff=50.0,
    torque_limits=True,
)


def _control(**kw) -> ControlConfig:
    base = dict(
        duration=1.2,
        payload_on=0.3,
        payload_off=0.9,
        payloads=[0.0, 10.0],
        network=NetworkConfig(num_centers=6, tune=TUNE, law=NetworkLaw.tracking),  # the law the tuning searches
        controllers=["smc", "arbfn_kmeans", *SEARCHES],
    )
    base.update(kw)
    return ControlConfig(**base)


def _cost(tune: TuneConfig = TUNE, loop: LoopConfig | None = REAL) -> ClosedLoopCost:
    """The SCARA's closed-loop cost for a 6-centre network, as compare_controllers builds it."""
    cfg = _control()
    setup = control_robot(RobotConfig(), cfg)
    sc = Scenario(cfg.duration, cfg.dt, cfg.integrator, cfg.payload_on, cfg.payload_off)
    ref = Reference(*setup.trajectory(sc.times(torch.float64)))
    gains, model = GainsConfig(), setup.model
    real = None if loop is None else real_loop(loop, sc.dt, setup.prismatic, torch.tensor(setup.effort))
    x, y = pilot_residuals(setup.plant, sc, ref, gains, model)
    twin = control_network("kmeans", x, y, m=6, seed=0, sample_dt=sc.dt * 10)
    scenarios = tuning_scenarios(
        tune,
        rated_payload=setup.rated_payload,
        disturbance=[5.0] * 3,
        eval_payloads=setup.payloads,
        eval_freq=cfg.disturbance_freq,
        eval_noise_seed=0,
    )
    tsc = Scenario(tune.duration, cfg.dt, cfg.integrator, tune.payload_on, tune.payload_off)
    return ClosedLoopCost(
        plant=setup.plant,
        model=model,
        gains=gains,
        twin=twin,
        scenarios=scenarios,
        scenario=tsc,
        ref=Reference(*setup.trajectory(tsc.times(torch.float64))),
        tune=tune,
        loop=real,
    )


@pytest.mark.parametrize(
    "duration,window,episode",
    [(10.0, (1.0, 4.0), (6.0, 1.0, 4.0)), (5.0, (1.0, 4.0), (3.0, 0.6, 2.4)), (1.2, (0.3, 0.9), (0.72, 0.18, 0.54))],
)
def test_the_derived_episode_is_shorter_than_the_evaluations(duration, window, episode):
    """Null tune.duration and window: min(6 s, 0.6 x control.duration), the evaluation's window
    where it fits, else scaled with the episode."""
    got = TuneConfig().episode(duration, *window)
    assert got == pytest.approx(episode)
    TuneConfig().check("control.network.tune", duration, window)


@pytest.mark.parametrize("loop", [REAL, None], ids=["realistic", "ideal"])
def test_one_batch_equals_the_candidates_separate_runs(loop):
    cost = _cost(loop=loop)
    g = torch.Generator().manual_seed(0)
    x = 0.3 * torch.randn(3, cost.dimension, generator=g, dtype=torch.float64)
    together = cost(x)
    apart = torch.cat([cost(x[i : i + 1]) for i in range(3)])
    # each environment's network, alone or in a batch: the same to rounding (a batch's kernels may sum in another order)
    torch.testing.assert_close(together, apart, rtol=1e-13, atol=0.0)
    assert torch.isfinite(together).all() and len(set(together.tolist())) == 3  # different networks, costs


def test_the_twin_is_the_origin_and_smc_costs_one_per_joint():
    cost = _cost()
    centers, widths = cost.networks(torch.zeros(1, cost.dimension, dtype=torch.float64))
    assert torch.equal(centers[0], cost.twin.centers) and torch.equal(widths[0], cost.twin.widths)
    assert cost.smc_rms.shape == (TUNE.scenarios, 3) and (cost.smc_rms > 0).all()


def test_a_varied_plant_feels_its_own_disturbance_in_each_environment():
    plant = Plant(ScaraTerms(), disturbance=5.0, disturbance_freq=2.0)
    amp = torch.tensor([[5.0, 5.0, 5.0], [1.0, 2.0, 3.0]], dtype=torch.float64)
    varied = plant.varied(amp, torch.tensor([2.0, 3.0]), torch.tensor([0.0, 0.5]))
    d = stage_disturbances(varied, 10, 1e-3, dtype=torch.float64)  # (10, 3, B, n)
    assert d.shape == (10, 3, 2, 3)
    torch.testing.assert_close(d[:, :, 0, 0], stage_disturbances(plant, 10, 1e-3, dtype=torch.float64))
    t = torch.arange(21, dtype=torch.float64) * 0.5e-3
    torch.testing.assert_close(d[:, 0, 1, 2], 3.0 * torch.sin(3.0 * t[0:-1:2] + 0.5))
    assert plant.dist == 5.0  # the original is untouched


def test_tuning_scenarios_are_never_the_evaluations():
    """Ranges that hold the evaluation's payloads, frequency and amplitude: none is drawn."""
    tune = TuneConfig(scenarios=40, payload=[0.0, 1.0], disturbance=[0.5, 1.5], disturbance_freq=[1.0, 4.0])
    eval_payloads = [0.0, 10.0, 20.0]
    sc = tuning_scenarios(
        tune, rated_payload=20.0, disturbance=[5.0] * 3, eval_payloads=eval_payloads, eval_freq=2.0, eval_noise_seed=0
    )
    assert sc.payloads.shape == (40,) and sc.amplitude.shape == (40, 3)
    assert torch.equal(sc.payloads // 0.5, torch.arange(40.0))  # stratified: one per part of the range
    for p in eval_payloads:
        assert (sc.payloads - p).abs().min() > 0.19  # 1 % of the 20 kg range
    assert (sc.freq - 2.0).abs().min() > 0.029 and (sc.amplitude[:, 0] / 5.0 - 1.0).abs().min() > 0.0099
    assert sc.noise_seed != 0
    assert 0.0 <= float(sc.phase.min()) and float(sc.phase.max()) <= 2 * math.pi
    again = tuning_scenarios(
        tune, rated_payload=20.0, disturbance=[5.0] * 3, eval_payloads=eval_payloads, eval_freq=2.0, eval_noise_seed=0
    )
    assert torch.equal(sc.payloads, again.payloads) and sc.noise_seed == again.noise_seed  # seeded


def test_the_evaluations_noise_seed_is_never_drawn():
    seeds = set()
    for s in range(20):
        tune = TuneConfig(scenarios=1, seed=s)
        seeds.add(
            tuning_scenarios(
                tune, rated_payload=1.0, disturbance=[1.0], eval_payloads=[], eval_freq=2.0, eval_noise_seed=s
            ).noise_seed
            - s
        )
    assert 0 not in seeds


def test_a_range_holding_only_an_evaluation_case_is_refused_by_name():
    with pytest.raises(ValueError, match=r"control.network.tune.payload=\[0.5, 0.5\].*evaluation's own"):
        tuning_scenarios(
            TuneConfig(payload=[0.5, 0.5]),
            rated_payload=20.0,
            disturbance=[5.0],
            eval_payloads=[10.0],
            eval_freq=2.0,
            eval_noise_seed=0,
        )


def test_every_search_spends_the_same_budget_and_keeps_its_best():
    res = compare_controllers(_control(), GainsConfig())
    budget = TUNE.population * TUNE.iterations * TUNE.scenarios
    twin = res.runs["arbfn_kmeans"].tuned
    assert twin is not None and twin.episodes == TUNE.scenarios
    for name in SEARCHES:
        tuned = res.runs[name].tuned
        assert tuned is not None and tuned.confirmation is not None, name
        # the search's budget, then the confirmation against the twin (and the twin's cost where kept)
        assert tuned.episodes == budget + 2 * TUNE.scenarios + (TUNE.scenarios if tuned.kept_twin else 0), name
        assert len(tuned.curve) == TUNE.iterations
        assert tuned.cost == (twin.cost if tuned.kept_twin else tuned.curve[-1])
        assert all(b <= a for a, b in zip(tuned.curve, tuned.curve[1:]))  # best so far
        mine, theirs = tuned.confirmation
        assert tuned.kept_twin == (mine > theirs)
        if name != "arbfn_cmaes":  # their first candidate is the twin
            assert tuned.curve[-1] <= twin.cost
    assert res.tune_scenarios is not None and not set(res.tune_scenarios.payloads.tolist()) & {0.0, 10.0}


def test_a_network_worse_than_its_twin_at_the_evaluations_length_gives_way_to_the_twin():
    """confirmed: a found network whose cost in full-length episodes exceeds the twin's is
    replaced by the twin (its tuning cost, its network); one no worse is kept as found."""
    from rbfn.control.tuning import confirmed

    cost = _cost(loop=None)
    tuned = tune_network("random", cost, TUNE, seed=0)
    assert tuned.x is not None

    class Fixed:  # a confirmation whose verdict is given
        s = cost.s

        def __init__(self, mine: float, theirs: float) -> None:
            self.values = torch.tensor([mine, theirs], dtype=torch.float64)

        def __call__(self, x: torch.Tensor) -> torch.Tensor:
            assert x.shape == (2, cost.dimension) and not x[1].any()  # the found network, then the twin
            return self.values

    kept = confirmed(tuned, cost, Fixed(1.0, 2.0))  # type: ignore[arg-type]
    assert not kept.kept_twin and kept.net is tuned.net and kept.episodes == tuned.episodes + 2 * cost.s
    back = confirmed(tuned, cost, Fixed(3.0, 2.0))  # type: ignore[arg-type]
    assert back.kept_twin and back.confirmation == (3.0, 2.0) and back.x is not None and not back.x.any()
    assert back.cost == float(cost(torch.zeros(1, cost.dimension, dtype=torch.float64))[0])
    assert torch.equal(back.net.centers, cost.twin.centers.double()) and torch.equal(
        back.net.widths, cost.twin.widths.double()
    )


def test_a_searchs_network_is_what_it_reports():
    """The tuned network re-evaluated alone costs what the search recorded."""
    cost = _cost(loop=None)
    tuned = tune_network("random", cost, TUNE, seed=0)
    assert tuned.x is not None and tuned.x.shape == (6 * 7 + 1,)
    assert float(cost(tuned.x[None])[0]) == tuned.cost
    centers, widths = cost.networks(tuned.x[None])
    assert torch.equal(tuned.net.centers, centers[0]) and torch.equal(tuned.net.widths, widths[0])


def test_the_static_objectives_stay():
    """objective=fit: arbfn_aco is the pilot-fit colony, exactly as control_network selects it."""
    aco = ACOConfig(iterations=2, ants=4)
    cfg = _control(
        controllers=["arbfn_aco"], network=NetworkConfig(num_centers=6, aco=aco, objective=NetworkObjective.fit)
    )
    res = compare_controllers(cfg, GainsConfig())
    assert res.runs["arbfn_aco"].tuned is None and res.tune_scenarios is None


@pytest.mark.parametrize(
    "change,match",
    [
        ({"duration": 1.2}, r"control.network.tune.duration=1.2 .*shorter than control.duration"),
        ({"payload_off": 1.5}, r"control.network.tune.payload_on/payload_off"),
        ({"population": 1}, r"control.network.tune.population=1 .*>= 2"),
        ({"payload": [1.0, 0.0]}, r"control.network.tune.payload=\[1.0, 0.0\] .*low <= high"),
        ({"disturbance_freq": [-1.0, 2.0]}, r"control.network.tune.disturbance_freq=.*low >= 0"),
        ({"iterations": 0}, r"control.network.tune.iterations=0"),
        ({"scenarios": 0}, r"control.network.tune.scenarios=0"),
    ],
)
def test_bad_tuning_settings_are_refused_by_name(change, match):
    tune = replace(TuneConfig(duration=1.0, payload_on=0.2, payload_off=0.9), **change)
    with pytest.raises(ValueError, match=match):
        _control(network=NetworkConfig(num_centers=6, tune=tune, law=NetworkLaw.tracking)).check()


@pytest.mark.parametrize(
    "change,match",
    [
        ({"aco": ACOConfig(colony=Colony.ant_system)}, r"control.network.aco.colony='ant_system'.*acor"),
        ({"aco": ACOConfig(objective=Objective.cluster)}, r"control.network.aco.objective='cluster'.*objective"),
    ],
)
def test_settings_the_closed_loop_search_cannot_take_are_refused_by_name(change, match):
    with pytest.raises(ValueError, match=match):
        _control(network=NetworkConfig(num_centers=6, tune=TUNE, law=NetworkLaw.tracking, **change)).check()


def test_bad_keys_fail_at_composition_naming_the_options():
    with pytest.raises(Exception) as e:
        compose_config("evaluate", "control.network.objective=magic")
    message = f"{e.value} {e.value.__cause__}"  # Hydra shows both on the command line
    assert "objective=magic" in message and "expected one of [closed_loop, fit, cluster]" in message
    with pytest.raises(Exception) as e:
        compose_config("evaluate", "control.network.tune.episodes=3")
    assert "tune.episodes" in f"{e.value} {e.value.__cause__}"
    net = compose_config("evaluate").control.network  # the law and objective derived from the loop
    assert net.law is None and net.objective is None
    assert net.resolved(realistic=True).law == NetworkLaw.two_phase
    assert net.resolved(realistic=True).objective == NetworkObjective.fit
    ideal = net.resolved(realistic=False)
    assert ideal.law == NetworkLaw.tracking and ideal.objective == NetworkObjective.closed_loop
    # asking for the closed-loop tuning asks for the law it tunes
    tuned = replace(net, objective=NetworkObjective.closed_loop).resolved(realistic=True)
    assert tuned.law == NetworkLaw.tracking


def test_the_other_controllers_do_not_change_when_the_colony_tunes_on_the_closed_loop():
    names = ["smc", "smc_obs", "arbfn_aco", "arbfn_kmeans"]
    fit = NetworkConfig(num_centers=6, tune=TUNE, objective=NetworkObjective.fit)
    static = compare_controllers(_control(controllers=names, network=fit), GainsConfig())
    tuned = compare_controllers(_control(controllers=names), GainsConfig())
    for name in ("smc", "smc_obs", "arbfn_kmeans"):
        assert tuned.runs[name].metrics == static.runs[name].metrics, name
    assert tuned.runs["arbfn_aco"].metrics != static.runs["arbfn_aco"].metrics


def test_metrics_json_reports_the_tuned_cost_beside_the_held_out_result(tmp_path):
    cfg = _control(controllers=["smc", "arbfn_kmeans", "arbfn_aco"])
    with SummaryWriter(str(tmp_path)) as writer:
        info = evaluate_control(cfg, GainsConfig(), device="cpu", writer=writer, out_dir=tmp_path)["control_info"]
    json.dumps(info)
    assert set(info["tuning"]) == {"arbfn_kmeans", "arbfn_aco"}
    aco = info["tuning"]["arbfn_aco"]
    assert set(aco) == {"cost", "held_out", "episodes", "seconds", "curve", "confirmation", "kept_twin"}
    extra = 2 * TUNE.scenarios + (TUNE.scenarios if aco["kept_twin"] else 0)  # the confirmation
    assert aco["episodes"] == TUNE.population * TUNE.iterations * TUNE.scenarios + extra and len(aco["curve"]) == 2
    assert len(aco["confirmation"]) == 2 and aco["kept_twin"] == (aco["confirmation"][0] > aco["confirmation"][1])
    assert math.isfinite(aco["held_out"]) and aco["held_out"] > 0
    assert len(info["tuning_scenarios"]["payloads"]) == TUNE.scenarios
    assert info["tuning_seconds"] >= aco["seconds"] > 0  # the whole tuning holds the search and more
    events = EventAccumulator(str(tmp_path)).Reload()
    assert [e.step for e in events.Scalars("control/tuning/arbfn_aco/cost")] == [1, 2]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_the_tuning_runs_on_cuda_as_on_the_cpu():
    """device=cuda runs the whole batch (candidates x scenarios) on the GPU; the searches see the
    same costs to rounding, so they spend the same budget and land close."""
    cfg = _control(controllers=["smc", "arbfn_kmeans", "arbfn_aco"])
    cpu, gpu = (compare_controllers(cfg, GainsConfig(), device) for device in ("cpu", "cuda"))
    a, b = cpu.runs["arbfn_aco"].tuned, gpu.runs["arbfn_aco"].tuned
    assert a is not None and b is not None and a.episodes == b.episodes
    assert b.cost == pytest.approx(a.cost, rel=0.05)
    twin_cpu, twin_gpu = cpu.runs["arbfn_kmeans"].metrics, gpu.runs["arbfn_kmeans"].metrics
    for case, m in twin_cpu.items():  # no search: the same run to rounding
        assert twin_gpu[case]["rms_err"] == pytest.approx(m["rms_err"], rel=1e-3)
