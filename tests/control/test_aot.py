"""The closed loop's chunk compiled ahead of time and cached on disk."""

import shutil

import pytest
import torch
import torch.utils._pytree as pytree

from rbfn.control import Plant, Scenario, make_controller, paper_trajectory, simulate
from rbfn.control.aot import ENV, ahead_of_time, fingerprint, map_tensors, rebuilder
from rbfn.control.batch import Stacked
from rbfn.control.controllers import Gains, SlidingState
from rbfn.control.models import NominalModel
from rbfn.control.simulator import Loop, Periods, make_chunk, stage_disturbances
from rbfn.robots.scara import ScaraTerms

SCARA_MODEL = NominalModel(ScaraTerms())  # the paper's nominal model of the SCARA


def test_fingerprint_follows_values_not_identity_or_caches():
    a, b = Plant(ScaraTerms()), Plant(ScaraTerms())
    a._joint_values[1] = torch.ones(3)  # a private cache: not part of the value
    assert fingerprint(a, 1e-3) == fingerprint(b, 1e-3)
    assert fingerprint(a, 1e-3) != fingerprint(Plant(ScaraTerms(), viscous=11.0), 1e-3)
    assert fingerprint(a, 1e-3) != fingerprint(a, 2e-3)
    c1 = make_controller("smc_obs", Gains(), 1e-3, model=SCARA_MODEL)
    c2 = make_controller("smc_obs", Gains(K=49.0), 1e-3, model=SCARA_MODEL)
    assert fingerprint(c1) != fingerprint(c2)
    f1 = make_controller("arbfn", Gains(), 1e-3, model=SCARA_MODEL, features=torch.zeros(5, 2))
    f2 = make_controller("arbfn", Gains(), 1e-3, model=SCARA_MODEL, features=torch.ones(5, 2))
    assert fingerprint(f1, skip=("features",)) == fingerprint(f2, skip=("features",))
    assert fingerprint(f1) != fingerprint(f2)
    assert fingerprint(torch.zeros(2)) != fingerprint(torch.zeros(2, dtype=torch.float64))
    both = Stacked([c1, f1], [2, 2])  # slices of its feature columns
    assert fingerprint(both, skip=("features",)) == fingerprint(Stacked([c1, f2], [2, 2]), skip=("features",))
    assert fingerprint(both) != fingerprint(Stacked([c2, f1], [2, 2]))
    with pytest.raises(TypeError, match="cannot fingerprint a"):
        fingerprint(object())


