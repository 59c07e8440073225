"""ACO_R, ant colony optimization for continuous domains (Socha & Dorigo, EJOR 2008).

An archive of k solutions ranked by objective; each ant picks a guide solution with Gaussian
rank weights (parameter q), then samples every coordinate from a normal around the guide with
spread xi times the archive's mean absolute distance to it. The archive keeps the best k of
archive and ants, so the best-so-far never worsens. All ants of an iteration are evaluated as
one batch: `objective` maps (K, D) solutions to (K,) values to minimize.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from tqdm.auto import tqdm

from .result import ACOResult

__all__ = ["ACOR"]


class ACOR:
    """Continuous ant colony optimizer.

    archive_size: k solutions kept; ants: solutions sampled per iteration; q: locality of guide
    choice (small q: mostly the best); xi: spread factor; iterations: maximum iterations;
    lower / upper: (D,) bounds, samples are clipped to them.
    """

    def __init__(
        self,
        archive_size: int = 20,
        ants: int = 20,
        q: float = 0.2,
        xi: float = 0.85,
        iterations: int = 100,
        lower: torch.Tensor | None = None,
        upper: torch.Tensor | None = None,
        progress: bool = False,
    ) -> None:
        if archive_size < 2:
            raise ValueError(f"archive_size must be >= 2, got {archive_size}")
        if ants < 1 or iterations < 0 or q <= 0 or xi <= 0:
            raise ValueError(
                f"need ants >= 1, iterations >= 0, q > 0, xi > 0; got ants={ants}, "
                f"iterations={iterations}, q={q}, xi={xi}"
            )
        self.k, self.ants, self.q, self.xi, self.iterations = archive_size, ants, q, xi, iterations
        self.lower, self.upper, self.progress = lower, upper, progress

    def _clip(self, x: torch.Tensor) -> torch.Tensor:
        if self.lower is not None:
            x = torch.maximum(x, self.lower)
        if self.upper is not None:
            x = torch.minimum(x, self.upper)
        return x

    def minimize(
        self,
        objective: Callable[[torch.Tensor], torch.Tensor],
        init: torch.Tensor,
        generator: torch.Generator | None = None,
        callback: Callable[[int, float, float], None] | None = None,
        state: dict | None = None,
        on_state: Callable[[dict], None] | None = None,
    ) -> ACOResult:
        """Minimize `objective` from an initial population `init` (n >= 2, D); returns ACOResult.

        The archive is the best min(n, k) of `init`; it is filled to k by sampling around them.
        `callback(iteration, best, mean)` is called after every iteration. `on_state(state)`
        receives after every iteration a snapshot (archive, values, iteration, of iterations, histories and the
        generator's state) that, passed back as `state`, continues the run exactly where it was.
        """
        if state is not None:
            arch, vals = state["archive"].to(init), state["values"].to(init)
            res = ACOResult(
                best=arch[0].clone(),
                best_value=float(vals[0]),
                iterations=state["iteration"],
                best_history=list(state["best_history"]),
                mean_history=list(state["mean_history"]),
            )
            if generator is not None:
                generator.set_state(state["generator"])
        else:
            x = self._clip(init)
            values = objective(x)
            order = values.argsort()
            arch, vals = x[order][: self.k], values[order][: self.k]
            if arch.shape[0] < self.k:
                extra = self._sample(arch, vals, self.k - arch.shape[0], generator)
                arch, vals = self._merge(arch, vals, extra, objective(extra))
            res = ACOResult(best=arch[0].clone(), best_value=float(vals[0]), iterations=0)
        k = arch.shape[0]
        ranks = torch.arange(k, dtype=arch.dtype, device=arch.device)
        w = torch.exp(-ranks.square() / (2 * (self.q * k) ** 2)) / (self.q * k * math.sqrt(2 * math.pi))
        self._probs = w / w.sum()
        for it in tqdm(
            range(res.iterations, self.iterations),
            desc="ACO_R",
            disable=not self.progress,
            leave=False,
            initial=res.iterations,
            total=self.iterations,
        ):
            ants = self._sample(arch, vals, self.ants, generator)
            ant_vals = objective(ants)
            arch, vals = self._merge(arch, vals, ants, ant_vals)
            res.best_history.append(float(vals[0]))
            res.mean_history.append(float(torch.nan_to_num(ant_vals, posinf=float("nan")).nanmean()))
            res.iterations = it + 1
            if callback is not None:
                callback(it, res.best_history[-1], res.mean_history[-1])
            if on_state is not None:
                on_state(
                    {
                        "archive": arch.cpu(),
                        "values": vals.cpu(),
                        "iteration": it + 1,
                        "iterations": self.iterations,
                        "best_history": list(res.best_history),
                        "mean_history": list(res.mean_history),
                        "generator": generator.get_state() if generator is not None else torch.get_rng_state(),
                    }
                )
        res.best, res.best_value = arch[0].clone(), float(vals[0])
        return res

    def _sample(
        self, arch: torch.Tensor, vals: torch.Tensor, n: int, generator: torch.Generator | None
    ) -> torch.Tensor:
        k = arch.shape[0]
        probs = getattr(self, "_probs", None)
        if probs is None or probs.shape[0] != k:
            probs = torch.ones(k, dtype=arch.dtype, device=arch.device) / k
        guide = torch.multinomial(probs.cpu(), n, replacement=True, generator=generator).to(arch.device)
        mu = arch[guide]  # (n, D)
        spread = self.xi * (arch.unsqueeze(0) - mu.unsqueeze(1)).abs().sum(1) / max(k - 1, 1)
        noise = torch.randn(mu.shape, dtype=arch.dtype, generator=generator).to(arch.device)
        return self._clip(mu + spread * noise)

    def _merge(self, arch, vals, new, new_vals):
        new_vals = torch.nan_to_num(new_vals, nan=torch.inf)
        x = torch.cat([arch, new])
        v = torch.cat([vals, new_vals])
        order = v.argsort(stable=True)[: self.k]
        return x[order], v[order]
