"""The discrete Ant System exactly as the paper prints it, for choosing M of N candidates.

Each of K ants picks M distinct candidates with p_j = tau_j^a eta_j^b / sum (the paper: a = 1,
b = 0). After all ants of an iteration are evaluated (one batched objective call), the pheromone
is updated as printed: tau <- (1 - rho) tau + rho * dtau, dtau_j = sum over ants that chose j of
Q / L_k. The colony stops when every ant chose the same set (convergence) or after NC_max
iterations; the best-so-far set is kept throughout.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tqdm.auto import tqdm

from .result import ACOResult

__all__ = ["AntSystem"]

_TAU_FLOOR = 1e-300  # keeps every candidate drawable, far below any reachable pheromone


class AntSystem:
    """Discrete colony over `n_candidates` choices, each ant choosing `subset_size` of them."""

    def __init__(
        self,
        ants: int = 20,
        iterations: int = 100,
        rho: float = 0.9,
        Q: float = 100.0,
        alpha: float = 1.0,
        beta: float = 0.0,
        tau0: float = 1.0,
        progress: bool = False,
    ) -> None:
        if not 0.0 < rho < 1.0:
            raise ValueError(f"rho must be in (0, 1), got {rho}")
        if ants < 1 or iterations < 0 or Q <= 0 or tau0 <= 0:
            raise ValueError(
                f"need ants >= 1, iterations >= 0, Q > 0, tau0 > 0; got ants={ants}, "
                f"iterations={iterations}, Q={Q}, tau0={tau0}"
            )
        self.ants, self.iterations, self.rho, self.Q = ants, iterations, rho, Q
        self.alpha, self.beta, self.tau0, self.progress = alpha, beta, tau0, progress

    def minimize(
        self,
        objective: Callable[[torch.Tensor], torch.Tensor],
        n_candidates: int,
        subset_size: int,
        eta: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
        callback: Callable[[int, float, float], None] | None = None,
        state: dict | None = None,
        on_state: Callable[[dict], None] | None = None,
    ) -> ACOResult:
        """Minimize `objective` over subsets; it maps indices (K, M) (long) to positive values (K,).

        eta: optional heuristic desirability (N,) of each candidate. Returns ACOResult whose
        `best` is the best subset's indices (M,), sorted. `on_state(state)` receives after every
        iteration a snapshot (pheromone, best, iteration, of iterations, histories, generator state) that,
        passed back as `state`, continues the run exactly where it was.
        """
        if not 1 <= subset_size <= n_candidates:
            raise ValueError(f"subset_size must be in [1, {n_candidates}], got {subset_size}")
        eta_b = (
            torch.ones(n_candidates, dtype=torch.float64)
            if eta is None
            else eta.to(torch.float64).cpu().clamp_min(0) ** self.beta
        )
        if state is not None:
            tau = state["pheromone"].clone()
            res = ACOResult(
                best=state["best"].clone(),
                best_value=state["best_value"],
                iterations=state["iteration"],
                best_history=list(state["best_history"]),
                mean_history=list(state["mean_history"]),
                converged=state["converged"],
            )
            if generator is not None:
                generator.set_state(state["generator"])
        else:
            tau = torch.full((n_candidates,), self.tau0, dtype=torch.float64)
            res = ACOResult(best=torch.empty(0, dtype=torch.long), best_value=float("inf"), iterations=0)
        start = self.iterations if res.converged else res.iterations
        for it in tqdm(
            range(start, self.iterations),
            desc="Ant System",
            disable=not self.progress,
            leave=False,
            initial=start,
            total=self.iterations,
        ):
            p = (tau.clamp_min(_TAU_FLOOR) ** self.alpha) * eta_b
            p = (p / p.sum()).clamp_min(_TAU_FLOOR)
            choice = (
                torch.multinomial(p.expand(self.ants, -1), subset_size, replacement=False, generator=generator)
                .sort(-1)
                .values
            )  # (K, M)
            lengths = objective(choice).to(torch.float64).cpu()
            lengths = torch.nan_to_num(lengths, nan=torch.inf)
            k_best = int(lengths.argmin())
            if float(lengths[k_best]) < res.best_value:
                res.best, res.best_value = choice[k_best].clone(), float(lengths[k_best])
            # tau <- (1 - rho) tau + rho * sum_{k chose j} Q / L_k
            dtau = torch.zeros_like(tau).index_add_(
                0, choice.reshape(-1), (self.Q / lengths).repeat_interleave(subset_size)
            )
            tau = (1 - self.rho) * tau + self.rho * dtau
            res.best_history.append(res.best_value)
            res.mean_history.append(float(lengths[torch.isfinite(lengths)].mean()))
            res.iterations = it + 1
            if callback is not None:
                callback(it, res.best_value, res.mean_history[-1])
            res.converged = bool((choice == choice[0]).all())
            if on_state is not None:
                on_state(
                    {
                        "pheromone": tau.clone(),
                        "best": res.best.clone(),
                        "best_value": res.best_value,
                        "iteration": it + 1,
                        "iterations": self.iterations,
                        "best_history": list(res.best_history),
                        "mean_history": list(res.mean_history),
                        "converged": res.converged,
                        "generator": generator.get_state() if generator is not None else torch.get_rng_state(),
                    }
                )
            if res.converged:
                break
        self.pheromone = tau  # the final pheromone (N,), for inspection
        return res
