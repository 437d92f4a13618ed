"""An analytic planning problem with a known best plan.

Skills: ``move`` (1 -> 1) keeps the shape code ``z`` and may go anywhere; ``cut`` (1 -> 2) works only at
the cutting station ``t_x = 0.2`` and gives two halves with ``z_in + DELTA`` at ``t_in +- OFFSET``.
The scene holds a distractor ``R`` already at its goal and a piece ``P`` away from the station; the goal
wants one half at the station and the other moved away. The unique best sequence is (move, cut, move):
move P (index 1 of U^0) to the station, cut it (index 0 of U^1), move one half (index 0 or 1 of U^2, never
R at index 2). The best score is 0 (every feasibility 1, cost 0). About one sample in 24 of the right
sequence has the right structure and a first-iteration matching that lets it reach 0 (the matching is
frozen), so tests use a few hundred samples.
"""

from __future__ import annotations

import torch

from pasta.models.latent_prior import LatentPrior
from pasta.plan import PlanningFunctions, SkillSpec

WIDTH = 0.5
STATION_WEIGHT = 10.0
DELTA = torch.tensor([-0.5, 0.0])
OFFSET = torch.tensor([0.0, 0.0, 0.1])
PRIOR = LatentPrior(2, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
SKILLS = (SkillSpec("move", 1, 1), SkillSpec("cut", 1, 2))

R = [1.0, 0.0, 0.5, 0.1, 0.8]
P = [0.0, 0.0, 0.8, 0.1, 0.3]
HALF_AT_STATION = [-0.5, 0.0, 0.2, 0.1, 0.4]
HALF_MOVED = [-0.5, 0.0, 0.8, 0.1, 0.2]
OBS = torch.tensor([R, P])
GOAL = torch.tensor([HALF_MOVED, R, HALF_AT_STATION])
BEST_SKILLS = ("move", "cut", "move")


def feasibility(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
    """``(B, n_in, 5)``, ``(B, n_out, 5)`` -> ``(B,)``."""
    z_in, t_in = inputs[:, 0, :2], inputs[:, 0, 2:]
    if SKILLS[skill].name == "move":
        error = ((outputs[:, 0, :2] - z_in) ** 2).sum(-1)
    else:
        delta, offset = DELTA.to(inputs), OFFSET.to(inputs)
        error = STATION_WEIGHT * (t_in[:, 0] - 0.2) ** 2
        for j, sign in enumerate((1.0, -1.0)):
            error = error + ((outputs[:, j, :2] - z_in - delta) ** 2).sum(-1)
            error = error + ((outputs[:, j, 2:] - t_in - sign * offset) ** 2).sum(-1)
    return torch.exp(-error / WIDTH**2)


def pair_cost(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distance of two entities ``(..., 5)`` -> ``(...)``."""
    return ((a - b) ** 2).sum(-1)


FUNCTIONS = PlanningFunctions(SKILLS, PRIOR, feasibility, pair_cost)
