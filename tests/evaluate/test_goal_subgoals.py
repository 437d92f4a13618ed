"""The goal's own pieces handed to the entities a plan finishes (``eval.final_subgoals: goal``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pasta.evaluate.encoding import EncodedScene
from pasta.evaluate.goal_subgoals import final_rows, goal_subgoals, step_subgoals
from pasta.plan.result import Plan

LATENT = 2  # latent width of these hand-made sets: u = [z (2), t (3)]


def entity(centre: tuple[float, float, float], z: float = 0.0) -> torch.Tensor:
    return torch.tensor([z, -z, *centre])


def crs_plan(final: list[torch.Tensor]) -> Plan:
    """cut, push the cut's first piece, spread the pushed one: U^3 = [spread, the cut's second piece]."""
    u0 = torch.stack([entity((0.5, 0.05, 0.5))])
    u1 = torch.stack([entity((0.4, 0.05, 0.5)), entity((0.6, 0.05, 0.5))])  # the cut's two pieces
    u2 = torch.stack([entity((0.3, 0.05, 0.5)), u1[1]])  # pushed [0], kept [1]
    u3 = torch.stack(final)
    return Plan(skills=("cut", "push", "spread"), attention=((0,), (0,), (0,)), latent_sets=(u0, u1, u2, u3),
                feasibilities=(1.0, 1.0, 1.0), cost=0.0, score=0.0, planning_time_s=0.0)


def two_piece_goal() -> tuple[EncodedScene, np.ndarray]:
    """A goal of two pieces, 30 and 50 points, around x = 0.3 and x = 0.6 (label 0 is the one at 0.6)."""
    rng = np.random.default_rng(0)
    right = rng.normal((0.6, 0.05, 0.5), 0.01, (30, 3))
    left = rng.normal((0.3, 0.04, 0.5), 0.01, (50, 3))
    points = np.concatenate([right, left]).astype(np.float32)
    labels = np.array([0] * 30 + [1] * 50)
    latents = torch.stack([entity(tuple(right.mean(0)), z=1.0), entity(tuple(left.mean(0)), z=2.0)]).float()
    return EncodedScene(latents=latents, labels=labels, entities=np.zeros((2, 1, 3), np.float32)), points


def test_final_rows_follow_each_new_entity_to_the_last_set():
    plan = crs_plan([entity((0.3, 0.04, 0.5)), entity((0.6, 0.05, 0.5))])
    # the cut's pieces are attended later (push takes [0]; the spread takes the pushed one, kept [1] is the cut's
    # second piece, which survives): spread's new entity is row 0, the cut's second piece row 1
    assert final_rows(plan) == {(3, 0): 0, (1, 1): 1}


def test_each_finished_entity_is_handed_the_goal_piece_nearest_its_planned_centre():
    plan = crs_plan([entity((0.32, 0.05, 0.5)), entity((0.58, 0.05, 0.5))])
    goal, points = two_piece_goal()
    handed = goal_subgoals(plan, goal, points)
    assert set(handed) == {(3, 0), (1, 1)}, "the cut's first piece is pushed later: it has no goal piece"
    np.testing.assert_array_equal(handed[(3, 0)].points, points[30:])  # the spread piece: the left goal piece
    np.testing.assert_array_equal(handed[(1, 1)].points, points[:30])
    torch.testing.assert_close(handed[(3, 0)].latent, goal.latents[1])
    torch.testing.assert_close(handed[(1, 1)].latent, goal.latents[0])


def test_a_step_mixing_goal_pieces_and_decoded_entities_conserves_the_attended_dough():
    goal, points = two_piece_goal()
    handed = goal_subgoals(crs_plan([entity((0.32, 0.05, 0.5)), entity((0.58, 0.05, 0.5))]), goal, points)
    decoded = np.random.default_rng(1).normal(size=(2, 100, 3)).astype(np.float32)
    cut = step_subgoals(decoded, [None, handed[(1, 1)]], attended_points=80, rng=np.random.default_rng(0))
    assert cut.shape == (80, 3), "the decoded piece holds the 50 attended points the goal's 30-point piece leaves"
    assert {tuple(p) for p in cut[:50]} <= {tuple(p) for p in decoded[0]} and len({tuple(p) for p in cut[:50]}) == 50
    np.testing.assert_array_equal(cut[50:], points[:30])
    nearly_all = step_subgoals(decoded, [None, handed[(1, 1)]], attended_points=35, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(nearly_all, decoded.reshape(-1, 3))  # 5 points left: the decoded clouds stay
    whole = step_subgoals(decoded[:1], [handed[(3, 0)]], attended_points=7, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(whole, points[30:])
    np.testing.assert_array_equal(step_subgoals(decoded, [None, None], 80, np.random.default_rng(0)),
                                  decoded.reshape(-1, 3))
    with pytest.raises(ValueError, match="1 handed pieces for 2 decoded new entities"):
        step_subgoals(decoded, [None], 80, np.random.default_rng(0))


def test_the_matching_is_one_to_one_over_the_whole_final_set():
    # both planned centres lie nearer the right piece; the one-to-one matching gives the left piece to the spread's
    plan = crs_plan([entity((0.50, 0.05, 0.5)), entity((0.60, 0.05, 0.5))])
    goal, points = two_piece_goal()
    np.testing.assert_array_equal(goal_subgoals(plan, goal, points)[(3, 0)].points, points[30:])
    np.testing.assert_array_equal(goal_subgoals(plan, goal, points)[(1, 1)].points, points[:30])
    swapped = crs_plan([entity((0.60, 0.05, 0.5)), entity((0.50, 0.05, 0.5))])
    np.testing.assert_array_equal(goal_subgoals(swapped, goal, points)[(3, 0)].points, points[:30])


def test_an_entity_with_no_goal_piece_left_keeps_its_decoded_subgoal():
    goal, points = two_piece_goal()
    one_piece = EncodedScene(latents=goal.latents[1:], labels=np.zeros(50, np.int64), entities=goal.entities[1:])
    matched_to_the_spread = crs_plan([entity((0.30, 0.05, 0.5)), entity((0.60, 0.05, 0.5))])
    np.testing.assert_array_equal(goal_subgoals(matched_to_the_spread, one_piece, points[30:])[(3, 0)].points,
                                  points[30:])
    one_step = Plan(skills=("cut",), attention=((0,),), latent_sets=(torch.stack([entity((0.5, 0.05, 0.5))]),
                    torch.stack([entity((0.3, 0.05, 0.5)), entity((0.6, 0.05, 0.5))])),
                    feasibilities=(1.0,), cost=0.0, score=0.0, planning_time_s=0.0)
    assert set(goal_subgoals(one_step, one_piece, points[30:])) == {(1, 0)}, "the right piece has no goal piece left"
    assert set(goal_subgoals(one_step, goal, points)) == {(1, 0), (1, 1)}


def test_goal_points_that_are_not_the_encoded_cloud_are_refused():
    plan = crs_plan([entity((0.30, 0.05, 0.5)), entity((0.60, 0.05, 0.5))])
    goal, points = two_piece_goal()
    with pytest.raises(ValueError, match=r"\(80, 3\) cloud the goal was encoded from, got \(79, 3\)"):
        goal_subgoals(plan, goal, points[:79])