def test_auto_compiles_on_a_cpu_unless_the_environment_says_otherwise(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    monkeypatch.setattr("shutil.which", lambda name: f"/usr/bin/{name}")
    assert ahead_of_time("auto", "cpu") and not ahead_of_time("auto", "cuda")
    assert not ahead_of_time("auto", "cpu", compile=True)  # torch.compile'd instead
    monkeypatch.setattr("shutil.which", lambda name: None)  # no C++ compiler: eager
    assert not ahead_of_time("auto", "cpu") and ahead_of_time("true", "cpu")
    for setting, want in [("true", True), (True, True), ("False", False), (False, False)]:
        assert ahead_of_time(setting, "cuda") is want and ahead_of_time(setting, "cpu") is want
    monkeypatch.setenv(ENV, "0")
    assert not ahead_of_time("auto", "cpu") and ahead_of_time("true", "cpu")
    monkeypatch.setenv(ENV, "1")
    assert ahead_of_time("auto", "cuda") and not ahead_of_time("false", "cpu")
    monkeypatch.setenv(ENV, "maybe")
    with pytest.raises(ValueError, match=r"\$ACO_RBFN_AOT is 'maybe': choose 0 or 1"):
        ahead_of_time("auto", "cpu")


def test_a_package_output_is_rebuilt_without_pytree_for_the_loops_own_types(monkeypatch):
    """The package's flat outputs become the loop's named state again: NamedTuples, tuples, lists
    and None directly (pytree's own unflatten costs as much as a short package call), anything
    else through pytree."""
    t = [torch.full((2,), float(i)) for i in range(6)]
    tree = (Loop(t[0], t[1], [SlidingState(t[2], None, t[3]), None]), [t[4]], t[5])
    flat: list[torch.Tensor] = []
    map_tensors(flat.append, tree)
    leaves, spec = pytree.tree_flatten(tree)
    assert [id(x) for x in flat] == [id(x) for x in leaves if x is not None]  # its inputs: the tensors
    rebuild = rebuilder(pytree.treespec_loads(pytree.treespec_dumps(spec)))  # as a package stores it
    monkeypatch.setattr(pytree.TreeSpec, "unflatten", lambda *a: pytest.fail("pytree's unflatten was used"))
    out = rebuild(iter(leaves))  # the package's outputs: a tensor or None per leaf
    assert type(out[0]) is Loop and type(out[0].controller[0]) is SlidingState and out[0].controller[1] is None
    assert all(a is b for a, b in zip(pytree.tree_leaves(out), pytree.tree_leaves(tree)))
    monkeypatch.undo()
    other = {"a": t[0], "b": (t[1],)}  # a dict: pytree's
    assert rebuilder(pytree.tree_flatten(other)[1])(iter([t[0], t[1]])) == other


def test_chunk_data_flatten_to_tensors_and_their_spec_serialises():
    """The chunk's named inputs and outputs are pytrees of tensors (what torch.compile and
    torch.export take) whose structure an AOT package's call spec can store and read back."""
    sc = Scenario(duration=0.01, payload_on=0.0, payload_off=0.005, metrics_after=0.0)
    ref = paper_trajectory(sc.times())
    plant, feats = Plant(ScaraTerms()), torch.rand(sc.steps + 1, 4, dtype=torch.float64)
    ctrl = Stacked(
        [
            make_controller("smc_obs", Gains(), sc.dt, model=SCARA_MODEL),
            make_controller("arbfn", Gains(), sc.dt, model=SCARA_MODEL, features=feats),
        ],
        [1, 1],
    )
    q, qd = ref.q_d[:2].clone(), ref.qd_d[:2].clone()
    n = sc.steps
    periods = Periods(
        ref=ref,
        h=feats,
        alpha=ctrl.alphas(sc.times()[:n]),
        dist=stage_disturbances(plant, n, sc.dt, dtype=torch.float64),
        load=plant.load(torch.zeros(n, 2, dtype=torch.float64)),
    )
    out = make_chunk(plant, ctrl, sc.dt, "rk4", n)(Loop(q, qd, ctrl.init_state(q, qd)), periods)
    for tree in ((Loop(q, qd, ctrl.init_state(q, qd)), periods), out):
        leaves, spec = pytree.tree_flatten(tree)
        assert all(isinstance(x, torch.Tensor) or x is None for x in leaves)
        assert pytree.treespec_loads(pytree.treespec_dumps(spec)) == spec
    (state,) = out.loop.controller  # one batched sliding-mode unit
    assert isinstance(state, SlidingState) and state.w is not None and state.w.shape == (2, 4, 3)


@pytest.mark.slow
def test_aot_run_equals_eager_and_is_built_once(tmp_path, monkeypatch, caplog):
    """evaluate.py's loop (the SCARA's realistic one, smc_obs) compiled ahead of time: its chunks
    run through the package's flat interface and a shorter last one eagerly, equal to the eager
    run; a package is built once and serves other values. One environment (its package keeps its
    temporaries on the stack), then two, built after it in the same process (on the heap:
    Inductor's choice of wrapper must not carry over)."""
    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("AOTInductor's CPU backend needs a C++ compiler")
    from bench.realistic_loop import setup

    monkeypatch.setenv("ACO_RBFN_CACHE", str(tmp_path))
    with caplog.at_level("INFO", logger="rbfn.control.simulator"):
        for b in (1, 2):
            args = setup("scara", b, 0.05)  # 25 periods: 12 chunks of 2, then 1
            eager = simulate(**args)
            aot = simulate(**args, aot=True)
            assert torch.allclose(aot.q, eager.q, rtol=0, atol=1e-12)
            assert torch.allclose(aot.tau, eager.tau, rtol=0, atol=1e-8)
            assert torch.equal(aot.saturated, eager.saturated)
            if b == 1:
                (pkg,) = (tmp_path / "aot").glob("chunk-*.pt2")
                built = pkg.stat().st_mtime_ns
                again = simulate(**{**args, "q0": args["q0"] + 1e-3}, aot=True)  # other values
                assert pkg.stat().st_mtime_ns == built and not torch.equal(again.q, aot.q)
    assert sum("compiling the closed-loop step" in r.message for r in caplog.records) == 2
    assert len(list((tmp_path / "aot").glob("chunk-*.pt2"))) == 2
