"""The oracle plan: the generator's own subgoals and attention, executed by the scripted skills or the policies."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.config import load
from pasta.data.configurations import evaluation_problem, oracle_chain
from pasta.evaluate.oracle import attended_components, check_plan_source
from pasta.evaluate.problem import evaluate_problem
from pasta.plan import PlanSettings
from tests.evaluate.conftest import FAST


def test_attended_components_take_the_pieces_most_of_whose_points_were_acted_on():
    labels = np.array([0, 0, 0, 0, 1, 1, 1, 1, 2, 2])
    acted = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)  # piece 0 mostly, one stray point in piece 1
    assert attended_components(labels, acted) == (0,)
    # No piece is mostly acted on: every piece holding an acted point.
    assert attended_components(labels, np.array([1, 0, 0, 0, 1, 0, 0, 0, 0, 0], bool)) == (0, 1)


def test_oracle_scripted_execution_needs_no_models_and_runs_the_chain(cfg):
    problem = evaluation_problem(cfg, 0)
    result = evaluate_problem(cfg, None, problem, 0, "scripted", PlanSettings.from_config(cfg), "oracle")
    assert result.plan_source == "oracle" and result.failure is None
    assert result.skills == problem.skill_sequence == ("cut", "rearrange", "rearrange")
    # The cut acts on the one piece; each rearrange on one of the two pieces it made, a different one each time.
    assert result.attention[0] == (0,)
    assert len(result.attention[1]) == 1 and len(result.attention[2]) == 1
    assert result.planning_time_s == 0.0 and result.emd_planned_goal == 0.0
    assert result.skipped == (False, False, False)
    chain = oracle_chain(cfg, 0)
    # Each frame after the initial one shows the chain's stage the skill aimed at (observation points).
    m = cfg.sim.observation_points
    for frame, step in zip(result.frames[1:4], chain, strict=True):
        np.testing.assert_array_equal(frame.dough_points, step.subgoal[:m])


def test_oracle_with_policies_needs_models(cfg, bundle):
    problem = evaluation_problem(cfg, 0)
    with pytest.raises(ValueError, match="needs trained models"):
        evaluate_problem(cfg, None, problem, 0, "policy", PlanSettings.from_config(cfg), "oracle")
    result = evaluate_problem(cfg, bundle, problem, 0, "policy", PlanSettings.from_config(cfg), "oracle")
    assert result.skills == problem.skill_sequence and np.isfinite(result.performance)


def test_unknown_plan_source_is_refused_by_name(cfg):
    with pytest.raises(ValueError, match="'dream'"):
        check_plan_source("dream")
    with pytest.raises(ValueError, match="'dream'"):
        evaluate_problem(load("CutRearrange", "smoke", list(FAST)), None, evaluation_problem(cfg, 0), 0, "scripted",
                         PlanSettings.from_config(cfg), "dream")


def test_an_aim_searched_oracle_scores_each_aim_on_the_goal_and_ends_no_worse_than_the_scripts(cfg, monkeypatch):
    import pasta.evaluate.execution as execution

    problem = evaluation_problem(cfg, 0)
    alone = evaluate_problem(cfg, None, problem, 0, "scripted", PlanSettings.from_config(cfg), "oracle")
    searched_cfg = load("CutRearrange", "smoke", [*FAST, "eval.aim_search_rollouts=3"])
    searches = []
    real_search = execution.search_aim

    def recording_search(env, skill, target, mask, budget, settle_steps, rest=None):
        result = real_search(env, skill, target, mask, budget, settle_steps, rest)
        searches.append((skill, budget, rest is not None, result))
        return result

    monkeypatch.setattr(execution, "search_aim", recording_search)
    searched = evaluate_problem(searched_cfg, None, problem, 0, "scripted", PlanSettings.from_config(searched_cfg),
                                "oracle")
    assert searched.failure is None
    # Every skill but the last is scored after the chain's remaining skills; the last on the goal itself.
    assert [(s, b, r) for s, b, r, _ in searches] == [("cut", 3, True), ("rearrange", 3, True),
                                                     ("rearrange", 3, False)]
    # The first search's identity rollout is the scripts' whole chain, so it scores their final EMD.
    assert searches[0][3].emd_identity == pytest.approx(alone.emd_final, rel=0.02)
    assert searched.emd_final <= alone.emd_final * 1.02
