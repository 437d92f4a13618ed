"""The goal's own pieces as the subgoals of the entities a plan finishes (``eval.final_subgoals: goal``).

A plan's subgoals are latents the executor decodes with the VAE. An entity that no later step attends is
one the plan means to leave as a piece of the goal, and the goal is observed: its pieces are at hand as
points, without the decoder's errors (at ``small`` CRS's 2-D latents decode both of its goal's pieces about
0.06 high, docs/evaluation.md). Here every entity of the plan's final set ``U^H`` takes the goal piece whose
centre is nearest its planned centre (a one-to-one matching of the centres ``t``; with unequal counts some
stay unmatched), and each step's new entities that survive to ``U^H`` matched are handed that piece's points and
latent instead of their decoded cloud. Entities a later step attends keep their decoded subgoals; where a step
makes both kinds (a cut whose one piece is finished and whose other is pushed later), the decoded ones are
resampled to hold the attended dough the goal pieces leave (:func:`step_subgoals`), so that the step's subgoals
weigh each piece by its mass, as a goal's points do. Measured on CRS at ``small`` this changes nothing overall
(docs/evaluation.md): the scripted cut splits by the pieces' lengths, which resampling leaves as decoded.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from pasta.evaluate.encoding import EncodedScene
from pasta.geometry.entities import resample
from pasta.plan.result import Plan

__all__ = ["MIN_SHARE", "GoalSubgoal", "final_rows", "goal_subgoals", "step_subgoals"]

MIN_SHARE = 10  # fewest points a decoded entity may be left beside goal pieces (a DBSCAN piece needs more than 10)


@dataclass(frozen=True, eq=False)
class GoalSubgoal:
    """A goal piece standing in for a new entity: ``points`` ``(Q, 3)`` float32, ``latent`` ``(D_z + 3,)``."""

    points: np.ndarray
    latent: torch.Tensor


def final_rows(plan: Plan) -> dict[tuple[int, int], int]:
    """``(h, i)`` -> row of ``U^H`` for the ``i``-th new entity of step ``h`` (1-based) that no later step attends.

    ``U^h`` is ``[new entities of step h, the entities of U^{h-1} it did not attend, in their order]``.
    """
    origins: list[tuple[int, int]] = [(0, i) for i in range(plan.latent_sets[0].shape[0])]
    for h, attention in enumerate(plan.attention, start=1):
        attended = set(attention)
        kept = [origin for j, origin in enumerate(origins) if j not in attended]
        n_out = plan.latent_sets[h].shape[0] - len(kept)
        origins = [(h, i) for i in range(n_out)] + kept
    return {origin: row for row, origin in enumerate(origins) if origin[0] > 0}


def goal_subgoals(plan: Plan, goal: EncodedScene, goal_points: np.ndarray) -> dict[tuple[int, int], GoalSubgoal]:
    """The goal piece each finished and matched new entity of ``plan`` is handed, keyed ``(h, i)`` as
    :func:`final_rows`.

    Args:
        goal: the goal encoded (``latents`` ``(K_g, D_z + 3)``, ``labels`` over ``goal_points``).
        goal_points: ``(P, 3)`` the goal cloud ``goal`` was encoded from.
    """
    points = np.asarray(goal_points, np.float32)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) != len(goal.labels):
        raise ValueError(f"goal_points must be the ({len(goal.labels)}, 3) cloud the goal was encoded from, "
                         f"got {points.shape}")
    final = plan.latent_sets[-1].detach().float().cpu()
    goal_latents = goal.latents.detach().float().cpu()
    if final.shape[1] != goal_latents.shape[1]:
        raise ValueError(f"the plan's latents have {final.shape[1]} numbers, the goal's {goal_latents.shape[1]}")
    centres = final[:, -3:].numpy().astype(np.float64)
    goal_centres = goal_latents[:, -3:].numpy().astype(np.float64)
    distances = np.linalg.norm(centres[:, None, :] - goal_centres[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(distances)
    piece_of_row = dict(zip(rows.tolist(), cols.tolist(), strict=True))
    return {key: GoalSubgoal(points[goal.labels == piece_of_row[row]], goal_latents[piece_of_row[row]])
            for key, row in final_rows(plan).items() if row in piece_of_row}


def step_subgoals(decoded: np.ndarray, handed: Sequence[GoalSubgoal | None], attended_points: int,
                  rng: np.random.Generator) -> np.ndarray:
    """One step's new subgoals stacked, ``(Q, 3)``: the goal piece where one is handed, else the decoded cloud.

    Args:
        decoded: ``(N_out, M, 3)`` the step's decoded new entities.
        handed: per new entity its goal piece, or None.
        attended_points: how many observed points the step acts on (the dough it shares among its new entities).

    Where a step mixes goal pieces and decoded entities, the decoded ones are resampled (with ``rng``) to share,
    in equal parts, the ``attended_points`` the goal pieces do not hold; when the goal pieces hold nearly all of
    them (fewer than ``MIN_SHARE`` points left per decoded entity) the step keeps every decoded cloud.
    """
    if len(handed) != len(decoded):
        raise ValueError(f"{len(handed)} handed pieces for {len(decoded)} decoded new entities")
    n_open = sum(goal is None for goal in handed)
    if n_open == 0:
        return np.concatenate([goal.points for goal in handed]).astype(np.float32)
    left = attended_points - sum(len(goal.points) for goal in handed if goal is not None)
    if n_open == len(decoded) or left < MIN_SHARE * n_open:
        return decoded.reshape(-1, 3)
    clouds = [resample(decoded[i], left // n_open, rng) if goal is None else goal.points
              for i, goal in enumerate(handed)]
    return np.concatenate(clouds).astype(np.float32)
