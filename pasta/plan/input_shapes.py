"""Input-shape guard: a skill acts only on entities shaped like the ones it was trained on.

The feasibility networks score pairs of sets; nothing in their training says what a skill's *input* may look
like beyond the random and hard negatives, which are far from every real entity. A chain the demonstrations
never show can then score well. CRS-Twice plans six steps with CRS's networks: the plan cuts, pushes and
spreads one half, then cuts again, and the second cut should take the untouched half. With whole-sequence
windows the planner's best chains cut the piece just spread (12 of 15 plans), which CRS's cut never saw:
measured on CRS-Twice's five test problems, the untouched half lies 0.018-0.073 (in the VAE's shape latent
``z``) from the nearest of CRS's 36 training cut inputs, whose own leave-one-out nearest distances reach
0.156, and the spread half 0.43-0.97 (docs/planning.md).

``plan.input_shape_guard`` subtracts ``sum_j (max(d_j - r_k, 0) / softness)^2`` from a step's log-feasibility,
``d_j`` being the distance of input entity ``j``'s ``z`` to the nearest training input ``z`` of skill ``k`` and
``r_k`` the largest leave-one-out nearest-neighbour distance among those training inputs (how sparse the skill's
own inputs are). Within the training inputs' cloud it costs nothing; it only rules out acting on shapes no
demonstration of the skill started from. The reach guard (:mod:`pasta.plan.reach`) does the same for where a
skill's outputs may lie.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch

from pasta.plan.functions import PenaltyFn

__all__ = ["input_shape_penalty", "leave_one_out_radius", "skill_input_shapes", "sum_penalties"]


def skill_input_shapes(inputs: Iterable[torch.Tensor], latent_dim: int) -> torch.Tensor:
    """``(M, D_z)``: the shape latents of every input entity of a skill's training transitions.

    Args:
        inputs: per transition, its ``(n_in, D_z + 3)`` input entity latents.
        latent_dim: ``D_z``.
    """
    rows = [entities[:, :latent_dim].float() for entities in inputs if len(entities)]
    return torch.cat(rows) if rows else torch.empty(0, latent_dim)


def leave_one_out_radius(shapes: torch.Tensor) -> float:
    """The largest distance from a row of ``shapes`` ``(M, D_z)`` to its nearest other row (0 for ``M < 2``)."""
    if len(shapes) < 2:
        return 0.0
    distances = torch.cdist(shapes.double(), shapes.double())
    distances.fill_diagonal_(float("inf"))
    return float(distances.min(dim=1).values.max())


def input_shape_penalty(shapes: Sequence[torch.Tensor | None], latent_dim: int, softness: float) -> PenaltyFn:
    """``sum_j (max(d_j - r_k, 0) / softness)^2`` over a step's input entities ``j`` (module docstring).

    Args:
        shapes: per skill index ``k`` (one per arity, as ``PlanningFunctions.skills``), the ``(M_k, D_z)`` training
            input shapes, or ``None`` / an empty tensor to leave that skill unguarded.
        latent_dim: ``D_z``; an entity is ``(D_z + 3,)``, its shape the first ``D_z`` entries.
        softness: the distance beyond ``r_k`` that costs 1 (a factor ``exp(-1)`` on the feasibility).
    """
    if softness <= 0:
        raise ValueError(f"softness must be > 0, got {softness}")
    for k, points in enumerate(shapes):
        if points is not None and len(points) and (points.ndim != 2 or points.shape[1] != latent_dim):
            raise ValueError(f"skill {k}'s input shapes must be (M, {latent_dim}), got {tuple(points.shape)}")
    guarded = [None if points is None or len(points) == 0 else (points.float(), leave_one_out_radius(points))
               for points in shapes]

    def penalty(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        if guarded[skill] is None:
            return inputs.new_zeros(inputs.shape[0])
        points, radius = guarded[skill]
        z = inputs[..., :latent_dim]  # (B, n_in, D_z)
        nearest = torch.cdist(z.reshape(-1, latent_dim), points.to(z)).min(dim=1).values.reshape(z.shape[:2])
        return ((nearest - radius).clamp_min(0.0) / softness).pow(2).sum(dim=-1)

    return penalty


def sum_penalties(penalties: Sequence[PenaltyFn | None]) -> PenaltyFn | None:
    """One penalty adding those given (``None`` entries skipped); ``None`` when none is given."""
    given = [p for p in penalties if p is not None]
    if not given:
        return None
    if len(given) == 1:
        return given[0]

    def penalty(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        return torch.stack([p(skill, inputs, outputs) for p in given]).sum(dim=0)

    return penalty
