from __future__ import annotations

import dataclasses

import pytest
import torch

from pasta.config import load
from pasta.plan import DEFAULT_HALVING, PlanSettings, enumerate_sequences, plan_with
from pasta.plan.optimiser import optimise
from tests.plan.analytic import BEST_SKILLS, FUNCTIONS, GOAL, OBS

SETTINGS = PlanSettings(lr=0.05, iterations=150, samples=200, alpha=10.0, feasibility_floor=1e-6, seed=0)


@pytest.fixture(scope="module")
def best_plan():
    return plan_with(FUNCTIONS, OBS, GOAL, 3, SETTINGS)


def _assert_optimal(plan):
    assert plan.skills == BEST_SKILLS
    assert plan.attention[0] == (1,)  # move P, not the distractor R
    assert plan.attention[1] == (0,)  # cut the moved P (new vectors come first)
    assert plan.attention[2] in {(0,), (1,)}  # move a half, not R (index 2)
    assert plan.score > -0.05
    assert plan.cost < 5e-3
    assert min(plan.feasibilities) > 0.95


def test_planner_finds_the_best_sequence_structure_and_optimum(best_plan):
    _assert_optimal(best_plan)
    sizes = [u.shape for u in best_plan.latent_sets]
    assert sizes == [(2, 5), (2, 5), (3, 5), (3, 5)]
    torch.testing.assert_close(best_plan.latent_sets[0], OBS)
    # The distractor R (first of U^0) is carried through untouched, last in every later set.
    for u in best_plan.latent_sets[1:]:
        torch.testing.assert_close(u[-1], OBS[0])
    assert best_plan.planning_time_s > 0


def test_successive_halving_keeps_the_optimum(best_plan):
    pruned = plan_with(FUNCTIONS, OBS, GOAL, 3, dataclasses.replace(SETTINGS, halving=DEFAULT_HALVING, min_survivors=8))
    _assert_optimal(pruned)
    assert pruned.score >= best_plan.score - 1e-3


def test_plans_are_seeded_and_chunking_does_not_change_them(best_plan):
    again = plan_with(FUNCTIONS, OBS, GOAL, 3, dataclasses.replace(SETTINGS, chunk_samples=128))
    assert again.skills == best_plan.skills and again.attention == best_plan.attention
    for a, b in zip(again.latent_sets, best_plan.latent_sets, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=0)


def test_explicit_sequences_restrict_the_search():
    plan = plan_with(FUNCTIONS, OBS, GOAL, 3, dataclasses.replace(SETTINGS, iterations=30, samples=8),
                     skill_sequences=[("cut", "move", "move")])
    assert plan.skills == ("cut", "move", "move")


def test_score_is_the_log_space_objective(best_plan):
    expected = sum(torch.tensor(best_plan.feasibilities).clamp_min(1e-6).log().tolist()) - 10.0 * best_plan.cost
    assert best_plan.score == pytest.approx(expected, abs=1e-5)


@pytest.mark.parametrize(
    ("obs", "goal", "kwargs", "match"),
    [
        (torch.zeros(2, 4), GOAL, {}, r"obs must have shape \(K, 5\), got \(2, 4\)"),
        (OBS, torch.zeros(0, 5), {}, r"goal must hold at least one entity, got shape \(0, 5\)"),
        (OBS, torch.zeros(9, 5), {}, r"takes 2 entities to 9 \(net change \+7\)"),
        (OBS, GOAL, {"skill_sequences": [("move", "spread", "move")]}, "'spread'"),
        (OBS, GOAL, {"skill_sequences": [("move", "cut")]}, "has length 2, horizon is 3"),
        (OBS, GOAL, {"skill_sequences": [("cut", "move", "move"), ("cut", "cut", "move")]},
         r"different entity counts \[3, 4\]"),
    ],
)
def test_bad_inputs_raise_naming_the_value(obs, goal, kwargs, match):
    small = dataclasses.replace(SETTINGS, iterations=2, samples=2)
    with pytest.raises((ValueError, KeyError), match=match):
        plan_with(FUNCTIONS, obs, goal, 3, small, **kwargs)


def test_settings_reject_bad_values():
    with pytest.raises(ValueError, match="halving must be increasing fractions in \\(0, 1\\), got \\(0.5, 0.2\\)"):
        dataclasses.replace(SETTINGS, halving=(0.5, 0.2))
    with pytest.raises(ValueError, match="samples must be >= 1, got 0"):
        dataclasses.replace(SETTINGS, samples=0)


@pytest.mark.gpu
def test_cuda_plan_matches_cpu(best_plan):
    plan = plan_with(FUNCTIONS, OBS, GOAL, 3, SETTINGS, device="cuda")
    assert plan.skills == best_plan.skills
    assert plan.score == pytest.approx(best_plan.score, abs=1e-3)


def test_halving_drops_the_worse_half_at_the_listed_iterations():
    sequences = enumerate_sequences(FUNCTIONS.skills, 3, 2, 3)
    settings = dataclasses.replace(SETTINGS, iterations=10, samples=32, halving=(0.2, 0.5), min_survivors=1)
    pruned = optimise(FUNCTIONS, OBS, GOAL, sequences, settings, torch.Generator().manual_seed(0), torch.device("cpu"))
    # 96 samples for iterations 0-1, 48 for 2-4, 24 for 5-9.
    assert pruned.sample_iterations == 2 * 96 + 3 * 48 + 5 * 24
    floor = dataclasses.replace(settings, min_survivors=60)
    kept = optimise(FUNCTIONS, OBS, GOAL, sequences, floor, torch.Generator().manual_seed(0), torch.device("cpu"))
    assert kept.sample_iterations == 2 * 96 + 8 * 60


def test_alpha_comes_from_the_config_or_the_official_default():
    assert PlanSettings.from_config(load("CutRearrange", "smoke", [])).alpha == 10.0
    assert PlanSettings.from_config(load("CRS", "smoke", [])).alpha == 100.0
    assert PlanSettings.from_config(load("CRS", "smoke", ["plan.alpha=1000"])).alpha == 1000.0
    with pytest.raises(ValueError, match="alpha"):
        load("CRS", "smoke", ["plan.alpha=-1"])
