"""Skill reach: how far a skill moves the dough along each axis in the demonstrations, and a planner guard on it.

A feasibility network trained on a few dozen demonstrations can score a transition no demonstration
resembles: at ``small`` the CutRearrange planner let ``cut`` put one half of the dough straight onto its
goal, 0.3 away, at feasibility 0.5-0.6, while the real in-place split scored 0.02-0.09 (docs/planning.md).
A skill's reach is, per axis, the largest displacement over its training transitions from an output
entity's centre to the centre of the input entity nearest it: a cut moves its pieces along x (0.29 on
CutRearrange with 150 demonstrations) but hardly in z (0.019) or y (0.006); a rearrange moves them in x
and z. ``plan.guard: reach`` subtracts ``sum_j sum_axis (max(|d_j,axis| - reach_axis, 0) / softness)^2``
over the step's output entities ``j`` from the step's log-feasibility (after the floor, so that the penalty
keeps its gradient where the network's feasibility is floored), so the planner keeps every skill's outputs
within the displacements its networks were trained on.

A box per axis is right for the knife, which moves along x only, but too tight for a tool that moves along x
and z: CRS's 24 demonstrations pushed pieces at most 0.385 along x and 0.202 along z, and a test problem that
needs a push of 0.25 along x and 0.31 along z was planned as two pushes instead of a push and a spread. For the
skills in ``planar`` (their tool moves along both x and z, :func:`planar_skills`), the guard limits the
horizontal distance ``|(d_x, d_z)|`` by the larger of the two horizontal reaches, and ``d_y`` by its own.

Horizontally the tasks are symmetric, vertically they are not: a spread always lowers its piece's centre (by
0.019-0.022 on CRS at ``small``), a cut lowers its pieces a little, a lift raises the dough. With
``plan.reach_vertical: signed`` the guard keeps ``d_y`` (signed) between the lowest and the highest values of
the skill's training transitions (:func:`skill_vertical_range`), so a spread that leaves its piece as it was
(a wasted step the planner used to put first) is as far outside the training data as one that goes too far.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import torch

from pasta.config.schema import TaskConfig
from pasta.plan.functions import PenaltyFn

__all__ = ["output_displacements", "planar_skills", "reach_penalty", "signed_output_displacements", "skill_reach",
           "skill_vertical_range"]


def signed_output_displacements(inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
    """Per axis, the displacement (output minus input) of each output centre from the input centre nearest it.

    Args:
        inputs: ``(B, n_in, 3)`` input entity centres.
        outputs: ``(B, n_out, 3)`` output entity centres.

    Returns:
        ``(B, n_out, 3)``.
    """
    offsets = outputs[:, :, None, :] - inputs[:, None, :, :]  # (B, n_out, n_in, 3)
    nearest = offsets.norm(dim=-1).argmin(dim=2)  # (B, n_out)
    return offsets.gather(2, nearest[..., None, None].expand(-1, -1, 1, 3)).squeeze(2)


def output_displacements(inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
    """Per axis, the absolute displacement ``(B, n_out, 3)`` of each output centre from the input centre nearest
    it (:func:`signed_output_displacements`)."""
    return signed_output_displacements(inputs, outputs).abs()


def skill_reach(transitions: Iterable[tuple[torch.Tensor, torch.Tensor]]) -> tuple[float, float, float]:
    """Per axis, the largest output displacement (:func:`output_displacements`) over one skill's transitions,
    each a pair of input centres ``(n_in, 3)`` and output centres ``(n_out, 3)``; ``nan`` without transitions."""
    farthest = [d.reshape(-1, 3) for inputs, outputs in transitions if len(inputs) and len(outputs)
                for d in [output_displacements(inputs[None], outputs[None])]]
    if not farthest:
        return (math.nan, math.nan, math.nan)
    x, y, z = torch.cat(farthest).max(dim=0).values.tolist()
    return (x, y, z)


def skill_vertical_range(transitions: Iterable[tuple[torch.Tensor, torch.Tensor]]) -> tuple[float, float]:
    """The lowest and highest signed ``d_y`` (:func:`signed_output_displacements`) over one skill's transitions,
    each a pair of input centres ``(n_in, 3)`` and output centres ``(n_out, 3)``; ``nan`` without transitions."""
    heights = [d[..., 1].reshape(-1) for inputs, outputs in transitions if len(inputs) and len(outputs)
               for d in [signed_output_displacements(inputs[None], outputs[None])]]
    if not heights:
        return (math.nan, math.nan)
    every = torch.cat(heights)
    return (float(every.min()), float(every.max()))


def planar_skills(cfg: TaskConfig) -> frozenset[str]:
    """The skills whose tool moves along both horizontal axes (action scales of x and z above zero)."""
    tools = {tool.name: tool for tool in cfg.tools}
    return frozenset(skill.name for skill in cfg.skills
                     if tools[skill.tool].action_scales[0] > 0 and tools[skill.tool].action_scales[2] > 0)


def reach_penalty(reach: Sequence[Sequence[float]], latent_dim: int, softness: float,
                  planar: Sequence[bool] | None = None,
                  vertical: Sequence[Sequence[float]] | None = None) -> PenaltyFn:
    """``sum_j sum_axis (max(d_j,axis - reach_k,axis, 0) / softness)^2`` over a step's output entities ``j``
    (:func:`output_displacements`); for a planar skill the axes are the horizontal distance ``|(d_x, d_z)|``,
    limited by ``max(reach_x, reach_z)``, and ``d_y``. With ``vertical`` the ``d_y`` term is the signed
    ``d_y``'s distance outside the skill's ``(lowest, highest)`` range instead.

    Args:
        reach: per skill index ``k``, the ``(x, y, z)`` reach; ``nan`` leaves that skill unguarded.
        latent_dim: ``D_z``; the centre ``t`` is the last 3 entries of an entity ``(D_z + 3,)``.
        softness: the distance beyond the reach that costs 1 (a factor ``exp(-1)`` on the feasibility).
        planar: per skill index, whether its horizontal reach is one distance (default: none is).
        vertical: per skill index, the ``(lowest, highest)`` signed ``d_y`` (:func:`skill_vertical_range`).
    """
    if softness <= 0:
        raise ValueError(f"softness must be > 0, got {softness}")
    flat = [False] * len(reach) if planar is None else list(planar)
    if len(flat) != len(reach):
        raise ValueError(f"planar has {len(flat)} values for {len(reach)} skills")
    if vertical is not None and (len(vertical) != len(reach) or any(len(v) != 2 for v in vertical)
                                 or any(v[0] > v[1] for v in vertical)):
        raise ValueError(f"vertical must hold a (lowest, highest) pair for each of {len(reach)} skills, got {vertical}")

    # Per skill: None (unguarded), or its limits, (horizontal, y) for a planar skill and (x, y, z) otherwise.
    limits = [None if any(math.isnan(v) for v in r)
              else torch.tensor([max(r[0], r[2]), r[1]] if planar_skill else list(r), dtype=torch.float32)
              for r, planar_skill in zip(reach, flat, strict=True)]

    def penalty(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        limit = limits[skill]
        if limit is None:
            return inputs.new_zeros(inputs.shape[0])
        signed = signed_output_displacements(inputs[..., latent_dim:], outputs[..., latent_dim:])
        displacement = signed.abs()
        if flat[skill]:
            displacement = torch.stack([displacement[..., [0, 2]].norm(dim=-1), displacement[..., 1]], dim=-1)
        excess = (displacement - limit.to(inputs)).clamp_min(0.0)
        if vertical is not None:
            lowest, highest = vertical[skill]
            vertical_excess = (signed[..., 1] - highest).clamp_min(0.0) + (lowest - signed[..., 1]).clamp_min(0.0)
            excess = torch.cat([excess[..., :1], vertical_excess[..., None], excess[..., 2:]], dim=-1)
        return (excess / softness).pow(2).sum(dim=(-1, -2))

    return penalty
