from __future__ import annotations

import pytest
import torch

from pasta.plan import PlanSettings, plan_receding_horizon_with
from pasta.plan.optimiser import optimise
from pasta.plan.planner import describe
from pasta.plan.sequences import resolve_sequence
from tests.plan.analytic import FUNCTIONS, OBS, PRIOR

SETTINGS = PlanSettings(lr=0.05, iterations=20, samples=16, alpha=100.0, feasibility_floor=1e-6, seed=0)
SEQUENCE = ("move", "cut", "move", "move", "cut", "move")


@pytest.fixture(scope="module")
def rhp_plan():
    goal = PRIOR.sample((4,), torch.Generator().manual_seed(5))
    return plan_receding_horizon_with(FUNCTIONS, OBS, goal, SEQUENCE, 3, SETTINGS)


def test_receding_horizon_plan_has_horizon_six_and_its_steps_chain(rhp_plan):
    assert rhp_plan.skills == SEQUENCE
    assert len(rhp_plan.attention) == len(rhp_plan.feasibilities) == 6
    assert [u.shape[0] for u in rhp_plan.latent_sets] == [2, 2, 3, 3, 3, 4, 4]
    torch.testing.assert_close(rhp_plan.latent_sets[0], OBS)
    n_out = {"move": 1, "cut": 2}
    for h, skill in enumerate(SEQUENCE, start=1):
        before, after = rhp_plan.latent_sets[h - 1], rhp_plan.latent_sets[h]
        attended = rhp_plan.attention[h - 1]
        assert len(attended) == 1
        kept = [i for i in range(before.shape[0]) if i not in attended]
        torch.testing.assert_close(after[n_out[skill]:], before[kept])  # U^h = [new, kept of U^{h-1}]
    assert all(0.0 <= f <= 1.0 for f in rhp_plan.feasibilities)
    assert rhp_plan.planning_time_s > 0


def test_receding_horizon_is_seeded(rhp_plan):
    goal = PRIOR.sample((4,), torch.Generator().manual_seed(5))
    again = plan_receding_horizon_with(FUNCTIONS, OBS, goal, SEQUENCE, 3, SETTINGS)
    assert again.attention == rhp_plan.attention
    for a, b in zip(again.latent_sets, rhp_plan.latent_sets, strict=True):
        torch.testing.assert_close(a, b)


def test_receding_horizon_rejects_bad_windows_and_sequences():
    goal = PRIOR.sample((4,), torch.Generator().manual_seed(5))
    with pytest.raises(ValueError, match="window must be >= 1, got 0"):
        plan_receding_horizon_with(FUNCTIONS, OBS, goal, SEQUENCE, 0, SETTINGS)
    with pytest.raises(KeyError, match="'spread'"):
        plan_receding_horizon_with(FUNCTIONS, OBS, goal, ("move", "spread"), 3, SETTINGS)


def test_warm_started_windows_continue_the_first_windows_plan():
    """One sample and no Adam step per window: with the warm start every later window holds only the
    previous window's plan, so the receding plan is exactly the first window's six-step plan."""
    goal = PRIOR.sample((4,), torch.Generator().manual_seed(5))
    single = PlanSettings(lr=0.05, iterations=1, samples=1, alpha=100.0, feasibility_floor=1e-6, seed=3)
    first = describe(FUNCTIONS, optimise(FUNCTIONS, OBS, goal, [resolve_sequence(FUNCTIONS.skills, SEQUENCE, 2)],
                                         single, torch.Generator().manual_seed(3), torch.device("cpu")))
    warm = plan_receding_horizon_with(FUNCTIONS, OBS, goal, SEQUENCE, 6, single, warm_start=True)
    assert warm.attention == first.attention
    for a, b in zip(warm.latent_sets, first.latent_sets, strict=True):
        torch.testing.assert_close(a, b)
    cold = plan_receding_horizon_with(FUNCTIONS, OBS, goal, SEQUENCE, 6, single)
    assert not torch.allclose(cold.latent_sets[-1], first.latent_sets[-1])


def test_warm_start_keeps_the_plan_chained():
    goal = PRIOR.sample((4,), torch.Generator().manual_seed(5))
    warm = plan_receding_horizon_with(FUNCTIONS, OBS, goal, SEQUENCE, 3, SETTINGS, warm_start=True)
    assert [u.shape[0] for u in warm.latent_sets] == [2, 2, 3, 3, 3, 4, 4]
    for h in range(1, 7):
        attended = warm.attention[h - 1]
        kept = [i for i in range(warm.latent_sets[h - 1].shape[0]) if i not in attended]
        n_out = warm.latent_sets[h].shape[0] - len(kept)
        torch.testing.assert_close(warm.latent_sets[h][n_out:], warm.latent_sets[h - 1][kept])
