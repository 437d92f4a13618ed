"""Aims and the aim search: an aim moves the destination the script reads, and the search keeps the best of
its rollouts, never one worse than the script's own, and leaves the environment where that rollout ended."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.data.aim_search import count_pieces, moved, search_aim
from pasta.data.skills import Aim, place_tool_for_skill, scripted_actions
from pasta.geometry.distances import earth_movers_distance
from tests.data.test_skills import push_problem


def test_the_identity_aim_leaves_the_pieces_alone():
    pieces = (np.random.default_rng(0).random((20, 3)),)
    assert Aim().apply(pieces) is pieces


def test_an_aim_scales_the_pieces_together_about_their_joint_centre_then_shifts_them():
    left = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]])
    right = np.array([[0.6, 0.0, 0.0], [0.8, 0.0, 0.0]])  # joint centre x = 0.4
    new_left, new_right = Aim(shift=(0.01, 0.0, 0.0), scale=(2.0, 1.0, 1.0)).apply((left, right))
    np.testing.assert_allclose(new_left[:, 0], [-0.39, 0.01])
    np.testing.assert_allclose(new_right[:, 0], [0.81, 1.21])  # the gap between them doubled too


@pytest.mark.parametrize("shift, scale", [((0.0, 0.0), (1.0, 1.0, 1.0)), ((0.0, np.nan, 0.0), (1.0, 1.0, 1.0)),
                                          ((0.0, 0.0, 0.0), (1.0, 0.0, 1.0))])
def test_a_malformed_aim_is_refused(shift, scale):
    with pytest.raises(ValueError, match="aim"):
        Aim(shift=shift, scale=scale)


def test_moving_an_aim_coordinate():
    aim = moved(moved(Aim(), "dx", 0.01), "sy", np.log(1.5))
    assert aim.shift == (0.01, 0.0, 0.0)
    assert aim.scale == pytest.approx((1.0, 1.5, 1.0))
    with pytest.raises(ValueError, match="'qx'"):
        moved(aim, "qx", 0.1)


def test_count_pieces_counts_separate_clusters():
    rng = np.random.default_rng(0)
    blob = rng.normal(0.0, 0.005, (200, 3))
    env, _, _ = push_problem()
    assert count_pieces(blob, env.cfg) == 1
    assert count_pieces(np.concatenate([blob, blob + (0.3, 0.0, 0.0)]), env.cfg) == 2


def _pushed_piece_x(aim: Aim | None) -> float:
    env, target, attention = push_problem()
    place_tool_for_skill(env, "push", attention, target, aim)
    for action in scripted_actions(env, "push", target, attention, aim=aim):
        env.step(action)
    return float(env.particles()[attention, 0].mean())


def test_an_aim_further_along_the_push_pushes_the_piece_further():
    # push_problem's piece travels +x towards x = 0.28; aimed 0.04 beyond, it must end further along.
    assert _pushed_piece_x(Aim(shift=(0.04, 0.0, 0.0))) > _pushed_piece_x(None) + 0.015


def test_the_search_keeps_its_best_rollout_and_never_loses_to_the_script():
    env, target, attention = push_problem()
    start = env.get_state()
    result = search_aim(env, "push", target, attention, budget=3, settle_steps=2)
    assert result.rollouts == 3
    assert result.emd <= result.emd_identity
    # The environment is where the best rollout ended, and that is the score it was given.
    np.testing.assert_array_equal(env.particles(), result.state["x"])
    assert earth_movers_distance(env.observation().dough_points, target[:1000], rng=0) == pytest.approx(result.emd)
    # With one rollout the search is the script itself, run from the same start.
    env.set_state(start)
    alone = search_aim(env, "push", target, attention, budget=1, settle_steps=2)
    assert alone.aim == Aim() and alone.rollouts == 1 and alone.emd == alone.emd_identity
    env.set_state(start)
    place_tool_for_skill(env, "push", attention, target)
    np.testing.assert_array_equal(alone.actions, scripted_actions(env, "push", target, attention))


def test_with_a_rest_the_search_scores_the_end_of_the_plan():
    env, target, attention = push_problem()
    far_goal = np.asarray(target[:1000], np.float64) + (0.0, 0.0, 0.2)
    calls = []

    def rest(env_after):
        calls.append(env_after.particles()[attention, 0].mean())
        return np.asarray(env_after.observation().dough_points), far_goal

    result = search_aim(env, "push", target, attention, budget=3, settle_steps=0, rest=rest)
    assert len(calls) == 3
    assert result.emd == pytest.approx(earth_movers_distance(env.observation().dough_points, far_goal, rng=0))
    with pytest.raises(ValueError, match="budget"):
        search_aim(env, "push", target, attention, budget=0, settle_steps=0)
