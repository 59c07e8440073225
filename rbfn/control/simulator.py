"""The closed-loop simulator: a "real" robot (`rbfn.control.plants.Plant`: an arm's dynamics with
friction, disturbance and payload) driven by a controller along a desired
trajectory, B environments at once, n joints.

A scenario is a time grid, an integrator (RK4, or semi-implicit Euler) and when the payload is
carried (one window, or a pick-and-place sequence of `Carry`s);
`simulate` runs it in chunks of fused periods (optionally torch.compile'd) and stops with the
step, time, environment and state where a run diverges; `control_metrics` scores a rollout.

Why one module of over 500 lines: the ideal and the realistic loop drive one chunk runner
(`run_chunks`) with one scenario, record and divergence check, and their named state is
registered together for the ahead-of-time packages; the realistic loop's own parts follow the
ideal loop's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple, overload

import torch
import torch.utils._pytree as pytree  # no public pytree module in torch 2.13 (see rbfn.control.aot)

from ..config import Integrator
from ..robots.arm_terms import PointMass
from ..robots.scara.closed_form import ScaraLoad
from .aot import Package, aot_chunk, chunk_key, map_tensors, rebuilder, same_kind, serializable
from .controllers import Controller, Forces, SlidingState, TwoPhaseState
from .loop import Actuation, Applied, RealLoop, Sensing, filtered_velocity, quantise, saturate
from .plants import Plant
from .trajectory import Reference

__all__ = [
    "Plant",
    "Reference",
    "Scenario",
    "Carry",
    "pick_and_place",
    "Rollout",
    "SimulationDiverged",
    "Loop",
    "Periods",
    "Recorded",
    "simulate",
    "control_metrics",
    "metric_tensors",
    "make_chunk",
    "stage_disturbances",
    "payload_schedule",
    "CHECK_EVERY",
]

log = logging.getLogger(__name__)
CHECK_EVERY = 100  # steps between finiteness checks (each check synchronises a GPU)
NOISE_BLOCK = 100  # the realistic loop's noise is drawn this many control periods at a time


class SimulationDiverged(RuntimeError):
    """A state or torque became non-finite; the message names the step, time and state, and
    `environment` is the index of the first environment that diverged."""

    def __init__(self, message: str, environment: int = 0) -> None:
        super().__init__(message)
        self.environment = environment


class Carry(NamedTuple):
    """The payload carried from `on` to `off` (s), `share` of the environment's payload mass (>= 0):
    a pick at `on`, a place at `off`."""

    on: float
    off: float
    share: float


@dataclass
class Scenario:
    """Time grid, integrator and payload schedule; times in s, masses in kg. The payload is carried
    in [payload_on, payload_off), or, where `carries` are given, in each of them instead."""

    duration: float = 10.0
    dt: float = 1e-3
    integrator: str = "rk4"  # rk4 | euler (semi-implicit)
    payload_on: float = 1.0
    payload_off: float = 4.0
    metrics_after: float = 0.5  # errors are measured for t > metrics_after
    carries: tuple[Carry, ...] = ()

    def validate(self) -> None:
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt={self.dt} must be a positive finite number of seconds")
        if not (math.isfinite(self.duration) and self.duration >= self.dt):
            raise ValueError(f"duration={self.duration} must be finite and >= dt={self.dt}")
        if self.integrator not in tuple(Integrator):
            raise ValueError(
                f"integrator={self.integrator!r} is not allowed; choose one of {[str(i) for i in Integrator]}"
            )
        if not 0 <= self.payload_on < self.payload_off <= self.duration:
            raise ValueError(
                f"payload window [{self.payload_on}, {self.payload_off}] s must satisfy "
                f"0 <= payload_on < payload_off <= duration={self.duration}"
            )
        if not 0 <= self.metrics_after < self.duration:
            raise ValueError(f"metrics_after={self.metrics_after} must be in [0, duration={self.duration})")
        last = 0.0
        for c in self.carries:
            if not (last <= c.on < c.off <= self.duration and math.isfinite(c.share) and c.share >= 0):
                raise ValueError(
                    f"carries: {c} needs {last:g} <= on < off <= duration={self.duration} (in order, not "
                    "overlapping) and a finite share >= 0"
                )
            last = c.off

    @property
    def windows(self) -> tuple[Carry, ...]:
        """When the payload is carried: the carries, else the one window at the full payload."""
        return self.carries or (Carry(self.payload_on, self.payload_off, 1.0),)

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.dt))

    def times(self, dtype=torch.float64, device="cpu") -> torch.Tensor:
        """Control instants t_k = k dt, k = 0 .. steps (steps + 1,)."""
        return torch.arange(self.steps + 1, dtype=dtype, device=device) * self.dt


@dataclass
class Rollout:
    """Recorded run: t (T,), q, qd, tau (T, B, n) with T = steps + 1 (tau[-1] repeats tau[-2]); in
    the realistic loop one row per control period, and `saturated` (B, n) the fraction of periods
    each joint's torque was saturated (None in the ideal loop)."""

    t: torch.Tensor
    q: torch.Tensor
    qd: torch.Tensor
    tau: torch.Tensor
    saturated: torch.Tensor | None = None


