"""The scripted skills as an expert that can be asked at any state: bring the tool back onto the script's path.

A scripted skill is an open-loop path of its tool, computed once at the skill's start
(:func:`pasta.data.skills.scripted_actions`). A learned policy executing the same skill drifts off that path,
and the states it then sees are not in the demonstrations; DAgger (Ross et al., 2011) labels such states with
what an expert would do there. Replanning the script from a visited state is no such expert (a cut half done
would be planned again from the two pieces), so the expert here tracks the path planned at the skill's start:
at step ``k`` it moves the tool from wherever it is to the path's pose of step ``k + 1``, and so on for a chunk.

What is tracked, per tool kind (the other dimensions keep the script's own action):

=========== ===========================================================================
kind        tracked
=========== ===========================================================================
knife       position (actions 0-2)
box         position (0-2) and the heading about the vertical (4)
gripper     position (0-2) and the gap (6)
rolling pin height (lift, 2) and the position along the rolling direction (slide, 3,
            on top of the script's roll 0)
=========== ===========================================================================

Every action is clipped to [-1, 1], so a tool far off the path returns over several steps at full speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pasta.data.skills.motion import Motion
from pasta.data.skills.scene import half_plate_turn, rotation
from pasta.sim.envs.base import DoughEnv

__all__ = ["ScriptedPath", "scripted_path", "tracking_actions"]


@dataclass(frozen=True, eq=False)
class ScriptedPath:
    """A tool's scripted path: its actions and the poses they lead through.

    Attributes:
        tool: the tool's name.
        actions: ``(n, A_tool)`` float64 the script's actions of the tool (its slice of the full action).
        positions: ``(n + 1, 3)`` the tool's position before step 0, ..., after step ``n - 1``.
        yaws: ``(n + 1,)`` its heading about the vertical (radians).
        gaps: ``(n + 1,)`` its gap (0 for tools without one).
    """

    tool: str
    actions: np.ndarray
    positions: np.ndarray
    yaws: np.ndarray
    gaps: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)


def scripted_path(env: DoughEnv, tool_name: str, actions: np.ndarray) -> ScriptedPath:
    """The path of ``tool_name`` under the full ``(n, action_dim)`` ``actions`` from its current pose (the
    kinematic model the scripts plan with; the environment is not stepped)."""
    full = np.asarray(actions, dtype=np.float64)
    if full.ndim != 2 or full.shape[1] != env.action_dim:
        raise ValueError(f"actions must have shape (n, {env.action_dim}), got {full.shape}")
    own = full[:, env.tool_action_slice(tool_name)]
    motion = Motion(env, tool_name, len(own))
    positions, yaws, gaps = [motion.pos.copy()], [motion.yaw], [motion.gap]
    for action in own:
        motion.step(action)
        positions.append(motion.pos.copy())
        yaws.append(motion.yaw)
        gaps.append(motion.gap)
    return ScriptedPath(tool_name, own, np.asarray(positions), np.asarray(yaws), np.asarray(gaps))


def _tracking_step(motion: Motion, nominal: np.ndarray, position: np.ndarray, yaw: float, gap: float) -> np.ndarray:
    """The tool's action that takes ``motion``'s pose to (``position``, ``yaw``, ``gap``), starting from the
    script's action ``nominal`` for the dimensions that are not tracked."""
    action = np.array(nominal, dtype=np.float64)
    scales, tool = motion.scales, motion.tool
    delta = motion.clip_pos(position) - motion.pos

    def units(value: float, dim: int) -> float:
        return value / scales[dim] if scales[dim] > 0 else action[dim]

    if tool.kind == "rolling_pin":
        axis = rotation(motion.rot) @ np.array([0.0, 0.0, 1.0])
        direction = np.cross([0.0, 1.0, 0.0], axis)
        along = float(delta @ direction) - action[0] * scales[0] * tool.radius
        action[2] = units(float(delta[1]), 2)
        action[3] = units(along, 3)
    else:
        for i in range(3):
            action[i] = units(float(delta[i]), i)
        if tool.kind == "box":
            action[4] = units(half_plate_turn(yaw - motion.yaw), 4)
        elif tool.kind == "gripper":
            action[6] = units(motion.gap - gap, 6)
    return np.clip(action, -1.0, 1.0)


def tracking_actions(env: DoughEnv, path: ScriptedPath, step: int, horizon: int) -> np.ndarray:
    """The expert's ``(horizon, action_dim)`` float32 full actions at step ``step`` of the skill: from the tool's
    current pose back onto ``path`` (reaching its pose of step ``step + j + 1`` with action ``j`` where the
    action range allows), then along it; zero actions after the path's last step (the skill is over)."""
    if step < 0 or horizon < 1:
        raise ValueError(f"need step >= 0 and horizon >= 1, got step {step}, horizon {horizon}")
    motion = Motion(env, path.tool, horizon)
    out = np.zeros((horizon, env.action_dim), np.float32)
    own = env.tool_action_slice(path.tool)
    for j in range(horizon):
        k = step + j
        if k >= len(path):
            break
        action = _tracking_step(motion, path.actions[k], path.positions[k + 1], float(path.yaws[k + 1]),
                                float(path.gaps[k + 1]))
        motion.step(action)
        out[j, own] = action
    return out
