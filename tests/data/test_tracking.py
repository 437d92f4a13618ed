"""The tracking expert (pasta.data.skills.tracking): on the scripted path it is the script; off it, it steers back."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.data.skills import place_tool_for_skill, scripted_actions, skill_tool
from pasta.data.skills.tracking import scripted_path, tracking_actions
from tests.data.test_skills import env_for, push_problem, rearrange_problem, spread_problem


def _on_path_gap(env, skill: str, target: np.ndarray, attention) -> float:
    """Largest difference between the expert's action and the script's at every step of a scripted run."""
    tool = skill_tool(env.cfg, skill).name
    place_tool_for_skill(env, skill, attention, target)
    actions = scripted_actions(env, skill, target, attention)
    path = scripted_path(env, tool, actions)
    worst = 0.0
    for k, action in enumerate(actions):
        expert = tracking_actions(env, path, k, 3)
        ahead = actions[k : k + 3]
        worst = max(worst, float(np.abs(expert[: len(ahead)] - ahead).max()))
        env.step(action)
    return worst


@pytest.mark.parametrize("problem", [rearrange_problem, push_problem, spread_problem])
def test_on_the_scripted_path_the_expert_acts_as_the_script(problem):
    """Gripper (position, gap), box (position, heading) and rolling pin (lift, slide): where the simulated tool
    follows the script, the expert's chunk is the script's next actions."""
    env, target, attention = problem()
    skill = {rearrange_problem: "rearrange", push_problem: "push", spread_problem: "spread"}[problem]
    assert _on_path_gap(env, skill, target, attention) < 2e-3


def test_off_the_path_the_expert_steers_back_and_then_follows():
    """A gripper put 3.5 full steps off in x and half a step in z: the expert closes the x offset at full speed
    (the script's action plus the offset left, clipped), the z offset at once, and then moves as the script."""
    env, target, attention = rearrange_problem()
    tool = "gripper"
    place_tool_for_skill(env, "rearrange", attention, target)
    own = env.tool_action_slice(tool)
    script = scripted_actions(env, "rearrange", target, attention)[:, own]
    path = scripted_path(env, tool, scripted_actions(env, "rearrange", target, attention))
    pose = env.tool_poses()[tool]
    offset = np.array([3.5, 0.0, -0.5])  # in full steps (action units) of each dimension
    env.teleport_tool(tool, tuple(np.asarray(pose.pos) + offset * np.asarray(env.tool(tool).action_scales[:3])),
                      pose.rot, pose.gap)
    expert = tracking_actions(env, path, 0, 8)[:, own]
    left = offset.copy()
    for k in range(8):
        wanted = np.clip(script[k, :3] - left, -1.0, 1.0)
        np.testing.assert_allclose(expert[k, :3], wanted, atol=1e-4)
        left += wanted - script[k, :3]
    np.testing.assert_allclose(left, 0.0, atol=1e-4)  # back on the path within the chunk
    np.testing.assert_allclose(expert[:, 3:], script[:8, 3:], atol=1e-4)  # the gap was on its path all along
    assert expert[0, 0] == pytest.approx(-1.0)


def test_after_the_path_the_expert_stops_and_bad_requests_are_refused():
    env = env_for("CutRearrange")
    with pytest.raises(ValueError, match="shape"):
        scripted_path(env, "gripper", np.zeros((4, env.action_dim + 1)))
    path = scripted_path(env, "gripper", np.zeros((4, env.action_dim)))
    assert not tracking_actions(env, path, 4, 3).any()
    with pytest.raises(ValueError, match="step"):
        tracking_actions(env, path, -1, 3)
