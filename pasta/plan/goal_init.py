"""Goal-directed initial latents: samples that start on a path from the observed entities to the goal's.

The appendix draws every new vector from the prior, so a long plan starts far from both its inputs and the
goal and must be found by gradient steps alone. Here a sample's final set ``U^H`` is assigned goal entities
(a uniformly random assignment per sample), each new vector inherits the goal entity its lineage ends in,
and it starts on the straight line from what its step attends to that goal entity, one equal stride per
remaining step of the lineage: the vectors of the final set start *at* their goal entities, an earlier step's
outputs part of the way there. Vectors whose lineage reaches no goal entity (``U^H`` longer than the goal)
keep their prior draws. The attention structures are unchanged.
"""

from __future__ import annotations

import torch

from pasta.plan.attention import Structures

__all__ = ["goal_directed_latents"]


def goal_directed_latents(structures: Structures, start: torch.Tensor, goal: torch.Tensor, drawn: torch.Tensor,
                          rows: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """Replace the initial vectors of ``rows`` by goal-directed ones.

    Args:
        structures: the ``S`` samples' attention structures (CPU).
        start: ``(K_0, E)`` the observed entities.
        goal: ``(K_g, E)`` the goal entities.
        drawn: ``(S, V, E)`` the prior draws of the new vectors (``V >= structures.n_variables``).
        rows: ``(R,)`` the samples to initialise from the goal.
        generator: CPU generator for the assignment of goal entities to ``U^H``.

    Returns:
        ``(S, V, E)``: ``drawn`` with the vectors of ``rows`` replaced.
    """
    if rows.numel() == 0:
        return drawn
    device = drawn.device
    n_rows, k_fixed, k_goal = rows.shape[0], structures.n_fixed, goal.shape[0]
    n_pool = k_fixed + structures.n_variables
    local = rows.cpu()
    final = structures.sets[-1][local]  # (R, K_H)
    k_final = final.shape[1]
    order = torch.rand((n_rows, max(k_final, k_goal)), generator=generator).argsort(dim=1)[:, :k_final]
    assigned = torch.where(order < k_goal, order, torch.full_like(order, -1))
    destination = torch.full((n_rows, n_pool), -1, dtype=torch.long)
    remaining = torch.zeros((n_rows, n_pool), dtype=torch.long)
    destination.scatter_(1, final, assigned)
    for h in reversed(range(len(structures.sequence))):
        created = structures.created[h]
        inputs = structures.attended[h][local]  # (R, n_in)
        chosen = destination[:, created[0]]
        steps_left = remaining[:, created[0]]
        for index in created[1:]:  # the first output with a destination names the inputs' destination
            take = (chosen < 0) & (destination[:, index] >= 0)
            chosen = torch.where(take, destination[:, index], chosen)
            steps_left = torch.where(take, remaining[:, index], steps_left)
        destination.scatter_(1, inputs, chosen.unsqueeze(1).expand_as(inputs))
        remaining.scatter_(1, inputs, (steps_left + 1).unsqueeze(1).expand_as(inputs))
    values = torch.cat([start.to(device).expand(n_rows, -1, -1), drawn[rows, : structures.n_variables]], dim=1)
    destination, remaining = destination.to(device), remaining.to(device)
    goal = goal.to(device=device, dtype=drawn.dtype)
    e = values.shape[2]
    for h in range(len(structures.sequence)):
        inputs = structures.attended[h][local].to(device)
        origin = values.gather(1, inputs.unsqueeze(-1).expand(-1, -1, e)).mean(dim=1)  # (R, E)
        for index in structures.created[h].tolist():
            target = destination[:, index]
            towards = goal[target.clamp_min(0)]
            stride = 1.0 / (remaining[:, index] + 1).to(drawn.dtype)
            moved = origin + (towards - origin) * stride.unsqueeze(1)
            values[:, index] = torch.where((target >= 0).unsqueeze(1), moved, values[:, index])
    out = drawn.clone()
    out[rows, : structures.n_variables] = values[:, k_fixed:]
    return out