def _check(step: int, t: float, q, qd, tau) -> None:
    bad = ~(torch.isfinite(q).all(-1) & torch.isfinite(qd).all(-1) & torch.isfinite(tau).all(-1))
    if bool(bad.any()):
        b = int(bad.nonzero()[0, 0])
        raise SimulationDiverged(
            f"simulation diverged by step {step} (t = {t:.4f} s) in environment {b}: "
            f"q = {q[b].tolist()}, qd = {qd[b].tolist()}, tau = {tau[b].tolist()}",
            b,
        )


def stage_disturbances(plant: Plant, n: int, dt: float, **kw) -> torch.Tensor:
    """Disturbance torque at the start, middle and end of each of n periods, for RK4: (n, 3), or
    (n, 3, joints) when the amplitude differs per joint."""
    d = plant.disturbance(torch.arange(2 * n + 1, **kw) * (0.5 * dt))
    return torch.stack([d[0:-1:2], d[1::2], d[2::2]], 1)


def payload_schedule(scenario: Scenario, steps: int, payload: torch.Tensor, **kw) -> torch.Tensor:
    """The payload at each of `steps` integration steps (steps, B) kg: the payload (B,) times the
    carried share inside the scenario's windows, none outside; dtype and device from kw."""
    k = torch.arange(steps, device=kw.get("device"))
    dt = scenario.dt
    share = torch.zeros(steps, **kw)
    for c in scenario.windows:
        share = torch.where((k >= round(c.on / dt)) & (k < round(c.off / dt)), c.share, share)
    return share[:, None] * payload.to(**kw)[None, :]


def pick_and_place(duration: float, picks: int, seed: int, start: float = 1.0) -> tuple[Carry, ...]:
    """`picks` carries over [start, duration] s: the cycles split it evenly, each carrying for its
    first 60 % and empty for the rest; the shares are drawn uniformly in [0, 1] (times the
    environment's payload: masses between none and all of it) by a generator seeded `seed`."""
    if picks < 1 or not (0 <= start < duration):
        raise ValueError(f"pick_and_place: picks={picks} must be >= 1 and start={start} in [0, duration={duration})")
    cycle = (duration - start) / picks
    shares = torch.rand(picks, generator=torch.Generator().manual_seed(seed), dtype=torch.float64).tolist()
    return tuple(Carry(start + i * cycle, start + (i + 0.6) * cycle, s) for i, s in enumerate(shares))


class Loop(NamedTuple):
    """The closed loop's state: joints q and velocities qd (B, n) (rad or m, per s) and the
    controller's state."""

    q: torch.Tensor
    qd: torch.Tensor
    controller: Any


class Periods(NamedTuple):
    """The inputs of consecutive control periods, stacked over the periods (first dimension m):
    the reference (each (m, n), or per environment (m, B, n)), the features h (m, M) or None,
    the adaptation steps alpha (m,) (a Stacked controller's: (m, K)), the disturbance torque at
    each period's start, middle and end dist (m, 3) or (m, 3, n) (`stage_disturbances`), and the
    payload's load (`Plant.load` of `payload_schedule`, each (m, B))."""

    ref: Reference
    h: torch.Tensor | None
    alpha: torch.Tensor
    dist: torch.Tensor
    load: tuple[torch.Tensor, ...]


class Recorded(NamedTuple):
    """What a chunk of m periods returns: the loop after them (a `Loop`, or in the realistic loop a
    `RealState`), and per period the joints q and velocities qd at its start and the torque tau
    applied during it (m, B, n)."""

    loop: Any
    q: torch.Tensor
    qd: torch.Tensor
    tau: torch.Tensor


def _forces(controller: Controller, load: tuple, dist: torch.Tensor) -> Forces | None:
    """What the perfect-knowledge ceiling is told this step (`Controller.needs_forces`): the
    payload's load (each (B,)) and the disturbance at the step's start (dist[0] of the step's (3,)
    or (3, n)); None for every other controller."""
    return Forces(load, dist[0]) if controller.needs_forces else None


