"""The closed-loop comparison and its outputs; bad control settings stop before any work."""

import json
import math
from dataclasses import replace

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from torch.utils.tensorboard import SummaryWriter

from rbfn.config import (
    ACOConfig,
    ACORConfig,
    ControlConfig,
    Feedforward,
    GainsConfig,
    LoopConfig,
    NetworkConfig,
    NetworkLaw,
    NetworkObjective,
    Objective,
    PickAndPlaceConfig,
    TuneConfig,
)
from rbfn.control import SimulationDiverged
from rbfn.control.comparison import compare_controllers
from rbfn.studies.control import evaluate_control, held_out

from ..conftest import compose_config

KEYS = {"rms_err", "max_err", "max_err_payload", "peak_tau", "chattering", "limit_breach", "limit_excess"}


def _short(**kw):
    tune = TuneConfig(scenarios=2, duration=0.8, payload_on=0.2, payload_off=0.6, population=4, iterations=2)
    net = NetworkConfig(num_centers=8, aco=ACOConfig(iterations=5, ants=6, acor=ACORConfig(archive_size=6)), tune=tune)
    base = dict(
        duration=1.2,
        payload_on=0.3,
        payload_off=0.9,
        payloads=[0.0, 10.0],
        network=net,
        controllers=["pd", "ctc", "smc", "smc_obs", "arbfn_aco", "arbfn_kmeans"],
    )
    base.update(kw)
    return ControlConfig(**base)


def test_evaluate_control_writes_the_nested_metrics_and_figures(tmp_path):
    cfg = _short()
    with SummaryWriter(str(tmp_path)) as writer:
        out = evaluate_control(cfg, GainsConfig(), device="cpu", writer=writer, out_dir=tmp_path)
    metrics, info = out["control"], out["control_info"]
    assert list(metrics) == cfg.controllers
    for name, cases in metrics.items():
        assert set(cases) == {"0kg", "10kg"}
        for m in cases.values():
            assert set(m) == KEYS and all(len(v) == 3 for v in m.values())
            assert all(torch.isfinite(torch.tensor(v)).all() for v in m.values())
        assert (tmp_path / f"control_{name}.png").stat().st_size > 10_000
    assert set(info["select_seconds"]) == {"arbfn_aco", "arbfn_kmeans"}
    json.dumps(out)
    # The unknown payload hurts the controller without an observer far more than with one.
    assert metrics["smc"]["10kg"]["rms_err"][2] > 10 * metrics["smc_obs"]["10kg"]["rms_err"][2]
    # TensorBoard: the table as one text entry, the tracking error as curves (a point a 50 ms
    # window, its peak), the figures under figures/; no final number as a chart of one point.
    events = EventAccumulator(str(tmp_path), size_guidance={"scalars": 0, "images": 0, "tensors": 0}).Reload()
    scalars = events.Tags()["scalars"]
    curves = {f"control/tracking_error/{n}/{c}" for n in cfg.controllers for c in ("0kg", "10kg")}
    assert set(scalars) == curves | {"control/tuning/arbfn_aco/cost"}  # and the tuning's cost per iteration
    curve = events.Scalars("control/tracking_error/smc/10kg")
    assert [p.step for p in curve] == [50 * (i + 1) for i in range(round(cfg.duration / 0.05))]
    assert max(p.value for p in curve) >= max(metrics["smc"]["10kg"]["max_err"]) * (1 - 1e-6)  # peaks kept (float32)
    assert "control/summary/text_summary" in events.Tags()["tensors"]
    assert {f"figures/control_{n}" for n in cfg.controllers} <= set(events.Tags()["images"])


def test_adaptive_network_learns_and_beats_smc_at_equal_gains():
    cfg = _short(controllers=["smc", "arbfn_kmeans"], network=NetworkConfig(num_centers=8))
    res = compare_controllers(cfg, GainsConfig())
    for case in ("0kg", "10kg"):
        smc, net = res.runs["smc"].metrics[case]["rms_err"], res.runs["arbfn_kmeans"].metrics[case]["rms_err"]
        assert all(n <= 0.25 * s for n, s in zip(net, smc)), (case, net, smc)


