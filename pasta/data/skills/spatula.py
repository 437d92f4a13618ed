"""The spatula's lift and move: from under the dough, lift above every support on the way, carry to
the target, lower onto the support there.

The carry is one smooth path over the whole remaining budget (:func:`carry_path`) so that the dough
neither takes off nor arrives late; both skills need the spatula's ``expel_rate`` at 0 (see the
measurements in :mod:`pasta.data.skills`).
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import ToolConfig
from pasta.data.skills.motion import Motion
from pasta.data.skills.scene import CLEARANCE, EXTENT_PERCENTILES, Scene, collides, support_y, world_half_y
from pasta.sim.envs.base import DoughEnv, ToolPose

SPATULA_CLEARANCE = 0.015  # the carrying spatula's bottom clears the highest support by this
SPATULA_EASE = 4  # steps over which the spatula speeds up and slows down (the dough must not take off)
# The carry of a placed spatula is one path over the whole remaining budget (measured on GatherMove's move
# at small: median 0.94 against 0.64 for separately eased lift, carry and lower segments, which ran out of
# steps): the rise eases (smoothstep) over CARRY_RISE_STEPS; the travel starts CARRY_TRAVEL_DELAY steps in
# with CARRY_TRAVEL_RAMP-step speed ramps and ends CARRY_END_MARGIN steps before the budget does; the
# descent onto the goal's support eases over CARRY_LOWER_STEPS ending at the same time.
CARRY_RISE_STEPS = 18
CARRY_TRAVEL_DELAY = 4
CARRY_TRAVEL_RAMP = 8
CARRY_LOWER_STEPS = 6
CARRY_END_MARGIN = 2


def _spatula_heights(env: DoughEnv, tool: ToolConfig, rot, scene: Scene, goal_centre: np.ndarray | None
                     ) -> tuple[float, float, float]:
    """(under-dough height, carrying height, height resting at the goal) of a spatula's centre."""
    half_y = world_half_y(tool, rot)
    under = scene.bottom - half_y - 0.002
    centre = scene.centre
    path = [centre] if goal_centre is None else [centre + t * (goal_centre - centre) for t in np.linspace(0, 1, 21)]
    highest = max(support_y(env, p[0], p[2]) for p in path)
    carry = max(highest, scene.bottom) + half_y + SPATULA_CLEARANCE
    rest = (support_y(env, goal_centre[0], goal_centre[2]) if goal_centre is not None else scene.bottom) + half_y
    return under, carry, rest


def spatula_start(env: DoughEnv, tool_name: str, scene: Scene) -> ToolPose:
    tool = env.tool(tool_name)
    current = env.tool_poses()[tool_name]
    under, _, _ = _spatula_heights(env, tool, current.rot, scene, None)
    centre = scene.centre
    for extra in np.arange(0.0, 0.03, 0.005):  # lower until clear of the dough
        pose = ToolPose(pos=(centre[0], max(under - extra, tool.lower_bound[1]), centre[2]), rot=current.rot)
        if not collides(tool, pose, scene.points):
            return pose
    return pose


def lift(env: DoughEnv, m: Motion, scene: Scene) -> None:
    """From under the dough (sliding in at floor level first if needed), lift above every support on
    the way, carry to the target's centre, lower onto the support there; every motion eased."""
    tool = m.tool
    goal = scene.destination
    goal_centre = goal.mean(axis=0) if goal is not None else None
    under, carry, rest = _spatula_heights(env, tool, m.rot, scene, goal_centre)
    centre = scene.centre
    # Already under the dough (at most a little lower than ``under``): lifting picks it up.
    below = (np.linalg.norm((m.pos - centre)[[0, 2]]) < 0.02
             and under - CLEARANCE - 0.05 <= m.pos[1] <= under + 0.005)
    if not below:  # slide in under the dough from the side the spatula is on, at floor level
        side = 1.0 if m.pos[0] >= centre[0] else -1.0
        half_x = float((np.abs(m.R) @ np.asarray(tool.half_extents))[0])
        reach = float(np.percentile(side * (scene.attended[:, 0] - centre[0]), EXTENT_PERCENTILES[1]))
        beside = centre[0] + side * (reach + half_x + CLEARANCE)
        safe_y = scene.top_all + world_half_y(tool, m.rot) + CLEARANCE
        if abs(m.pos[0] - beside) > 0.01:
            m.move(pos=(m.pos[0], max(m.pos[1], safe_y), m.pos[2]))
            m.move(pos=(beside, m.pos[1], centre[2]))
        m.move(pos=(beside, under, centre[2]))
        m.move(pos=(centre[0], under, centre[2]))
    if goal_centre is None:
        m.move(pos=(m.pos[0], carry, m.pos[2]), ease=SPATULA_EASE)
        return
    shift = goal_centre - centre
    end = m.pos + np.array([shift[0], 0.0, shift[2]])
    m.follow(carry_path(m.pos, end, carry, rest, m.left))


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _trapezoid_progress(n_steps: int, ramp: int) -> np.ndarray:
    """``(n_steps,)`` fraction of the way covered after each step, with linear speed ramps of ``ramp`` steps
    at both ends (shortened when the segment is short); ends at exactly 1."""
    ramp = max(0, min(ramp, (n_steps - 1) // 2))
    speed = np.ones(n_steps)
    if ramp:
        speed[:ramp] = np.arange(1, ramp + 1) / (ramp + 1)
        speed[n_steps - ramp:] = np.arange(ramp, 0, -1) / (ramp + 1)
    return np.cumsum(speed) / speed.sum()


def carry_path(start: np.ndarray, end: np.ndarray, carry_y: float, rest_y: float, n_steps: int) -> np.ndarray:
    """``(n_steps, 3)`` spatula centre after each step: rise from ``start`` to ``carry_y``, travel to ``end``'s
    x and z, and come down to ``rest_y`` at the goal (timings: the ``CARRY_*`` constants, scaled down when the
    budget is shorter than 50 steps)."""
    scale = min(1.0, n_steps / 50.0)
    rise = max(1, round(CARRY_RISE_STEPS * scale))
    delay = round(CARRY_TRAVEL_DELAY * scale)
    margin = round(CARRY_END_MARGIN * scale)
    lower = max(1, round(CARRY_LOWER_STEPS * scale))
    steps = np.arange(1, n_steps + 1, dtype=np.float64)
    path = np.repeat(np.asarray(start, dtype=np.float64)[None], n_steps, axis=0)
    travel_steps = max(1, n_steps - delay - margin)
    progress = np.zeros(n_steps)
    progress[delay:delay + travel_steps] = _trapezoid_progress(travel_steps, round(CARRY_TRAVEL_RAMP * scale))
    progress[delay + travel_steps:] = 1.0
    for axis in (0, 2):
        path[:, axis] = start[axis] + progress * (end[axis] - start[axis])
    lower_start = n_steps - margin - lower
    y = start[1] + _smoothstep(steps / rise) * (carry_y - start[1])
    down = _smoothstep((steps - lower_start) / lower)
    path[:, 1] = y + down * (rest_y - carry_y)
    return path
