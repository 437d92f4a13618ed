from __future__ import annotations

import pytest
import torch

from pasta.plan import PlanSettings, SkillSpec, sample_structures
from pasta.plan.goal_init import goal_directed_latents
from pasta.plan.optimiser import optimise
from tests.plan.analytic import FUNCTIONS, OBS, PRIOR

CUT, MOVE = SkillSpec("cut", 1, 2), SkillSpec("move", 1, 1)
START = torch.tensor([[0.0, 0.0, 0.0]])
GOAL = torch.tensor([[4.0, 0.0, 2.0], [-4.0, 2.0, 0.0]])


def _pool(structures, values, row):
    return torch.cat([START, values[row, : structures.n_variables]])


def test_final_vectors_start_at_goal_entities_and_earlier_ones_part_way():
    structures = sample_structures((CUT, MOVE), 1, 50, torch.Generator().manual_seed(0))
    drawn = torch.randn((50, 3, 3), generator=torch.Generator().manual_seed(1))
    rows = torch.arange(0, 50, 2)
    out = goal_directed_latents(structures, START, GOAL, drawn, rows, torch.Generator().manual_seed(2))
    torch.testing.assert_close(out[1::2], drawn[1::2])  # the other samples keep their prior draws
    assignments = set()
    for row in rows.tolist():
        pool = _pool(structures, out, row)
        final = pool[structures.sets[-1][row]]
        matched = [int((GOAL - f).abs().sum(dim=1).argmin()) for f in final]
        assert sorted(matched) == [0, 1]
        torch.testing.assert_close(final, GOAL[matched])
        assignments.add(tuple(matched))
        moved = int(structures.attended[1][row][0])  # the cut output the move acts on: half-way to its goal
        torch.testing.assert_close(pool[moved], (START[0] + pool[structures.created[1][0]]) / 2)
    assert len(assignments) == 2  # both assignments of goal entities occur


def test_vectors_reaching_no_goal_entity_keep_their_draws():
    structures = sample_structures((CUT, CUT), 1, 8, torch.Generator().manual_seed(0))  # 3 entities, goal has 2
    drawn = torch.randn((8, 4, 3), generator=torch.Generator().manual_seed(1))
    out = goal_directed_latents(structures, START, GOAL, drawn, torch.arange(8), torch.Generator().manual_seed(2))
    for row in range(8):
        pool, prior = _pool(structures, out, row), _pool(structures, drawn, row)
        final = structures.sets[-1][row].tolist()
        on_goal = [i for i in final if any(torch.allclose(pool[i], g) for g in GOAL)]
        assert len(on_goal) == 2
        (left,) = [i for i in final if i not in on_goal]
        torch.testing.assert_close(pool[left], prior[left])  # no goal entity left for it: its prior draw


def test_the_optimiser_starts_goal_directed_samples_on_the_goal():
    goal = PRIOR.sample((3,), torch.Generator().manual_seed(5))
    sequence = (FUNCTIONS.skills[1], FUNCTIONS.skills[0])  # cut, move: 2 -> 3 entities
    settings = PlanSettings(lr=0.05, iterations=1, samples=8, alpha=100.0, goal_init_share=1.0)
    best = optimise(FUNCTIONS, OBS, goal, [sequence], settings, torch.Generator().manual_seed(0), torch.device("cpu"))
    final = best.structures[0].sets[-1][best.row].tolist()
    new = [i for i in final if i >= OBS.shape[0]]
    assert new
    for i in new:
        assert min(float((best.pool[i] - g).abs().max()) for g in goal) < 1e-6
    prior_only = optimise(FUNCTIONS, OBS, goal, [sequence], PlanSettings(lr=0.05, iterations=1, samples=8, alpha=100.0),
                          torch.Generator().manual_seed(0), torch.device("cpu"))
    assert not any(min(float((prior_only.pool[i] - g).abs().max()) for g in goal) < 1e-6
                   for i in range(OBS.shape[0], prior_only.pool.shape[0]))
    with pytest.raises(ValueError, match="goal_init_share must be in"):
        PlanSettings(lr=0.05, iterations=1, samples=8, alpha=100.0, goal_init_share=1.5)