def make_chunk(
    plant: Plant, controller: Controller, dt: float, integrator: str, n: int
) -> Callable[[Loop, Periods], Recorded]:
    """`n` closed-loop periods as one pure tensor function (what torch.compile fuses):
    run(loop, periods) -> Recorded, `periods` holding n periods' inputs."""

    def run(loop: Loop, periods: Periods) -> Recorded:
        q, qd, state = loop
        qs, qds, taus = [], [], []
        hs = periods.h.unbind(0) if periods.h is not None else (None,) * n
        rows = zip(
            *(r.unbind(0) for r in periods.ref),
            hs,
            periods.alpha.unbind(0),
            periods.dist.unbind(0),
            *(c.unbind(0) for c in periods.load),
        )
        for q_d, qd_d, qdd_d, h, alpha, dist, *parts in rows:
            qs.append(q)
            qds.append(qd)
            load = same_kind(periods.load, parts)
            forces = _forces(controller, load, dist)
            tau, state = controller.torque(Reference(q_d, qd_d, qdd_d), q, qd, state, h=h, alpha=alpha, forces=forces)
            q, qd = plant.step(q, qd, tau, dist, dt, load, integrator)
            taus.append(tau)
        return Recorded(Loop(q, qd, state), torch.stack(qs), torch.stack(qds), torch.stack(taus))

    return run


@overload
def simulate(
    plant: Plant,
    controller: Controller,
    scenario: Scenario,
    ref: Reference,
    *,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    payload: torch.Tensor,
    record: Literal[True] = ...,
    compile: bool = ...,
    chunk: int = ...,
    aot: bool = ...,
    loop: RealLoop | None = ...,
) -> Rollout: ...
@overload
def simulate(
    plant: Plant,
    controller: Controller,
    scenario: Scenario,
    ref: Reference,
    *,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    payload: torch.Tensor,
    record: Literal[False],
    compile: bool = ...,
    chunk: int = ...,
    aot: bool = ...,
    loop: RealLoop | None = ...,
) -> tuple[torch.Tensor, torch.Tensor]: ...
@overload
def simulate(
    plant: Plant,
    controller: Controller,
    scenario: Scenario,
    ref: Reference,
    *,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    payload: torch.Tensor,
    record: bool = ...,
    compile: bool = ...,
    chunk: int = ...,
    aot: bool = ...,
    loop: RealLoop | None = ...,
) -> Rollout | tuple[torch.Tensor, torch.Tensor]: ...
def simulate(
    plant: Plant,
    controller: Controller,
    scenario: Scenario,
    ref: Reference,
    *,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    payload: torch.Tensor,
    record: bool = True,
    compile: bool = False,
    chunk: int = 0,
    aot: bool = False,
    loop: RealLoop | None = None,
) -> Rollout | tuple[torch.Tensor, torch.Tensor]:
    """Run the closed loop from (q0, qd0) (B, n) along the Reference `ref` (q_d, qd_d, qdd_d; a
    plain 3-tuple is taken as one), each (steps + 1, n) on the scenario's time grid; payload (B,)
    kg applies inside the window.

    Returns a Rollout, or with record=False only the final (q, qd). `chunk` periods run per call
    (default 100 eager; compiled, the plant's `compile_chunk`: 10 for the SCARA's closed form, 1
    for the URDF recursion, whose step alone is a large graph); `compile` fuses them into one
    torch.compile'd call, which removes most of the per-operation overhead at small B and, for a URDF arm, streams its
    dynamics through registers instead of memory (compiling takes minutes). `aot` runs the same
    chunks compiled ahead of time and cached on disk (`rbfn.control.aot`): minutes the first time
    for a configuration, milliseconds to load after that. Raises SimulationDiverged naming the
    first non-finite step (checked every CHECK_EVERY steps, rounded up to chunks, and at the end).

    `loop` (`rbfn.control.loop.RealLoop`; None: the ideal loop) runs the realistic loop instead:
    the controller acts every `loop.substeps` integration steps on measured state, its torque
    delayed and saturated; the Rollout then holds one row per control period (its `tau` the
    torque applied, its `saturated` the fraction of periods each joint spent saturated).
    """
    ref = _checked(plant, scenario, Reference(*ref), q0, qd0, payload)
    n, dt = scenario.steps, scenario.dt
    if loop is not None:
        return _simulate_real(
            plant,
            controller,
            scenario,
            ref,
            q0=q0,
            qd0=qd0,
            payload=payload,
            loop=loop,
            record=record,
            compile=compile,
            chunk=chunk,
            aot=aot,
        )
    chunk = chunk or (plant.compile_chunk if compile or aot else 100)
    kw: dict[str, Any] = {"dtype": q0.dtype, "device": q0.device}
    periods = Periods(
        ref=ref.to(**kw),  # every period's inputs, sliced per chunk below
        h=controller.features.to(**kw) if controller.features is not None else None,
        alpha=controller.alphas(torch.arange(n, **kw) * dt),
        dist=stage_disturbances(plant, n, dt, **kw),  # (n, 3) or (n, 3, joints)
        load=plant.load(payload_schedule(scenario, n, payload, **kw)),
    )
    run = make_chunk(plant, controller, dt, scenario.integrator, chunk)
    if compile:
        run = torch.compile(run, dynamic=False)
    # Environments last in memory ((B, n) views of (n, B) storage), the layout the plant's and
    # models' joint vectors have: elementwise results keep it, each joint's component is a
    # contiguous row, and compiled loops vectorise over environments.
    q, qd = q0.T.contiguous().T, qd0.T.contiguous().T
    state = Loop(q, qd, controller.init_state(q, qd))
    if aot and n >= chunk:
        example = (state, _rows(periods, slice(0, chunk)))
        key = chunk_key(plant, controller, dt, scenario.integrator, chunk, example)
        run = aot_chunk(run, key, example, q.shape[0], log.info)
    inputs: list[torch.Tensor] = []
    map_tensors(inputs.append, periods)
    state, rec = run_chunks(
        run,
        lambda m: make_chunk(plant, controller, dt, scenario.integrator, m),
        state,
        lambda sl: _rows(periods, sl),
        n=n,
        chunk=chunk,
        record=record,
        every=CHECK_EVERY,
        when=lambda k: (k, k * dt),
        flat_rows=lambda sl: [x[sl] for x in inputs],
    )
    if rec is None:
        return state.q.clone(), state.qd.clone()
    return Rollout(scenario.times(state.q.dtype, state.q.device), *rec)


