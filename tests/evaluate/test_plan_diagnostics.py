"""Plan diagnostics: a known plan against wrong ones on the analytic planning problem, the verdict, the metrics,
and the ground-truth chain written as a plan from a real evaluation problem."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from pasta.config import load
from pasta.data.configurations import evaluation_problem, oracle_chain
from pasta.evaluate.encoding import encode_scene
from pasta.evaluate.ground_truth import GroundTruthPlan, ground_truth_plan
from pasta.evaluate.metrics import plan_quality_metrics
from pasta.evaluate.plan_diagnostics import (
    NETWORKS_WRONG,
    OPTIMISER_FAILED,
    SCORES_TIE,
    diagnose,
    diagnostics_row,
    plan_objective,
    verdict,
)
from pasta.evaluate.problem import evaluate_problem
from pasta.plan import Plan, PlanSettings, plan_with
from tests.evaluate.conftest import FAST
from tests.plan.analytic import FUNCTIONS, GOAL, HALF_AT_STATION, HALF_MOVED, OBS, P, R

SETTINGS = PlanSettings(lr=0.05, iterations=20, samples=32, alpha=10.0)
# Each entity decodes to four points around its centre t.
SPREAD = np.array([[0.02, 0, 0], [-0.02, 0, 0], [0, 0, 0.02], [0, 0, -0.02]], np.float32)
P_AT_STATION = [0.0, 0.0, 0.2, 0.1, 0.3]
HALF_PLUS = HALF_AT_STATION  # the cut's first half (t_z + 0.1) stays at the station
HALF_MINUS = [-0.5, 0.0, 0.2, 0.1, 0.2]  # its second half (t_z - 0.1) is moved away


def decode(latents: torch.Tensor) -> np.ndarray:
    """``(K, 5)`` -> ``(K, 4, 3)``."""
    return latents[:, 2:].numpy()[:, None, :] + SPREAD


def sets(*rows: list[list[float]]) -> tuple[torch.Tensor, ...]:
    return tuple(torch.tensor(row) for row in rows)


# The unique best plan: move P to the station, cut it, move the second half away. Its objective is 0.
TRUE_SETS = sets([R, P], [P_AT_STATION, R], [HALF_PLUS, HALF_MINUS, R], [HALF_MOVED, HALF_PLUS, R])
TRUTH = GroundTruthPlan(("move", "cut", "move"), ((1,), (0,), (1,)), TRUE_SETS,
                        tuple(decode(u).reshape(-1, 3) for u in TRUE_SETS[1:]))


def hand_plan(skills: tuple[str, ...], attention: tuple[tuple[int, ...], ...],
              latent_sets: tuple[torch.Tensor, ...]) -> Plan:
    score = plan_objective(FUNCTIONS, SETTINGS, skills, attention, latent_sets, GOAL)
    return Plan(skills, attention, latent_sets, (), math.nan, score, 0.0)


def diagnosed(plan: Plan):
    return diagnose(plan, TRUTH, FUNCTIONS, SETTINGS, GOAL, decode, seed=0)


def test_the_ground_truth_plan_is_not_flagged():
    found = diagnosed(hand_plan(TRUTH.skills, TRUTH.attention, TRUE_SETS))
    assert found.sequence_match and found.attention_match
    assert found.attention_in_ground_truth == TRUTH.attention
    assert found.subgoal_emd == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert found.ground_truth_score == pytest.approx(0.0, abs=1e-9) == found.plan_score
    assert found.verdict == SCORES_TIE


def test_later_steps_compare_attention_by_entity_centre_not_by_position():
    """The cut's halves in the other order: the last move attends position 0, which is the ground truth's
    position 1 (the half moved away)."""
    swapped = sets([R, P], [P_AT_STATION, R], [HALF_MINUS, HALF_PLUS, R], [HALF_MOVED, HALF_PLUS, R])
    found = diagnosed(hand_plan(TRUTH.skills, ((1,), (0,), (0,)), swapped))
    assert found.attention_match and found.attention_in_ground_truth == ((1,), (0,), (1,))
    assert found.plan_score < 0.0  # the halves do not come out of the cut in this order: lower feasibility
    assert found.verdict == OPTIMISER_FAILED


def test_a_plan_that_attends_the_wrong_piece_is_flagged():
    """The right skills, but the first move takes the distractor R to the station, and the cut cuts it."""
    r_at_station = [1.0, 0.0, 0.2, 0.1, 0.3]
    r_plus, r_minus = [0.5, 0.0, 0.2, 0.1, 0.4], [0.5, 0.0, 0.2, 0.1, 0.2]
    wrong = sets([R, P], [r_at_station, P], [r_plus, r_minus, P], [[0.5, 0.0, 0.8, 0.1, 0.2], r_plus, P])
    found = diagnosed(hand_plan(TRUTH.skills, ((0,), (0,), (1,)), wrong))
    assert found.sequence_match and not found.attention_match
    assert found.attention_in_ground_truth[0] == (0,)
    assert found.subgoal_emd[0] > 0.05
    assert found.verdict == OPTIMISER_FAILED  # the analytic objective is right: the truth scores higher


def test_a_plan_in_the_wrong_skill_order_is_flagged():
    """Cut P where it lies, then move a half to the station and the other away."""
    p_plus, p_minus = [-0.5, 0.0, 0.8, 0.1, 0.4], [-0.5, 0.0, 0.8, 0.1, 0.2]
    wrong = sets([R, P], [p_plus, p_minus, R], [HALF_PLUS, p_minus, R], [HALF_MOVED, HALF_PLUS, R])
    found = diagnosed(hand_plan(("cut", "move", "move"), ((1,), (0,), (1,)), wrong))
    assert not found.sequence_match and not found.attention_match
    assert found.subgoal_emd[-1] == pytest.approx(0.0, abs=1e-9)  # it ends where the truth does
    assert found.plan_score < found.ground_truth_score
    assert found.verdict == OPTIMISER_FAILED


def test_the_objective_of_a_plan_is_the_planners_own_score():
    found = plan_with(FUNCTIONS, OBS, GOAL, 3, SETTINGS)
    value = plan_objective(FUNCTIONS, SETTINGS, found.skills, found.attention, found.latent_sets, GOAL)
    assert value == pytest.approx(found.score, abs=1e-5)


@pytest.mark.parametrize(("plan_score", "truth_score", "expected"), [
    (-3.0, -0.5, OPTIMISER_FAILED),  # the truth is better by the planner's own measure: the search missed it
    (0.0, -2.0, NETWORKS_WRONG),  # the networks prefer the plan to the truth
    (-1.0, -1.0 + 1e-9, SCORES_TIE),
])
def test_the_verdict_blames_the_optimiser_when_the_truth_scores_higher(plan_score, truth_score, expected):
    assert verdict(plan_score, truth_score) == expected


def test_plan_quality_metrics_count_an_unplanned_configuration_as_a_mismatch():
    right = diagnosed(hand_plan(TRUTH.skills, TRUTH.attention, TRUE_SETS))
    p_plus, p_minus = [-0.5, 0.0, 0.8, 0.1, 0.4], [-0.5, 0.0, 0.8, 0.1, 0.2]
    wrong_sets = sets([R, P], [p_plus, p_minus, R], [HALF_PLUS, p_minus, R], [HALF_MOVED, HALF_PLUS, R])
    wrong = diagnosed(hand_plan(("cut", "move", "move"), ((1,), (0,), (1,)), wrong_sets))
    rows = [{"config_id": i, "emd_planned_goal": emd, **diagnostics_row(d)}
            for i, (d, emd) in enumerate([(right, 0.01), (wrong, 0.03), (None, math.nan)])]
    metrics = plan_quality_metrics(rows)
    assert metrics["plan_sequence_match_rate"] == pytest.approx(1 / 3)
    assert metrics["plan_attention_match_rate"] == pytest.approx(1 / 3)
    assert metrics["plan_subgoal_emd"] == pytest.approx(wrong.mean_subgoal_emd / 2)  # the right plan's is 0
    assert metrics["plan_optimiser_failure_rate"] == pytest.approx(0.5)  # of the two planned configurations
    assert metrics["plan_sequence_match_config_0"] == 1.0 and metrics["plan_optimiser_failed_config_1"] == 1.0
    assert math.isnan(metrics["plan_score_config_2"]) and metrics["emd_planned_goal_config_1"] == 0.03


def test_the_ground_truth_chain_as_a_plan_tracks_pieces_by_particle(cfg, bundle):
    """CutRearrange: cut the one piece, then rearrange each half; the second rearrange acts on the half the
    first left alone, which ``U^2`` keeps after its new entity."""
    problem = evaluation_problem(cfg, 0)
    chain = oracle_chain(cfg, 0)
    m = cfg.sim.observation_points
    start = encode_scene(cfg, bundle, problem.initial.particles[:m], np.random.default_rng(0))
    truth = ground_truth_plan(cfg, bundle, chain, start, np.random.default_rng(1))
    assert truth.skills == problem.skill_sequence == ("cut", "rearrange", "rearrange")
    assert [u.shape[0] for u in truth.latent_sets] == [1, 2, 2, 2]
    assert truth.attention[0] == (0,) and truth.attention[2] == (1,)
    moved_first = truth.attention[1][0]
    left_alone = 1 - moved_first
    assert torch.equal(truth.latent_sets[2][1], truth.latent_sets[1][left_alone])
    assert torch.equal(truth.latent_sets[0], start.latents)
    for stage, step in zip(truth.stages, chain, strict=True):
        np.testing.assert_array_equal(stage, step.subgoal[:m])


def test_an_evaluated_learned_plan_carries_its_diagnostics_into_its_row(cfg, bundle):
    problem = evaluation_problem(cfg, 0)
    result = evaluate_problem(cfg, bundle, problem, 0, "policy", PlanSettings.from_config(cfg))
    found = result.diagnostics
    assert found.ground_truth_skills == problem.skill_sequence
    assert found.sequence_match == (result.skills == problem.skill_sequence)
    assert len(found.subgoal_emd) == cfg.horizon and np.isfinite([found.plan_score, found.ground_truth_score]).all()
    # The last stage is the goal: the last subgoal's EMD is the planned goal's.
    assert found.subgoal_emd[-1] == pytest.approx(result.emd_planned_goal)
    row = result.row()
    assert row["verdict"] == found.verdict and row["attention"] == [list(a) for a in result.attention]
    oracle = evaluate_problem(cfg, None, problem, 0, "scripted", PlanSettings.from_config(cfg), "oracle")
    assert oracle.diagnostics is None and "verdict" not in oracle.row()


def test_a_learned_plan_evaluated_with_carried_weights_measures_its_goal_by_the_plans_masses(bundle):
    cfg = load("CutRearrange", "smoke", [*FAST, "eval.decoded_entity_weights=carried"])
    result = evaluate_problem(cfg, bundle, evaluation_problem(cfg, 0), 0, "scripted", PlanSettings.from_config(cfg))
    assert np.isfinite(result.emd_planned_goal)
    assert result.diagnostics.subgoal_emd[-1] == pytest.approx(result.emd_planned_goal)
