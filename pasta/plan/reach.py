"""Skill reach: how far a skill's outputs lie from its inputs in the demonstrations, and a planner guard on it.

A feasibility network trained on a few dozen demonstrations can score a transition no demonstration
resembles: at ``small`` the CutRearrange planner let ``cut`` put one half of the dough straight onto its
goal, 0.3 away, at feasibility 0.5-0.6, while the real in-place split scored 0.02-0.09 (docs/planning.md).
The reach of a skill is the largest distance, over its training transitions, from an output entity's centre
to the nearest input entity's centre: small for a cut or a spread, which leave the dough where it is, large
for a rearrange. ``plan.guard: reach`` subtracts ``sum_j (max(d_j - reach, 0) / softness)^2`` over the step's
output entities ``j`` from the step's log-feasibility (after the floor, so that the penalty keeps its gradient
where the network's feasibility is floored), so the planner keeps every skill's outputs within the distances
its networks were trained on.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch

from pasta.plan.functions import PenaltyFn

__all__ = ["output_distances", "reach_penalty", "skill_reach"]


def output_distances(inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
    """Distance from each output centre to the nearest input centre.

    Args:
        inputs: ``(B, n_in, 3)`` input entity centres.
        outputs: ``(B, n_out, 3)`` output entity centres.

    Returns:
        ``(B, n_out)``.
    """
    return (outputs[:, :, None, :] - inputs[:, None, :, :]).norm(dim=-1).min(dim=2).values


def skill_reach(transitions: Iterable[tuple[torch.Tensor, torch.Tensor]]) -> float:
    """The largest output distance (:func:`output_distances`) over one skill's transitions, each a pair of
    input centres ``(n_in, 3)`` and output centres ``(n_out, 3)``; ``nan`` without transitions."""
    reach = float("nan")
    for inputs, outputs in transitions:
        if len(inputs) and len(outputs):
            farthest = float(output_distances(inputs[None], outputs[None]).max())
            reach = farthest if reach != reach else max(reach, farthest)
    return reach


def reach_penalty(reach: Sequence[float], latent_dim: int, softness: float) -> PenaltyFn:
    """``sum_j (max(d_j - reach_k, 0) / softness)^2`` over a step's output entities ``j`` (:func:`output_distances`).

    Args:
        reach: per skill index ``k``; ``nan`` leaves that skill unguarded.
        latent_dim: ``D_z``; the centre ``t`` is the last 3 entries of an entity ``(D_z + 3,)``.
        softness: the distance beyond the reach that costs 1 (a factor ``exp(-1)`` on the feasibility).
    """
    if softness <= 0:
        raise ValueError(f"softness must be > 0, got {softness}")

    def penalty(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        limit = reach[skill]
        if limit != limit:
            return inputs.new_zeros(inputs.shape[0])
        beyond = (output_distances(inputs[..., latent_dim:], outputs[..., latent_dim:]) - limit).clamp_min(0.0)
        return (beyond / softness).pow(2).sum(dim=-1)

    return penalty