def test_the_two_phase_law_beats_the_observer_at_an_unknown_payload():
    """Phase 1 at three payloads, then the law that estimates the payload online, against smc_obs
    at the same gains in the realistic loop's gain set (per-joint rates for the rated payload)."""
    net = NetworkConfig(num_centers=12, law=NetworkLaw.two_phase, objective=NetworkObjective.fit, conditions=3)
    cfg = _short(controllers=["smc_obs", "arbfn_kmeans"], network=net, duration=2.0, payload_on=0.5, payload_off=1.5)
    res = compare_controllers(cfg, GainsConfig(inertia_scaling=True))
    basis = res.runs["arbfn_kmeans"].basis
    assert basis is not None and basis.w0.shape == (12, 3) and float(basis.fit_error.max()) < 0.1
    assert res.runs["smc_obs"].basis is None
    obs, law = res.runs["smc_obs"].metrics["10kg"]["rms_err"], res.runs["arbfn_kmeans"].metrics["10kg"]["rms_err"]
    assert all(a < o for a, o in zip(law, obs)), (law, obs)


def test_cmaes_chooses_the_two_phase_basis_on_phase_ones_fit_as_the_colony_does():
    """Under the two-phase law CMA-ES searches phase 1's fit from k-means' centres at the colony's
    budget: its own centres, its basis fitted as the others' are, and a stable run."""
    net = NetworkConfig(num_centers=8, law=NetworkLaw.two_phase, objective=NetworkObjective.fit, conditions=3)
    net.aco = ACOConfig(iterations=4, ants=6, acor=ACORConfig(archive_size=6))
    cfg = _short(controllers=["smc", "arbfn_kmeans", "arbfn_cmaes"], network=net, payloads=[10.0])
    res = compare_controllers(cfg, GainsConfig(inertia_scaling=True))
    km, cm = res.runs["arbfn_kmeans"], res.runs["arbfn_cmaes"]
    assert km.basis is not None and cm.basis is not None and cm.basis.w0.shape == (8, 3)
    assert not torch.equal(km.basis.w0, cm.basis.w0)  # another basis, fitted the same way
    assert bool(cm.basis.fit_error.isfinite().all()) and cm.select_seconds is not None
    assert all(math.isfinite(e) for e in cm.metrics["10kg"]["rms_err"])


