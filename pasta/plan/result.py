"""``Plan``: the planner's answer, as the executor and the evaluation read it."""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["Plan"]


@dataclass(frozen=True, eq=False)
class Plan:
    """A skill sequence with its attention structure and latent subgoal sets.

    Attributes:
        skills: skill names, length ``H``.
        attention: per step ``h``, indices into ``U^{h-1}`` of the attended entities (``N_in`` of the skill).
        latent_sets: ``U^0 .. U^H``; ``U^h`` is ``(K_h, D_z + 3)`` = [the ``N_out`` new entities, then the
            kept entities of ``U^{h-1}`` in their order].
        feasibilities: predicted feasibility of each step, in [0, 1].
        cost: predicted set cost of ``U^H`` against the goal (optimal matching).
        score: ``sum_h (log max(f_h, floor) - penalty_h) - alpha * max(cost, 0)``.
        planning_time_s: wall-clock seconds spent planning.
        penalties: the guard's penalty of each step (``plan.guard``; empty without a guard's terms).
    """

    skills: tuple[str, ...]
    attention: tuple[tuple[int, ...], ...]
    latent_sets: tuple[torch.Tensor, ...]
    feasibilities: tuple[float, ...]
    cost: float
    score: float
    planning_time_s: float
    penalties: tuple[float, ...] = ()

    @property
    def horizon(self) -> int:
        return len(self.skills)
