"""Controllers batched as one: a batch of two-phase controllers does what each does alone."""

import pytest
import torch

from rbfn.control import Plant, Scenario, make_controller, paper_trajectory, simulate
from rbfn.control.batch import Stacked, TwoPhaseBatch
from rbfn.control.controllers import Gains, InertiaSchedule, NominalModel, TwoPhase
from rbfn.robots.scara import ScaraTerms

KW = {"dtype": torch.float64}
MODEL = NominalModel(ScaraTerms())


def _two_phase(
    gains: Gains, dt: float, feats: torch.Tensor, schedule: InertiaSchedule, feedforward=None, lag: float = 3e-3
) -> TwoPhase:
    ctrl = make_controller(
        "arbfn_x", gains, dt, model=MODEL, features=feats, law="two_phase",
        schedule=schedule, feedforward=feedforward, velocity_lag=lag,
    )  # fmt: skip
    assert isinstance(ctrl, TwoPhase)
    return ctrl


def test_two_phase_controllers_batched_equal_their_separate_runs():
    """Two-phase controllers that differ in their estimate's rate, their feedback's growth, their
    feedforward joints and their features run as one `TwoPhaseBatch` (with smc beside them), and
    each block of the batch is that controller's own run (their velocity lag compensated too)."""
    sc = Scenario(duration=0.3, payload_on=0.05, payload_off=0.25, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    plant = Plant(ScaraTerms())
    pay = torch.tensor([0.0, 15.0], **KW)
    q0, qd0 = ref.q_d[:1].expand(2, 3).clone(), ref.qd_d[:1].expand(2, 3).clone()
    gen = torch.Generator().manual_seed(0)
    schedule = InertiaSchedule(torch.tensor([2.0, 0.5, 20.0], **KW), torch.tensor([0.6, 0.16, 1.0], **KW), 25.0)
    gains = Gains(inertia_scaling=True)
    feats = [torch.randn(sc.steps + 1, 9, generator=gen, **KW) * 5.0 for _ in range(3)]
    parts = [
        make_controller("smc", gains, sc.dt, model=MODEL),
        _two_phase(gains, sc.dt, feats[0], schedule),
        _two_phase(Gains(inertia_scaling=True, estimate_rate=0.005), sc.dt, feats[1], schedule, torch.tensor([1.0, 0, 1]).double()),
        _two_phase(Gains(inertia_scaling=True, feedback_growth=3.0), sc.dt, feats[2], schedule, torch.zeros(3, **KW)),
    ]  # fmt: skip
    stacked = Stacked(parts, [2] * len(parts))
    assert len(stacked.units) == 2 and isinstance(stacked.units[1], TwoPhaseBatch)
    k = len(parts)
    both = simulate(plant, stacked, sc, ref, q0=q0.repeat(k, 1), qd0=qd0.repeat(k, 1), payload=pay.repeat(k))
    runs = [simulate(plant, ctrl, sc, ref, q0=q0, qd0=qd0, payload=pay) for ctrl in parts]
    for i, one in enumerate(runs):
        assert torch.allclose(both.q[:, 2 * i : 2 * i + 2], one.q, rtol=0, atol=1e-12)
        assert torch.allclose(both.tau[:, 2 * i : 2 * i + 2], one.tau, rtol=0, atol=1e-9)
    # the settings matter here, so the batch did not just run one of them
    assert not torch.allclose(runs[1].tau, runs[2].tau, atol=1e-3) and not torch.allclose(
        runs[1].tau, runs[3].tau, atol=1e-3
    )


def test_two_phase_controllers_of_other_gains_or_schedules_are_not_batched():
    dt, gen = 1e-3, torch.Generator().manual_seed(1)
    schedule = InertiaSchedule(torch.ones(3, **KW), torch.ones(3, **KW), 25.0)
    other = InertiaSchedule(torch.ones(3, **KW), torch.ones(3, **KW) * 2, 25.0)
    feats = torch.randn(10, 9, generator=gen, **KW)
    a = _two_phase(Gains(), dt, feats, schedule)
    assert len(Stacked([a, _two_phase(Gains(K=7.0), dt, feats, schedule)], [1, 1]).units) == 2
    assert len(Stacked([a, _two_phase(Gains(), dt, feats, other)], [1, 1]).units) == 2
    assert len(Stacked([a, _two_phase(Gains(), dt, feats, schedule, lag=0.0)], [1, 1]).units) == 2
    assert len(Stacked([a, _two_phase(Gains(estimate_rate=0.01), dt, feats, schedule)], [1, 1]).units) == 1


@pytest.mark.slow
def test_a_compiled_two_phase_batch_takes_its_settings_as_inputs(tmp_path, monkeypatch, caplog):
    """The settings ride in the state, so one package serves candidates of the same shapes, and
    each run of it equals its own eager run (the settings are not baked into the package)."""
    import shutil

    from rbfn.control.aot import fingerprint

    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("AOTInductor's CPU backend needs a C++ compiler")
    monkeypatch.setenv("ACO_RBFN_CACHE", str(tmp_path))
    sc = Scenario(duration=0.02, payload_on=0.005, payload_off=0.015, integrator="euler", metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    plant = Plant(ScaraTerms())
    pay = torch.tensor([0.0, 15.0], **KW).repeat(2)
    q0, qd0 = ref.q_d[:1].expand(4, 3).clone(), ref.qd_d[:1].expand(4, 3).clone()
    schedule = InertiaSchedule(torch.tensor([2.0, 0.5, 20.0], **KW), torch.tensor([0.6, 0.16, 1.0], **KW), 25.0)
    feats = torch.randn(sc.steps + 1, 9, generator=torch.Generator().manual_seed(2), **KW) * 5.0

    def batch(rate: float, growth: float, ff: list[float], k: float = 10.0) -> Stacked:
        other = Gains(inertia_scaling=True, estimate_rate=rate, feedback_growth=growth, K=k)
        first = _two_phase(Gains(inertia_scaling=True, K=k), sc.dt, feats, schedule)
        return Stacked([first, _two_phase(other, sc.dt, feats * 0.5, schedule, torch.tensor(ff, **KW))], [2, 2])

    a, b = batch(0.005, 3.0, [1.0, 0.0, 1.0]), batch(0.2, 1.2, [0.0, 1.0, 0.0])
    assert len(a.units) == 1
    key = lambda c: fingerprint(c, skip=("features",))  # noqa: E731  (chunk_key's view of a controller)
    assert key(a) == key(b) and key(a) != key(batch(0.005, 3.0, [1.0, 0.0, 1.0], k=12.0))
    with caplog.at_level("INFO", logger="rbfn.control.simulator"):
        runs = [simulate(plant, c, sc, ref, q0=q0, qd0=qd0, payload=pay, chunk=4, aot=True) for c in (a, b)]
    assert sum("compiling the closed-loop step" in r.message for r in caplog.records) == 1
    for c, run in zip((a, b), runs):
        eager = simulate(plant, c, sc, ref, q0=q0, qd0=qd0, payload=pay, chunk=4)
        assert torch.allclose(run.tau, eager.tau, rtol=0, atol=1e-8)
    assert not torch.allclose(runs[0].tau[:, 2:], runs[1].tau[:, 2:], atol=1e-6)
