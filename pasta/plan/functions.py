"""What the planner needs from the learned models, as plain callables (so tests can pass analytic ones)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from pasta.models.latent_prior import LatentPrior
from pasta.plan.sequences import SkillSpec

__all__ = ["FeasibilityFn", "PairCostFn", "PenaltyFn", "PlanningFunctions"]

# (skill index, attended inputs (B, n_in, E), new vectors (B, n_out, E)) -> (B,) feasibility in [0, 1].
FeasibilityFn = Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor]
# (a (..., E), b (..., E)) -> (...) predicted cost of each entity pair.
PairCostFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
# (skill index, attended inputs (B, n_in, E), new vectors (B, n_out, E)) -> (B,) penalty >= 0, subtracted from
# the step's log-feasibility after the floor (so that it keeps its gradient where the feasibility is floored).
PenaltyFn = Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class PlanningFunctions:
    """The skills, the latent prior and the two differentiable functions the objective is built from.

    Attributes:
        skills: the skills, one spec per arity (a skill taking 1 or 2 entities has two specs of one name);
            ``feasibility``'s first argument indexes this tuple.
        prior: ``z ~ N(0, I)`` and the box of ``t``; new vectors start from it and ``t`` stays in its box.
        feasibility: ``f_k(inputs, outputs)`` per skill index (see ``FeasibilityFn``).
        pair_cost: ``c(a, b)`` for entity pairs (see ``PairCostFn``).
        penalty: a guard's log-space penalty per step (see ``PenaltyFn``), or ``None``.
    """

    skills: tuple[SkillSpec, ...]
    prior: LatentPrior
    feasibility: FeasibilityFn
    pair_cost: PairCostFn
    penalty: PenaltyFn | None = None

    def __post_init__(self) -> None:
        if not self.skills:
            raise ValueError("need at least one skill")
        arities = [(s.name, s.n_in, s.n_out) for s in self.skills]
        if len(set(arities)) != len(arities):
            raise ValueError(f"skills must be distinct (name, n_in, n_out), got {arities}")

    def step_penalty(self, skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        """``(B,)``: the guard's penalty of each step, zeros without a guard."""
        if self.penalty is None:
            return inputs.new_zeros(inputs.shape[0])
        return self.penalty(skill, inputs, outputs)

    @property
    def entity_dim(self) -> int:
        return self.prior.entity_dim