def test_the_closed_loop_chooses_the_joints_the_network_feeds_forward_on(tmp_path):
    """control.network.feedforward: chosen runs the law with and without the network's torque on
    the tuning's scenarios and keeps it per joint where it tracks better; on and off keep it on
    every joint or none, and off leaves the law as the one without it."""
    tune = TuneConfig(scenarios=2, duration=1.0)
    net = NetworkConfig(
        num_centers=8, law=NetworkLaw.two_phase, objective=NetworkObjective.fit, conditions=3, tune=tune
    )
    loop = LoopConfig(  # the SCARA's realistic loop: 500 Hz, one period of delay, noise, a 50 Hz velocity filter
        name="realistic", control_rate=500.0, actuation_delay=1, position_noise=1e-5, velocity_cutoff=50.0
    )
    cfg = _short(controllers=["smc_obs", "arbfn_kmeans"], network=net, duration=2.0, payload_on=0.5, payload_off=1.5)
    gains = GainsConfig(observer_gain=25.0, gamma=200.0, dead_zone=0.012, inertia_scaling=True, phase_margin=30.0)
    runs = {}
    for mode in Feedforward:  # one estimate rate and growth: on and off need no run
        c = replace(
            cfg,
            network=replace(cfg.network, feedforward=mode, estimate_rate_factors=[1.0], feedback_growth_factors=[1.0]),
        )
        with SummaryWriter(str(tmp_path / str(mode))) as writer:
            out = evaluate_control(c, gains, device="cpu", writer=writer, out_dir=tmp_path, loop=loop, parallel=False)
        runs[mode] = out
        info = out["control_info"]["feedforward"]
        joints = info["joints"]["arbfn_kmeans"]
        assert info["mode"] == str(mode) and len(joints) == 3 and set(joints) <= {0.0, 1.0}
        if mode != Feedforward.chosen:
            assert joints == [1.0 if mode == Feedforward.on else 0.0] * 3 and info["seconds"] < 0.1
            assert info["ratio"] == {}  # nothing chosen, no evidence
        errors = out["control_info"]["phase_one"]["joint_error"]["arbfn_kmeans"]
        assert len(errors) == 3 and all(0.0 <= e < 1.0 for e in errors)
    chosen = runs[Feedforward.chosen]["control_info"]["feedforward"]["joints"]["arbfn_kmeans"]
    for j, keep in enumerate(chosen):  # the chosen law's joint tracks as the law it took on that joint
        same = runs[Feedforward.on if keep else Feedforward.off]["control"]["arbfn_kmeans"]["0kg"]["rms_err"][j]
        assert runs[Feedforward.chosen]["control"]["arbfn_kmeans"]["0kg"]["rms_err"][j] == pytest.approx(same, rel=0.2)
    off, on = (runs[m]["control"]["arbfn_kmeans"]["10kg"]["rms_err"] for m in (Feedforward.off, Feedforward.on))
    assert off != on


def _two_phase_realistic(tmp_path, rates, growths):
    """The two-phase law without the network's torque, in the SCARA's realistic loop, with its
    payload estimate's rate and its feedback's growth chosen among gains' times `rates` and
    `growths`: metrics.json's dict."""
    net = NetworkConfig(
        num_centers=8, law=NetworkLaw.two_phase, objective=NetworkObjective.fit, conditions=3,
        tune=TuneConfig(scenarios=2, duration=1.0), feedforward=Feedforward.off,
        estimate_rate_factors=rates, feedback_growth_factors=growths,
    )  # fmt: skip
    loop = LoopConfig(
        name="realistic", control_rate=500.0, actuation_delay=1, position_noise=1e-5, velocity_cutoff=50.0
    )
    cfg = _short(controllers=["smc_obs", "arbfn_kmeans"], network=net, duration=2.0, payload_on=0.5, payload_off=1.5)
    gains = GainsConfig(observer_gain=25.0, gamma=200.0, dead_zone=0.012, inertia_scaling=True, phase_margin=30.0)
    with SummaryWriter(str(tmp_path / f"{rates}-{growths}")) as writer:
        return evaluate_control(cfg, gains, device="cpu", writer=writer, out_dir=tmp_path, loop=loop, parallel=False)


def test_the_closed_loop_chooses_the_estimates_rate_and_the_feedbacks_growth(tmp_path, monkeypatch):
    """control.network.estimate_rate_factors and feedback_growth_factors: the choice runs every rate
    beside smc, then every growth at the chosen rate, keeps the cheapest of each (here the choice's
    runs answer made-up errors, so that the second rate and the second growth win), records them in
    control_info, and the evaluation runs at them: it tracks exactly as the law given those alone."""
    import rbfn.control.comparison as comparison

    calls = []

    def made_up(plant, ctrl, k, scenarios, *args, **kw):
        calls.append(k)
        s, n = scenarios.payloads.shape[0], 3
        err = [1.0, 0.5, 0.3] if len(calls) == 1 else [0.2]  # smc, rate 1 and rate 2; then growth 2
        return torch.tensor(err, dtype=torch.float64)[:, None, None].expand(k, s, n), torch.zeros(k, s, n)

    with monkeypatch.context() as patch:
        patch.setattr(comparison, "run_scenarios", made_up)
        chosen = _two_phase_realistic(tmp_path, [1.0, 0.5], [1.0, 1.2])
    assert calls == [3, 1]
    info = chosen["control_info"]
    assert info["estimate_rate"] == {"factors": [1.0, 0.5], "chosen": {"arbfn_kmeans": pytest.approx(0.025)}}
    assert info["feedback_growth"] == {"factors": [1.0, 1.2], "chosen": {"arbfn_kmeans": pytest.approx(1.8)}}
    alone = _two_phase_realistic(tmp_path, [0.5], [1.2])  # one of each, feedforward off: no run
    assert alone["control_info"]["feedforward"]["seconds"] < 0.1
    assert chosen["control"]["arbfn_kmeans"] == alone["control"]["arbfn_kmeans"]
    default = _two_phase_realistic(tmp_path, [1.0], [1.0])
    assert default["control"]["arbfn_kmeans"]["10kg"]["rms_err"] != alone["control"]["arbfn_kmeans"]["10kg"]["rms_err"]


