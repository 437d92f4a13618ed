"""What the planner needs from the learned models, as plain callables (so tests can pass analytic ones)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from pasta.models.latent_prior import LatentPrior
from pasta.plan.sequences import SkillSpec

__all__ = ["FeasibilityFn", "PairCostFn", "PlanningFunctions"]

# (skill index, attended inputs (B, n_in, E), new vectors (B, n_out, E)) -> (B,) feasibility in [0, 1].
FeasibilityFn = Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor]
# (a (..., E), b (..., E)) -> (...) predicted cost of each entity pair.
PairCostFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class PlanningFunctions:
    """The skills, the latent prior and the two differentiable functions the objective is built from.

    Attributes:
        skills: the skills, one spec per arity (a skill taking 1 or 2 entities has two specs of one name);
            ``feasibility``'s first argument indexes this tuple.
        prior: ``z ~ N(0, I)`` and the box of ``t``; new vectors start from it and ``t`` stays in its box.
        feasibility: ``f_k(inputs, outputs)`` per skill index (see ``FeasibilityFn``).
        pair_cost: ``c(a, b)`` for entity pairs (see ``PairCostFn``).
    """

    skills: tuple[SkillSpec, ...]
    prior: LatentPrior
    feasibility: FeasibilityFn
    pair_cost: PairCostFn

    def __post_init__(self) -> None:
        if not self.skills:
            raise ValueError("need at least one skill")
        arities = [(s.name, s.n_in, s.n_out) for s in self.skills]
        if len(set(arities)) != len(arities):
            raise ValueError(f"skills must be distinct (name, n_in, n_out), got {arities}")

    @property
    def entity_dim(self) -> int:
        return self.prior.entity_dim
