"""Several controllers as one batch, so that one simulation runs them all (the closed-loop
comparison: B = controllers x payload cases).

`Stacked` splits the environments into blocks, one per controller; consecutive sliding-mode
controllers that share gains, time step, model and joint scale run as one `SlidingModeBatch`,
which evaluates the model once for all their environments, and consecutive two-phase controllers
that differ only in their settings and features as one `TwoPhaseBatch`. The laws themselves
(`rbfn.control.controllers`) know nothing of batching: a batch hands the sliding-mode law each
environment's own features (B, M) and observer gain (B, 1), the two-phase law each environment's
features (B, 3n) and settings.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from typing import cast

import torch

from .aot import same_kind
from .controllers import Controller, Forces, Reference, SlidingMode, SlidingState, TwoPhase, TwoPhaseState
from .loop import Applied

__all__ = ["Stacked", "SlidingModeBatch", "TwoPhaseBatch"]


class SlidingModeBatch(SlidingMode):
    """Sliding-mode controllers that share gains, time step, model and joint scale as one
    controller of sum(sizes) environments (part i drives the i-th block of sizes[i]). Its features
    are the parts' side by side (T, sum M_i); an environment adds d_hat only if its part has the
    observer (its observer gain is 0 otherwise), and W^T h over its own part's feature columns
    only (its W is zero elsewhere and stays so)."""

    def __init__(self, parts: list[SlidingMode], sizes: list[int]) -> None:
        first = parts[0]
        feats = [p.features for p in parts if p.features is not None]
        super().__init__(
            first.gains,
            first.dt,
            first.model,
            observer=any(p.observer for p in parts),
            features=torch.cat(feats, -1) if feats else None,
            joint_scale=first.scale,
            rates=first.rates,
        )
        self.members = list(zip(parts, sizes))
        # Public, so a compiled chunk's cache key (which leaves features out) sees the column split.
        self.member_columns = [0 if p.features is None else p.features.shape[1] for p in parts]
        # Per environment, set by init_state: observer gain (B, 1), or (B, n) with per-joint rates
        # (None: every part has the observer), and mask of its own feature columns (B, M) (None:
        # no features).
        self._gain: torch.Tensor | None = None
        self._own: torch.Tensor | None = None

    def _blocks(self) -> Iterator[tuple[SlidingMode, slice, slice]]:
        """(part, its environments' rows, its feature columns)."""
        r = c = 0
        for (part, size), k in zip(self.members, self.member_columns):
            yield part, slice(r, r + size), slice(c, c + k)
            r, c = r + size, c + k

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> SlidingState:
        b = q0.shape[0]
        observed = None if all(p.observer for p, _ in self.members) else torch.zeros(b, 1)
        own = None if self.features is None else torch.zeros(b, self.features.shape[1])
        for part, rows, cols in self._blocks():
            if observed is not None:
                observed[rows] = float(part.observer)
            if own is not None:
                own[rows, cols] = 1.0
        gain = super().observer_gain()
        self._gain = (
            None if observed is None else observed.to(q0) * (gain.to(q0) if isinstance(gain, torch.Tensor) else gain)
        )
        self._own = None if own is None else own.to(q0)
        state = super().init_state(q0, qd0)  # w: zeros, the batch having no w0
        for part, rows, cols in self._blocks():
            if state.w is not None and part.w0 is not None:
                state.w[rows, cols] = part.w0.to(state.w)  # each block's own columns hold its w0
        return state

    def observer_gain(self) -> float | torch.Tensor:
        return super().observer_gain() if self._gain is None else self._gain

    def torque(
        self,
        ref: Reference,
        q: torch.Tensor,
        qd: torch.Tensor,
        state: SlidingState,
        *,
        h: torch.Tensor | None = None,
        alpha: torch.Tensor | None = None,
        applied: Applied | None = None,
        forces: Forces | None = None,
    ) -> tuple[torch.Tensor, SlidingState]:
        own = None if h is None or self._own is None else h * self._own  # (B, M): each environment's own
        return super().torque(ref, q, qd, state, h=own, alpha=alpha, applied=applied)


class TwoPhaseBatch(TwoPhase):
    """Two-phase controllers that share gains (but the estimate's rate and the feedback's growth),
    time step, model, inertia schedule and joint scale as one controller of sum(sizes) environments
    (part i drives the i-th block of sizes[i]), each environment with its part's settings
    (`TwoPhase.settings`, carried in its state: `TwoPhaseState.settings`) and features: the parts'
    (T, 3n) side by side (T, 3n parts), of which an environment reads its own part's columns. The
    choice of the law's settings (`rbfn.control.comparison`) runs its candidates this way: one
    graph for all of them, and, compiled, one package for any candidates of the same count."""

    def __init__(self, parts: list[TwoPhase], sizes: list[int]) -> None:
        first = parts[0]
        super().__init__(
            _settled(first),
            first.dt,
            first.model,
            torch.cat([p.features for p in parts], -1),
            first.schedule,
            joint_scale=first.scale,
            velocity_lag=first.velocity_lag,
        )
        width, n = first.features.shape[-1], first.schedule.base.shape[-1]
        part = torch.arange(len(parts)).repeat_interleave(torch.tensor(sizes))  # (B,) each environment's part
        self.columns = part[:, None] * width + torch.arange(width)  # (B, 3n) its features' columns
        self._columns: dict[torch.device, torch.Tensor] = {}  # `columns` on each device a run used
        rate, cap, ff = zip(*(p.settings() for p in parts))
        ones = torch.ones(n, dtype=torch.float64)
        # Private: the state carries them (`init_state`), so a compiled package's key leaves them out
        # and one package serves any candidates of the same shapes.
        self._settings = (
            torch.tensor(rate, dtype=torch.float64)[part],  # (B,)
            torch.tensor(cap, dtype=torch.float64)[part, None],  # (B, 1)
            torch.stack([ones if f is None else f.to(ones) for f in ff])[part],  # (B, n)
        )

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> TwoPhaseState:
        rate, cap, ff = (t.to(q0) for t in self._settings)
        return super().init_state(q0, qd0)._replace(settings=(rate, cap, ff))

    def torque(self, ref: Reference, q: torch.Tensor, qd: torch.Tensor, state: TwoPhaseState, *, h=None, **kw):
        """`TwoPhase.torque`, each environment given its own part's columns of h (3n parts,)."""
        assert h is not None
        cols = self._columns.get(h.device)
        if cols is None:  # once a device, not once a period
            cols = self._columns[h.device] = self.columns.to(h.device)
        return super().torque(ref, q, qd, state, h=h[cols], **kw)


class Stacked(Controller):
    """Several controllers as one batch: controller i drives the i-th block of `sizes[i]`
    environments. Consecutive sliding-mode controllers that share gains, time step, model and
    joint scale run as one `SlidingModeBatch`, consecutive two-phase ones that differ only in
    their settings and features as one `TwoPhaseBatch`. Its features are the units' side by side
    (T, sum M_i), its adaptation steps one column per unit (T, K), its state a tuple of the units'
    states; the reference (each (n,)) is every environment's."""

    def __init__(self, controllers: list[Controller], sizes: list[int]) -> None:
        if len(controllers) != len(sizes) or not controllers:
            raise ValueError(f"need one batch size per controller, got {len(sizes)} for {len(controllers)}")
        # The controllers themselves are not kept: the units are what runs (and, compiled, what a
        # package's key reads; a `TwoPhaseBatch` keeps its parts' settings for its state only).
        runs: list[list[tuple[Controller, int]]] = []
        for c, size in zip(controllers, sizes):
            if runs and _batchable(runs[-1][-1][0], c):
                runs[-1].append((c, size))
            else:
                runs.append([(c, size)])
        self.units = [r[0][0] if len(r) == 1 else _batch(r) for r in runs]
        self.unit_sizes = [sum(s for _, s in r) for r in runs]
        self.needs_forces = any(c.needs_forces for c in self.units)
        feats = [c.features for c in self.units if c.features is not None]
        self.features = torch.cat(feats, -1) if feats else None
        self.columns: list[slice | None] = []
        start = 0
        for c in self.units:
            m = 0 if c.features is None else c.features.shape[-1]
            self.columns.append(slice(start, start + m) if m else None)
            start += m

    def init_state(self, q0: torch.Tensor, qd0: torch.Tensor) -> tuple:
        return tuple(
            c.init_state(q, qd) for c, q, qd in zip(self.units, q0.split(self.unit_sizes), qd0.split(self.unit_sizes))
        )

    def alphas(self, t: torch.Tensor) -> torch.Tensor:
        return torch.stack([c.alphas(t) for c in self.units], -1)

    def torque(
        self,
        ref: Reference,
        q: torch.Tensor,
        qd: torch.Tensor,
        state: tuple,
        *,
        h: torch.Tensor | None = None,
        alpha: torch.Tensor | None = None,
        applied: Applied | None = None,
        forces: Forces | None = None,
    ) -> tuple[torch.Tensor, tuple]:
        assert alpha is not None  # one column per unit (K,)
        rows = (
            [
                Forces(same_kind(forces.load, ld), forces.dist)
                for ld in zip(*(c.split(self.unit_sizes) for c in forces.load))
            ]
            if forces
            else []
        )
        taus, states = [], []
        parts = (
            [None] * len(self.units)
            if applied is None
            else [Applied(*a) for a in zip(*(x.split(self.unit_sizes) for x in applied))]
        )
        for i, (c, qi, qdi) in enumerate(zip(self.units, q.split(self.unit_sizes), qd.split(self.unit_sizes))):
            cols = self.columns[i]
            hi = None if cols is None or h is None else h[cols]
            fi = rows[i] if c.needs_forces else None
            tau, st = c.torque(ref, qi, qdi, state[i], h=hi, alpha=alpha[i], applied=parts[i], forces=fi)
            taus.append(tau)
            states.append(st)
        return torch.cat(taus), tuple(states)

    def share(self, state: tuple, like: torch.Tensor) -> torch.Tensor:
        return torch.cat([c.share(st, x) for c, st, x in zip(self.units, state, like.split(self.unit_sizes))])


def _batch(run: list[tuple[Controller, int]]) -> Controller:
    """Controllers `_batchable` one after the other as one."""
    sizes = [s for _, s in run]
    if type(run[0][0]) is TwoPhase:
        return TwoPhaseBatch([cast(TwoPhase, c) for c, _ in run], sizes)
    return SlidingModeBatch([cast(SlidingMode, c) for c, _ in run], sizes)


def _settled(c: TwoPhase):
    """c's gains with the settings a `TwoPhaseBatch` gives each environment set aside."""
    return replace(c.gains, estimate_rate=0.0, feedback_growth=1.0)


def _batchable(a: Controller, b: Controller) -> bool:
    """Whether controllers a and b can run as one: sliding-mode controllers with equal gains, time
    step, joint scale, joint rates and nominal model; two-phase ones with equal gains but the
    estimate's rate and the feedback's growth, time step, joint scale, nominal model, inertia
    schedule, velocity lag and features' width."""
    if type(a) is not type(b) or type(a) not in (SlidingMode, TwoPhase) or a.dt != b.dt:
        return False
    same_scale = a.scale is b.scale or (a.scale is not None and b.scale is not None and torch.equal(a.scale, b.scale))
    same_model = a.model is b.model or a.model == b.model  # (NominalModel: the same dynamics, factors and payload)
    if isinstance(a, TwoPhase) and isinstance(b, TwoPhase):
        sa, sb = a.schedule, b.schedule
        same_schedule = sa is sb or (
            sa.high == sb.high and torch.equal(sa.base, sb.base) and torch.equal(sa.per_kg, sb.per_kg)
        )
        return (
            _settled(a) == _settled(b)  # the estimate's rate and the feedback's growth: each environment's own
            and same_schedule
            and a.velocity_lag == b.velocity_lag
            and a.features.shape[-1] == b.features.shape[-1]
            and same_scale
            and same_model
        )
    assert isinstance(a, SlidingMode) and isinstance(b, SlidingMode)
    same_rates = a.rates is b.rates or (
        a.rates is not None and b.rates is not None and all(map(torch.equal, a.rates, b.rates))
    )
    return a.gains == b.gains and same_scale and same_rates and same_model