def _choice_case(scenarios: int, rates: list[float]):
    """A short SCARA evaluation of arbfn_kmeans under the two-phase law whose choice tries the
    estimate `rates` (factors) on `scenarios` tuning scenarios of 1 s, at one growth."""
    net = NetworkConfig(
        num_centers=8, law=NetworkLaw.two_phase, objective=NetworkObjective.fit, conditions=3,
        tune=TuneConfig(scenarios=scenarios, duration=1.0), estimate_rate_factors=rates, feedback_growth_factors=[1.0],
    )  # fmt: skip
    return _short(controllers=["smc_obs", "arbfn_kmeans"], network=net, duration=2.0, payload_on=0.5, payload_off=1.5)


def test_a_candidate_that_diverges_in_the_choice_is_dropped_and_the_rest_run_again(tmp_path, monkeypatch):
    """The choice's first run raises SimulationDiverged in the first law's environments (the
    network's torque on every joint): the rest run again without it, and the law without the
    torque takes every joint."""
    import rbfn.control.comparison as comparison

    real, calls = comparison.run_scenarios, []

    def diverging(plant, ctrl, k, scenarios, *args, **kw):
        calls.append(k)
        if len(calls) == 1:  # smc is block 0: the first law's first environment is the next block's
            raise SimulationDiverged("diverged (a test's)", environment=scenarios.payloads.shape[0])
        return real(plant, ctrl, k, scenarios, *args, **kw)

    monkeypatch.setattr(comparison, "run_scenarios", diverging)
    cfg = _choice_case(scenarios=2, rates=[1.0])
    res = compare_controllers(cfg, GainsConfig(), "cpu")
    assert calls == [3, 2]  # smc and the law with and without the torque; then without the first
    settings = res.runs["arbfn_kmeans"].settings
    assert settings is not None and (settings.estimate_rate, settings.feedback_growth) == (0.05, 1.5)
    assert settings.feedforward.tolist() == [0.0, 0.0, 0.0]