def _checked(
    plant: Plant, scenario: Scenario, ref: Reference, q0: torch.Tensor, qd0: torch.Tensor, payload: torch.Tensor
) -> Reference:
    """`simulate`'s inputs checked: the reference long enough, the states' and the reference's
    shapes the plant's, the states finite, the payloads finite and >= 0 kg; returns `ref`."""
    scenario.validate()
    n = scenario.steps
    if ref.q_d.shape[0] < n + 1:
        raise ValueError(f"the reference has {ref.q_d.shape[0]} samples; the scenario needs {n + 1}")
    if q0.dim() != 2 or q0.shape[1] != plant.n or qd0.shape != q0.shape or ref.q_d.shape[-1] != plant.n:
        raise ValueError(
            f"the plant has {plant.n} joints: q0, qd0 must be (B, {plant.n}) and the reference "
            f"(T, {plant.n}); got {tuple(q0.shape)}, {tuple(qd0.shape)}, {tuple(ref.q_d.shape)}"
        )
    if not (torch.isfinite(q0).all() and torch.isfinite(qd0).all()):
        raise ValueError("initial state q0/qd0 must be finite")
    if not bool(torch.isfinite(payload).all()) or bool((payload < 0).any()):
        raise ValueError(f"payload masses must be finite and >= 0 kg, got {payload.tolist()}")
    return ref