def test_the_choice_feeds_forward_on_each_joint_where_the_torque_helped(monkeypatch):
    """Per joint, the network's torque is kept where the geometric mean over the scenarios of the
    RMS ratio with it to without it is below 1, and that ratio is recorded beside the choice (the
    runs answer made-up errors: with the torque 0.5x on joint 1, 2x on joint 2, and on joint 3
    0.8x in one scenario and 1.5x in the other, 1.1x overall)."""
    import rbfn.control.comparison as comparison

    def made_up(plant, ctrl, k, scenarios, *args, **kw):
        s = scenarios.payloads.shape[0]
        with_it = torch.tensor([[0.5, 2.0, 0.8], [0.5, 2.0, 1.5]], dtype=torch.float64).repeat(s // 2 + 1, 1)[:s]
        rms = torch.stack([torch.ones(s, 3, dtype=torch.float64), with_it, torch.ones(s, 3, dtype=torch.float64)])
        return rms, torch.zeros_like(rms)  # smc, then the law with and without the torque

    monkeypatch.setattr(comparison, "run_scenarios", made_up)
    cfg = _choice_case(scenarios=1, rates=[1.0])
    settings = compare_controllers(cfg, GainsConfig(), "cpu").runs["arbfn_kmeans"].settings
    assert settings is not None and settings.feedforward.tolist() == [1.0, 0.0, 0.0]
    assert settings.feedforward_ratio is not None
    assert settings.feedforward_ratio.tolist() == pytest.approx([0.5, 2.0, math.sqrt(0.8 * 1.5)])


def test_where_every_candidate_diverges_in_the_choice_the_law_keeps_its_defaults(monkeypatch):
    """Each run of the choice diverges in its first law's environments until none is left: the law
    keeps the first rate and growth without the network's torque, and the evaluation runs."""
    import rbfn.control.comparison as comparison

    calls = []

    def diverging(plant, ctrl, k, scenarios, *args, **kw):
        calls.append(k)
        raise SimulationDiverged("diverged (a test's)", environment=scenarios.payloads.shape[0])

    monkeypatch.setattr(comparison, "run_scenarios", diverging)
    cfg = _choice_case(scenarios=2, rates=[1.0, 0.5])
    res = compare_controllers(cfg, GainsConfig(), "cpu")
    assert calls == [5, 4, 3, 2]  # smc and 2 rates x 2 ways, one fewer each time
    settings = res.runs["arbfn_kmeans"].settings
    assert settings is not None and (settings.estimate_rate, settings.feedback_growth) == (0.05, 1.5)
    assert settings.feedforward.tolist() == [0.0, 0.0, 0.0]
    assert all(v > 0 for v in res.runs["arbfn_kmeans"].metrics["10kg"]["rms_err"])


def test_the_choice_takes_the_cheapest_candidate_within_the_saturation_limit():
    """The choice's rule: the least tuning cost among candidates within `saturation_limit`; where
    none is, the least cost among all; the first on a tie."""
    from rbfn.control.comparison import LawSettings, _cheapest, _Tried

    reference = torch.ones(2, 3)

    def cand(err, sat):
        return _Tried(LawSettings(torch.zeros(3), err, 1.0), torch.full((2, 3), err), torch.full((2, 3), sat))

    tune = TuneConfig(saturation_limit=0.01)
    assert _cheapest([cand(0.2, 0.0), cand(0.1, 0.02), cand(0.3, 0.0)], reference, tune).settings.estimate_rate == 0.2
    assert _cheapest([cand(0.2, 0.05), cand(0.1, 0.02)], reference, tune).settings.estimate_rate == 0.1
    assert _cheapest([cand(0.2, 0.0), cand(0.2, 0.0)], reference, tune) is not None
    loose = TuneConfig(saturation_limit=1.0, saturation_penalty=1.0)  # saturation only costs: 3 x 0.3 < 3 x (0.1 + 0.5)
    assert _cheapest([cand(0.3, 0.0), cand(0.1, 0.5)], reference, loose).settings.estimate_rate == 0.3


def test_a_pick_and_place_run_is_a_case_of_every_controller(tmp_path):
    """The payload picked up and put down twice in a run of its own: a case beside the payload
    cases, with its carries in control_info and a figure."""
    net = NetworkConfig(num_centers=8, law=NetworkLaw.two_phase, objective=NetworkObjective.fit, conditions=3)
    pnp = PickAndPlaceConfig(picks=2, duration=2.5, seed=1)
    cfg = _short(controllers=["smc", "smc_exact", "arbfn_kmeans"], network=net, pick_and_place=pnp)
    with SummaryWriter(str(tmp_path)) as writer:
        out = evaluate_control(cfg, GainsConfig(), device="cpu", writer=writer, out_dir=tmp_path)
    metrics, info = out["control"], out["control_info"]["pick_and_place"]
    for cases in metrics.values():
        assert list(cases) == ["0kg", "10kg", "pick_and_place"]
        assert cases["pick_and_place"].keys() == cases["0kg"].keys()
    carries = info["carries"]
    assert info["duration"] == 2.5 and len(carries) == 2 and carries[0]["pick"] == 1.0
    assert all(0 <= c["kg"] <= 20.0 for c in carries) and carries[0]["kg"] != carries[1]["kg"]  # rated: 20 kg
    assert metrics["smc_exact"]["pick_and_place"]["gap_closure"] == [1.0, 1.0, 1.0]
    # the carried masses load the arm: the vertical axis's error follows them under smc
    assert metrics["smc"]["pick_and_place"]["max_err_payload"][2] > 3 * metrics["smc"]["0kg"]["max_err_payload"][2]
    assert (tmp_path / "control_pick_and_place.png").stat().st_size > 10_000
    assert held_out(metrics, "arbfn_kmeans") == held_out(
        {k: {c: m for c, m in v.items() if c != "pick_and_place"} for k, v in metrics.items()}, "arbfn_kmeans"
    )


def test_a_diverging_controller_is_named_with_its_case():
    """All controllers share one batch; the one that diverges is named, with its payload case."""
    cfg = _short(controllers=["smc", "pd"], dt=0.005, duration=1.0, payload_on=0.5, payload_off=0.8, integrator="euler")
    with pytest.raises(SimulationDiverged, match=r"controller pd, payload 0kg: simulation diverged by step"):
        compare_controllers(cfg, GainsConfig(pd_kp=1e6, pd_kd=1e5))


def test_cluster_controller_does_not_change_the_shared_aco_config():
    aco = ACOConfig(iterations=3, ants=4, acor=ACORConfig(archive_size=4))
    cfg = _short(
        controllers=["arbfn_aco_cluster", "arbfn_aco"],
        payloads=[0.0],
        network=NetworkConfig(num_centers=6, aco=aco, objective=NetworkObjective.fit),
    )
    compare_controllers(cfg, GainsConfig())
    assert cfg.network.aco.objective == Objective.fit and aco.objective == Objective.fit


@pytest.mark.parametrize(
    "change,match",
    [
        ({"controllers": ["pd", "lqr"]}, "control.controllers='lqr'"),
        ({"controllers": ["arbfn_magic"]}, "control.controllers='arbfn_magic'"),
        ({"controllers": ["pd", "pd"]}, "each controller may appear once"),
        ({"payloads": [-1.0]}, "control.payloads"),
        ({"payloads": [10.0, 10.0]}, "each payload case may appear once"),
        ({"dt": 0.0}, "control.dt=0.0"),
        ({"payload_off": 5.0}, r"control.payload_on/payload_off=\[0.3, 5.0\]"),
        ({"network": NetworkConfig(num_centers=500)}, "control.network.num_centers=500 .*exceeds the pilot run"),
        ({"compile": True, "aot": True}, "control.aot=True.*choose one of control.compile and control.aot"),
        (
            {"network": NetworkConfig(law=NetworkLaw.two_phase, objective=NetworkObjective.closed_loop)},
            "control.network.objective='closed_loop'.*searches the tracking law's network",
        ),
        ({"network": NetworkConfig(conditions=1)}, "control.network.conditions=1"),
        ({"network": NetworkConfig(estimate_rate_factors=[])}, r"control.network.estimate_rate_factors=\[\]"),
        ({"network": NetworkConfig(estimate_rate_factors=[1.0, 2.0])}, r"estimate_rate_factors=\[1.0, 2.0\].*\(0, 1\]"),
        ({"network": NetworkConfig(feedback_growth_factors=[0.0])}, r"feedback_growth_factors=\[0.0\]"),
        (
            {"network": NetworkConfig(tune=TuneConfig(saturation_limit=2.0))},
            "control.network.tune.saturation_limit=2.0",
        ),
        ({"pick_and_place": PickAndPlaceConfig(picks=-1)}, "control.pick_and_place.picks=-1"),
        ({"pick_and_place": PickAndPlaceConfig(picks=3, duration=1.0)}, "control.pick_and_place.duration=1.0"),
    ],
)
def test_bad_control_config(change, match):
    with pytest.raises(ValueError, match=match):
        _short(**change).check()


@pytest.mark.parametrize(
    "field,value,match",
    [
        ("K", float("nan"), "gains.K=nan.*must be finite"),
        ("Lambda", 0.0, "gains.Lambda=0.0.*must be > 0"),
        ("gamma", -1.0, "gains.gamma=-1.0.*must be >= 0"),
        ("feedback_growth", 0.5, "gains.feedback_growth=0.5.*must be >= 1"),
        ("estimate_rate", 0.0, r"gains.estimate_rate=0.0.*must be in \(0, 1\]"),
        ("estimator_gain", 0.0, "gains.estimator_gain=0.0.*must be > 0"),
    ],
)
def test_bad_gains(field, value, match):
    with pytest.raises(ValueError, match=match):
        replace(GainsConfig(), **{field: value}).check()


def test_bad_choice_fails_at_composition_naming_the_options():
    with pytest.raises(Exception) as e:
        compose_config("evaluate", "gains.robust=tanh")
    message = f"{e.value} {e.value.__cause__}"  # Hydra shows both on the command line
    assert "gains.robust=tanh" in message and "expected one of [sign, sat]" in message


@pytest.mark.parametrize("gains,k", [("paper", 15.0), ("tuned", 50.0)])
def test_gains_group_composes(gains, k):
    cfg = compose_config("evaluate", f"gains={gains}")
    assert cfg.gains.K == k and cfg.gains.Lambda <= 20 and cfg.control.controllers[-2:] == ["arbfn_aco", "arbfn_kmeans"]
    cfg.control.check()
    cfg.gains.check()


def test_control_gains_preset_composes():
    cfg = compose_config("evaluate", "experiment=control_gains", hydra=True)
    assert cfg.hydra.sweeper.params["gains.K"] == "15,30,50" and cfg.ik is False
    assert cfg.loop.name == "ideal" and cfg.gains.observer_gain == 1000.0  # the ideal loop's gains it sweeps
    assert cfg.control.aot == "false"  # every job a new configuration: eager


UR5_TINY = [
    "robot=ur5",
    "ik=false",
    "online.enabled=false",
    "control.duration=0.6",
    "control.dt=0.002",
    "control.payload_on=0.1",
    "control.payload_off=0.4",
    "control.controllers=[smc,arbfn_kmeans]",
    "control.network.num_centers=4",
]


def test_evaluate_ur5_end_to_end(tmp_path):
    """python evaluate.py robot=ur5 (tiny settings): the realistic loop with the UR5's realistic
    gains, payload cases 0, 2.5 and 5 kg, metrics as lists of 6 per joint (the time saturated
    among them), a 6 x 3 figure per controller, TensorBoard events."""
    import evaluate

    cfg = compose_config("evaluate", *UR5_TINY)
    assert cfg.loop.name == "realistic"
    assert cfg.gains == compose_config("evaluate", "robot=ur5", "gains=realistic").gains
    m = evaluate.run(cfg, tmp_path)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert on_disk["control"] == m["control"] and set(on_disk["control"]) == {"smc", "arbfn_kmeans"}
    for cases in on_disk["control"].values():
        assert list(cases) == ["0kg", "2.5kg", "5kg"]
        for c in cases.values():
            assert set(c) == KEYS | {"saturated"} and all(len(v) == 6 for v in c.values())
            assert all(torch.isfinite(torch.tensor(v)).all() for v in c.values())
    assert len(on_disk["control_info"]["gains"]["joint_scale"]) == 6
    for name in ("control_smc.png", "control_arbfn_kmeans.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    assert list(tmp_path.glob("events.out.tfevents.*"))


@pytest.mark.parametrize(
    "override,match",
    [
        ("gains.K=inf", "gains.K=inf is not allowed: must be finite"),
        ("gains.observer_gain=nan", "gains.observer_gain=nan is not allowed: must be finite"),
        ("control.payload_link=ghost", "control.payload_link='ghost': payload link 'ghost' is not a link"),
        ("robot.end_link=nowhere", "robot.end_link='nowhere'.*end_link 'nowhere' is not a link"),
    ],
)
def test_ur5_bad_settings_stop_before_any_work(tmp_path, override, match):
    import evaluate

    with pytest.raises(ValueError, match=match):
        evaluate.run(compose_config("evaluate", *UR5_TINY, override), tmp_path)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("robot", ["scara", "ur5", "panda"])
@pytest.mark.parametrize("gains", ["paper", "tuned"])
def test_each_robot_has_its_paper_and_tuned_gains(robot, gains):
    cfg = compose_config("evaluate", f"robot={robot}", f"gains={gains}")
    cfg.control.check()
    cfg.gains.check()
    paper = compose_config("evaluate", f"robot={robot}", "gains=paper").gains
    assert paper.K == 15.0 and paper.Lambda == 10.0 and str(paper.robust) == "sign"
    assert cfg.gains.Lambda <= 20


def test_a_joint_without_a_torque_limit_is_never_reported_at_one(tmp_path):
    """A URDF joint without an effort limit (none given, or 0) cannot saturate: its `saturated`
    entries are null with the reason under `undefined`, `control_info.torque_limits` holds null for
    it, and the table says "no limit" where no joint has one, never 0 %."""
    import math
    import re

    from rbfn.config import LoopConfig, RobotConfig
    from rbfn.control.robot_setup import control_robot
    from rbfn.studies.control import control_table, torque_limits

    setup = control_robot(RobotConfig(), ControlConfig())
    setup.effort = [math.inf, 100.0, math.inf]
    loop = LoopConfig(name="realistic", torque_limits=True)

    def metrics() -> dict:
        return {"pd": {"0kg": {"rms_err": [1e-3] * 3, "max_err_payload": [1e-3] * 3, "peak_tau": [1.0] * 3,
                               "saturated": [0.0, 0.25, 0.0]}}}  # fmt: skip

    m = metrics()
    limits, undefined = torque_limits(setup, loop, m)
    assert limits == [None, 100.0, None] and m["pd"]["0kg"]["saturated"] == [None, 0.25, None]
    assert undefined["control.pd.0kg.saturated[0]"] == "joint1 has no effort limit in the URDF (none given, or 0)"
    assert set(undefined) == {f"control.pd.0kg.saturated[{j}]" for j in (0, 2)} | {
        f"control_info.torque_limits[{j}]" for j in (0, 2)
    }
    table = control_table(m, setup.units, setup.joint_names)
    assert re.search(r"25\.00%", table) and "no limit on ['joint1', 'joint3']" in table
    setup.effort = [math.inf] * 3  # no limit at all: "no limit", not 0 %
    m = metrics()
    assert torque_limits(setup, loop, m)[0] == [None] * 3
    table = control_table(m, setup.units, setup.joint_names)
    row = table.splitlines()[-2]
    assert row.startswith("pd") and row.endswith("  no limit") and "%" not in row
    setup.effort = [100.0] * 3  # limits in the URDF, but the loop applies none
    m = metrics()
    limits, undefined = torque_limits(setup, replace(loop, torque_limits=False, control_rate=500.0), m)
    assert limits == [None] * 3 and "loop.torque_limits=false" in undefined["control.pd.0kg.saturated[1]"]
    assert torque_limits(setup, LoopConfig(), metrics()) == ([None] * 3, {})  # the ideal loop: no saturation kept