def run_chunks(
    run: Callable,
    make: Callable[[int], Callable],
    state: Any,
    rows: Callable[[slice], Any],
    *,
    n: int,
    chunk: int,
    record: bool,
    every: int,
    when: Callable[[int], tuple[int, float]],
    after: Callable[[slice, Any], None] | None = None,
    flat_rows: Callable[[slice], list[torch.Tensor]] | None = None,
) -> tuple[Any, tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None]:
    """Run n periods from `state` in chunks of `chunk` (`run`; a shorter last one `make(m)`), each
    fed `rows(periods' slice)`; check finiteness every `every` periods (0: every chunk) and at the
    end, naming the step and time `when(period)`; then hand the chunk's output to `after(slice,
    output)` where given (the online learner's update). Returns the final state and, with
    `record`, the rows q, qd, tau (n + 1, B, nj) (the last row: the final state, tau repeated).

    `flat_rows(slice)`: the same rows as `rows`, their tensors alone in pytree's leaf order. With
    it, a `Package` runs its full chunks on flat lists of tensors (`_run_flat`), the state's tree
    rebuilt only for the checks and at the end: at B = 1 walking the trees each chunk cost about
    three times the package's own run."""
    q0 = state.q
    if record:
        qs = torch.empty(n + 1, *q0.shape, dtype=q0.dtype, device=q0.device)
        qds, taus = torch.empty_like(qs), torch.empty_like(qs)
    k0, checked = 0, 0
    # No autograd bookkeeping (a fifth of a small batch's step): the records are written in place
    # into ordinary tensors; the final state is copied out of inference mode. The state enters as
    # inference tensors, so that every chunk a compiled step sees is of one kind (no recompiling).
    with torch.inference_mode():
        state = pytree.tree_map_only(torch.Tensor, torch.clone, state)
        if isinstance(run, Package) and flat_rows is not None and after is None and n >= chunk:
            out_rows = (qs, qds, taus) if record else None
            state, k0, checked = _run_flat(run, state, flat_rows, n // chunk * chunk, chunk, out_rows, every, when)
        while k0 < n:
            m = min(chunk, n - k0)
            fn = run if m == chunk else make(m)
            sl = slice(k0, k0 + m)
            out = fn(state, rows(sl))
            # Every chunk sees its state in the first chunk's layout: a compiled chunk may return a
            # tensor in another (the realistic loop's sensing history), and a compiled step guards
            # on strides (dynamic=False: one more compile per configuration otherwise).
            state = map_tensors(_same_layout, out.loop, state)
            if record:
                qs[sl], qds[sl], taus[sl] = out.q, out.qd, out.tau
            k0 += m
            if k0 - checked >= every or k0 == n:
                _check(*when(k0), state.q, state.qd, out.tau[-1])
                checked = k0
            if after is not None:
                after(sl, out)
    if not record:
        return state, None
    qs[n], qds[n], taus[n] = state.q, state.qd, taus[n - 1]
    return state, (qs, qds, taus)


def _run_flat(
    package: Package,
    state: Any,
    flat_rows: Callable[[slice], list[torch.Tensor]],
    n: int,
    chunk: int,
    out_rows: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None,
    every: int,
    when: Callable[[int], tuple[int, float]],
) -> tuple[Any, int, int]:
    """`run_chunks`'s first n periods (a multiple of `chunk`) through `package.flat`: the state's
    tensors stay a flat list from chunk to chunk, each returned in the strides it entered with (the
    leaves to re-stride found at the first chunk). The package takes the tensors alone and returns
    every leaf of its output, None among them. Returns the state, the periods run and the period
    last checked."""
    leaves: list[torch.Tensor] = []
    map_tensors(leaves.append, state)
    loop_spec = package.out_spec.children()[0]  # Recorded(loop, q, qd, tau)
    nl = loop_spec.num_leaves
    rebuild = rebuilder(loop_spec)
    keep: list[int] = []  # the output's state leaves that are tensors
    restride: list[tuple[int, int]] = []  # (output leaf, state tensor) pairs whose strides differ
    checked = 0
    for k0 in range(0, n, chunk):
        sl = slice(k0, k0 + chunk)
        out = package.flat(leaves + flat_rows(sl))
        if k0 == 0:
            keep = [i for i in range(nl) if out[i] is not None]
            if len(keep) != len(leaves):
                raise RuntimeError(f"the package returns {len(keep)} state tensors, the loop holds {len(leaves)}")
            restride = [(i, j) for j, i in enumerate(keep) if out[i].stride() != leaves[j].stride()]
        for i, j in restride:
            out[i] = _same_layout(out[i], leaves[j])
        leaves = [out[i] for i in keep]
        if out_rows is not None:
            out_rows[0][sl], out_rows[1][sl], out_rows[2][sl] = out[nl], out[nl + 1], out[nl + 2]
        if k0 + chunk - checked >= every or k0 + chunk == n:
            state = rebuild(iter(out[:nl]))
            _check(*when(k0 + chunk), state.q, state.qd, out[nl + 2][-1])
            checked = k0 + chunk
    return state, n, checked


def _same_layout(new: torch.Tensor, old: torch.Tensor) -> torch.Tensor:
    """`new` in `old`'s strides (a copy only where they differ)."""
    if new.stride() == old.stride() or new.shape != old.shape:
        return new
    return torch.empty_strided(old.shape, old.stride(), dtype=new.dtype, device=new.device).copy_(new)


def _rows(periods: Any, sl: slice | tuple[int, ...]) -> Any:
    """The periods `sl` of every input, or one period's (one step's) with an index (views)."""
    return map_tensors(lambda x: x[sl], periods)


class RealState(NamedTuple):
    """The realistic loop's state: the plant's q, qd (B, n), the controller's state, the sensors'
    and the actuators'."""

    q: torch.Tensor
    qd: torch.Tensor
    controller: Any
    sensing: Sensing
    actuation: Actuation


class RealPeriods(NamedTuple):
    """The inputs of m consecutive control periods (first dimension m): the reference at each
    period's start, features h (m, M) or None, adaptation steps alpha, the disturbance torque at
    each integration step's start, middle and end dist (m, substeps, 3[, n]), the payload
    load (`Plant.load`, each (m, substeps, B)), and the noise: positions (m, B, n) rad (m) and
    torques (m, B, n) N m (N), or None."""

    ref: Reference
    h: torch.Tensor | None
    alpha: torch.Tensor
    dist: torch.Tensor
    load: tuple[torch.Tensor, ...]
    position_noise: torch.Tensor | None
    torque_noise: torch.Tensor | None


def make_real_chunk(
    plant: Plant, controller: Controller, loop: RealLoop, dt: float, integrator: str, m: int
) -> Callable[[RealState, RealPeriods], Recorded]:
    """`m` periods of the realistic loop as one pure tensor function: sense, control, actuate,
    then `loop.substeps` integration steps of dt with the applied torque held."""

    def run(state: RealState, periods: RealPeriods) -> Recorded:
        q, qd, cstate, sensing, act = state
        limit = None if loop.torque_limit is None else loop.torque_limit.to(q)
        resolution = None if loop.resolution is None else loop.resolution.to(q)
        qs, qds, taus = [], [], []
        for k in range(m):
            qs.append(q)
            qds.append(qd)
            # Sense: the position measured now (noise, then the encoder's count), used
            # sensing_delay periods later; velocity from filtered differences of what is used.
            y = q if periods.position_noise is None else q + periods.position_noise[k]
            if resolution is not None:
                y = quantise(y, resolution)
            history = torch.cat([sensing.history[1:], y[None]])
            q_hat = history[0]
            if loop.velocity_gain is None:
                qd_hat, velocity = qd, sensing.velocity
            else:
                velocity = filtered_velocity(sensing.velocity, q_hat, sensing.previous, loop.period, loop.velocity_gain)
                qd_hat = velocity
            sensing = Sensing(history, q_hat, velocity)
            # Control, told what the last period applied.
            ref = Reference(periods.ref.q_d[k], periods.ref.qd_d[k], periods.ref.qdd_d[k])
            h = None if periods.h is None else periods.h[k]
            forces = _forces(controller, _rows(periods.load, (k, 0)), periods.dist[k, 0])
            cmd, cstate = controller.torque(
                ref, q_hat, qd_hat, cstate, h=h, alpha=periods.alpha[k], applied=act.applied, forces=forces
            )
            share = controller.share(cstate, cmd)
            # Actuate: the command of actuation_delay periods ago, saturated, with noise.
            if loop.actuation_delay:
                commands, shares = torch.cat([act.commands, cmd[None]]), torch.cat([act.shares, share[None]])
                u, u_share, commands, shares = commands[0], shares[0], commands[1:], shares[1:]
            else:
                u, u_share, commands, shares = cmd, share, act.commands, act.shares
            if limit is not None:
                clipped = saturate(u, limit)
                saturated = (clipped != u).to(u)
                u = clipped
            else:
                saturated = torch.zeros_like(u)
            applied = Applied(u - u_share, saturated)
            act = Actuation(commands, shares, applied, act.saturated_periods + saturated)
            if periods.torque_noise is not None:
                u = u + periods.torque_noise[k]
            for j in range(loop.substeps):
                q, qd = plant.step(
                    q,
                    qd,
                    u,
                    periods.dist[k, j],
                    dt,
                    _rows(periods.load, (k, j)),
                    integrator,
                )
            taus.append(u)
        return Recorded(RealState(q, qd, cstate, sensing, act), torch.stack(qs), torch.stack(qds), torch.stack(taus))

    return run


def _simulate_real(
    plant: Plant,
    controller: Controller,
    scenario: Scenario,
    ref: Reference,
    *,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    payload: torch.Tensor,
    loop: RealLoop,
    record: bool,
    compile: bool,
    chunk: int,
    aot: bool = False,
) -> Rollout | tuple[torch.Tensor, torch.Tensor]:
    """`simulate` in the realistic loop (see there)."""
    dt, sub = scenario.dt, loop.substeps
    periods = scenario.steps // sub
    if periods < 1:
        raise ValueError(f"the scenario's {scenario.steps} steps hold no control period of {sub} steps")
    n_steps = periods * sub
    b, nj = q0.shape
    kw: dict[str, Any] = {"dtype": q0.dtype, "device": q0.device}
    load = map_tensors(
        lambda c: c.reshape(periods, sub, b), plant.load(payload_schedule(scenario, n_steps, payload, **kw))
    )
    dist = stage_disturbances(plant, n_steps, dt, **kw)
    dist = dist.reshape(periods, sub, *dist.shape[1:])
    starts = slice(0, n_steps, sub)  # each period's first integration step
    feats = controller.features
    inputs = RealPeriods(
        ref=Reference(*(r[starts].to(**kw) for r in ref)),
        h=None if feats is None else feats[starts].to(**kw),
        alpha=controller.alphas(torch.arange(periods, **kw) * loop.period),
        dist=dist,
        load=load,
        position_noise=None,
        torque_noise=None,
    )
    noise = _Noise(loop, periods, b, nj, kw)
    state = _real_state(controller, loop, q0, qd0)
    # Compiled, a fifth of the ideal loop's chunk: a period here is several integration steps and
    # the sensing and actuation around them.
    chunk = chunk or (max(1, plant.compile_chunk // 5) if compile or aot else 100)
    run = make_real_chunk(plant, controller, loop, dt, scenario.integrator, chunk)
    if compile:
        run = torch.compile(run, dynamic=False)

    def rows(sl: slice) -> RealPeriods:
        pos, tau = noise.rows(sl.start, sl.stop)
        return _rows(inputs, sl)._replace(position_noise=pos, torque_noise=tau)

    noiseless: list[torch.Tensor] = []  # the inputs' tensors; the noise, RealPeriods' last fields, is None here
    map_tensors(noiseless.append, inputs)

    def flat_rows(sl: slice) -> list[torch.Tensor]:
        return [x[sl] for x in noiseless] + [t for t in noise.rows(sl.start, sl.stop) if t is not None]

    if aot and periods >= chunk:
        example = _real_example(inputs, state, loop, chunk)
        key = chunk_key(plant, controller, dt, scenario.integrator, chunk, (loop, example))
        run = aot_chunk(run, key, example, b, log.info)

    state, rec = run_chunks(
        run,
        lambda m: make_real_chunk(plant, controller, loop, dt, scenario.integrator, m),
        state,
        rows,
        n=periods,
        chunk=chunk,
        record=record,
        every=max(1, CHECK_EVERY // sub),  # in periods
        when=lambda k: (k * sub, k * loop.period),
        flat_rows=flat_rows,
    )
    if rec is None:
        return state.q.clone(), state.qd.clone()
    t = torch.arange(periods + 1, dtype=state.q.dtype, device=state.q.device) * loop.period
    return Rollout(t, *rec, saturated=state.actuation.saturated_periods.clone() / periods)


class _Noise:
    """The realistic loop's position and torque noise (`loop.position_noise`, `loop.torque_noise`)
    for `periods` periods of b environments and nj joints: drawn on the CPU (the same numbers on
    every device), every `loop.noise_envs`-th environment alike, in blocks of NOISE_BLOCK periods
    whatever the chunk length (torch's CPU randn takes another algorithm from 16 numbers on, so
    draws per chunk made the run depend on the chunk), and sliced per chunk."""

    def __init__(self, loop: RealLoop, periods: int, b: int, nj: int, kw: dict[str, Any]) -> None:
        self.g = torch.Generator().manual_seed(loop.seed)
        self.envs = loop.noise_envs or b
        if b % self.envs:
            raise ValueError(f"loop.noise_envs={self.envs} must divide the {b} environments")
        self.loop, self.periods, self.b, self.nj, self.kw = loop, periods, b, nj, kw
        self.blocks: dict[int, tuple[torch.Tensor | None, torch.Tensor | None]] = {}

    def _draw(self, rows: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """`rows` periods' noise (rows, b, nj) each, position first."""
        loop, envs, b, nj = self.loop, self.envs, self.b, self.nj
        pos = None
        if loop.position_noise:
            d = torch.randn(rows, envs, nj, generator=self.g, dtype=torch.float64)
            pos = (loop.position_noise * d).repeat(1, b // envs, 1).to(**self.kw)
        tau = None
        if loop.torque_noise is not None:
            d = torch.randn(rows, envs, nj, generator=self.g, dtype=torch.float64)
            tau = (loop.torque_noise * d).repeat(1, b // envs, 1).to(**self.kw)
        return pos, tau

    def rows(self, start: int, stop: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """Periods start .. stop - 1's noise: slices of the blocks, each drawn once, in order."""
        pos: list[torch.Tensor | None] = []
        tau: list[torch.Tensor | None] = []
        for blk in range(start // NOISE_BLOCK, (stop - 1) // NOISE_BLOCK + 1):
            if blk not in self.blocks:
                self.blocks.clear()  # the chunks move forward: the earlier blocks are spent
                self.blocks[blk] = self._draw(min(NOISE_BLOCK, self.periods - blk * NOISE_BLOCK))
            lo, hi = max(start - blk * NOISE_BLOCK, 0), min(stop - blk * NOISE_BLOCK, NOISE_BLOCK)
            p, t = self.blocks[blk]
            pos.append(None if p is None else p[lo:hi])
            tau.append(None if t is None else t[lo:hi])
        return _join(pos), _join(tau)


def _join(parts: list[torch.Tensor | None]) -> torch.Tensor | None:
    return None if parts[0] is None else parts[0] if len(parts) == 1 else torch.cat(parts)  # type: ignore[arg-type]


def _real_state(controller: Controller, loop: RealLoop, q0: torch.Tensor, qd0: torch.Tensor) -> RealState:
    """The realistic loop's state at (q0, qd0) (B, n): at rest in its sensing (every delayed
    reading q0, quantised) and actuation (no torque waiting or applied)."""
    q, qd = q0.T.contiguous().T, qd0.T.contiguous().T
    y0 = q if loop.resolution is None else quantise(q, loop.resolution.to(q))
    z = torch.zeros_like(q)
    wait = torch.zeros(loop.actuation_delay, *q.shape, dtype=q.dtype, device=q.device)
    return RealState(
        q,
        qd,
        controller.init_state(q, qd),
        Sensing(y0[None].repeat(loop.sensing_delay + 1, 1, 1), y0.clone(), qd.clone()),
        Actuation(wait, wait.clone(), Applied(z.clone(), z.clone()), z.clone()),
    )


def _real_example(inputs: RealPeriods, state: RealState, loop: RealLoop, chunk: int) -> tuple:
    """The example a chunk's ahead-of-time package is built for: the state, and the first chunk's
    inputs with zeros for its noise (the generator's stream stays the run's)."""
    like = _rows(inputs, slice(0, chunk))
    q = state.q
    zeros = torch.zeros(chunk, *q.shape, dtype=q.dtype, device=q.device)
    like = like._replace(
        position_noise=zeros if loop.position_noise else None,
        torque_noise=zeros.clone() if loop.torque_noise is not None else None,
    )
    return (pytree.tree_map_only(torch.Tensor, torch.clone, state), like)


# in an AOT package's call spec
serializable(
    Reference,
    Loop,
    Periods,
    Recorded,
    SlidingState,
    TwoPhaseState,
    RealState,
    RealPeriods,
    Sensing,
    Actuation,
    Applied,
    ScaraLoad,
    PointMass,
)


def metric_tensors(
    roll: Rollout,
    q_des: torch.Tensor,
    scenario: Scenario,
    limits: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> dict[str, torch.Tensor]:
    """Each metric as (B, n), per environment and joint: rms_err, max_err (t > metrics_after),
    max_err_payload (while the payload is carried), peak_tau (whole run) and chattering (mean
    |dtau/dt|) (rad or m; N m or N; N m/s or N/s); in the realistic loop also `saturated`, the fraction of control
    periods the joint's torque was at its limit. q_des: the desired joints at the rollout's rows.
    With `limits` (lower, upper) (n,) (the URDF's position limits, rad or m, +-inf where none) also
    `limit_breach`, the fraction of the rollout's rows (whole run) the joint spent beyond a limit,
    and `limit_excess`, its largest distance beyond one (rad or m; 0 where it stayed within)."""
    err = (q_des[:, None, :] - roll.q).abs()  # (T, B, n)
    after = roll.t > scenario.metrics_after
    window = torch.zeros_like(roll.t, dtype=torch.bool)
    for c in scenario.windows:
        window |= (roll.t >= c.on) & (roll.t <= c.off)
    step = scenario.dt if roll.saturated is None else float(roll.t[1] - roll.t[0])  # a row's time, s
    per_key = {  # each (B, n)
        "rms_err": err[after].square().mean(0).sqrt(),
        "max_err": err[after].amax(0),
        "max_err_payload": err[window].amax(0),
        "peak_tau": roll.tau[:-1].abs().amax(0),
        "chattering": (roll.tau[1:-1] - roll.tau[:-2]).abs().mean(0) / step,
    }
    if roll.saturated is not None:
        per_key["saturated"] = roll.saturated
    if limits is not None:
        lower, upper = (v.to(roll.q) for v in limits)
        beyond = torch.maximum(lower - roll.q, roll.q - upper).clamp(min=0.0)  # (T, B, n)
        per_key["limit_breach"] = (beyond > 0).to(roll.q).mean(0)
        per_key["limit_excess"] = beyond.amax(0)
    return per_key


def control_metrics(
    roll: Rollout,
    q_des: torch.Tensor,
    scenario: Scenario,
    limits: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> list[dict]:
    """`metric_tensors` per environment: a dict of lists of n floats each (metrics.json's form)."""
    per_key = metric_tensors(roll, q_des, scenario, limits)
    lists = {k: v.tolist() for k, v in per_key.items()}
    return [{k: v[i] for k, v in lists.items()} for i in range(roll.q.shape[1])]
