"""The rolling pin's spread: press down to the target's thickness, then roll to and fro without
slipping about the target's centre.
"""

from __future__ import annotations

import numpy as np

from pasta.data.skills.motion import Motion
from pasta.data.skills.scene import Scene, extent, rotation, support
from pasta.sim.envs.base import DoughEnv, ToolPose

ROLL_CLEARANCE = 0.01  # the rolling pin starts this far above the dough
PIN_GAP_CELLS = 1.5  # the rolling pin stops this many grid cells above a static support (the board)
ROLL_SPAN = 0.2  # the rolling pin rolls over this fraction of the target's half length each side
PRESS_OVERSHOOT = 0.01  # the pin presses this far below the target's top (the dough springs back up) ...
PRESS_OVERSHOOT_SHARE = 0.25  # ... or this share of the target's thickness where that is less
ROLL_ONLY_SPEED = 0.15  # roll action of a pin without a slide action (its bottom slips at twice its speed)


def _pin_frame(rot) -> np.ndarray:
    """Horizontal unit direction a rolling pin travels in when it rolls forward."""
    axis = rotation(rot) @ np.array([0.0, 0.0, 1.0])
    direction = np.cross([0.0, 1.0, 0.0], axis)
    return direction / max(float(np.linalg.norm(direction)), 1e-9)


def spread_start(env: DoughEnv, tool_name: str, scene: Scene) -> ToolPose:
    tool = env.tool(tool_name)
    current = env.tool_poses()[tool_name]
    centre = scene.centre
    y = max(scene.top + tool.radius + ROLL_CLEARANCE, tool.lower_bound[1])
    return ToolPose(pos=(centre[0], y, centre[2]), rot=current.rot)


def spread(env: DoughEnv, m: Motion, scene: Scene) -> None:
    """Press straight down to the target's thickness, then roll to and fro about the target's centre.

    The pin's bottom goes to the dough's support height plus the target's thickness, less
    ``PRESS_OVERSHOOT`` (at grid 48 it raised the median of single-skill spreads from 0.44 to 0.51 on
    LiftSpread and from 0.49 to 0.52 on CRS), or less a quarter of a thinner target's thickness (a
    0.017 target at grid 32 pressed 0.01 deeper squirts the dough out: 0.4 -> -0.07). The to-and-fro
    spans ``ROLL_SPAN`` of the target's half length on each side of its centre and rolls without
    slipping: with RollingPinExt kinematics (env_spec 1.5) a roll action alone moves the pin's bottom
    at twice the pin's speed, which flings the dough ahead, so the roll (a0) is combined with a slide
    (a3) that cancels the slip. Wide passes push the dough out of the target instead of flattening
    it (measured at grids 32 and 48: pressing does most of the spreading).
    """
    tool = m.tool
    r = tool.radius
    direction = _pin_frame(m.rot)
    goal = scene.destination if scene.destination is not None else scene.attended
    g_lo, g_hi = extent(goal[:, 1])
    thickness = max(g_hi - g_lo, 1e-3)
    overshoot = min(PRESS_OVERSHOOT, PRESS_OVERSHOOT_SHARE * thickness)
    press_y = max(scene.bottom + thickness + r - overshoot, tool.lower_bound[1])
    centre = scene.centre
    support_height, on_tool = support(env, centre[0], centre[2])
    if on_tool:
        # Dough squeezed into less than a grid cell between the pin and a static tool (the
        # cutting board) is thrown out of the gap, and the simulation can blow up.
        press_y = max(press_y, support_height + PIN_GAP_CELLS / env.cfg.sim.n_grid + r)
    origin = m.pos.copy()
    s_lo, s_hi = extent((goal - origin) @ direction)
    mid, half = 0.5 * (s_lo + s_hi), 0.5 * (s_hi - s_lo)
    ends = (mid - ROLL_SPAN * half, mid + ROLL_SPAN * half)
    roll_scale, lift_scale, slide_scale = m.scales[0] * r, m.scales[2], m.scales[3]
    # Without slipping the pin moves at most half the slide speed; without a slide it rolls slowly.
    speed = 0.5 * slide_scale if slide_scale > 0 else ROLL_ONLY_SPEED * roll_scale
    if speed <= 0:
        return

    def lift_action() -> float:
        return float(np.clip((press_y - m.pos[1]) / lift_scale, -1.0, 1.0)) if lift_scale > 0 else 0.0

    while m.left > 0 and lift_scale > 0 and abs(press_y - m.pos[1]) > 1e-5:
        action = np.zeros(len(m.scales))
        action[2] = lift_action()
        m.step(action)
    s = float((m.pos - origin) @ direction)
    k = 0 if abs(ends[0] - s) <= abs(ends[1] - s) else 1
    while m.left > 0 and ends[1] - ends[0] > 1e-4:
        s = float((m.pos - origin) @ direction)
        if abs(ends[k % 2] - s) < 1e-5:
            k += 1
            continue
        v = float(np.clip(ends[k % 2] - s, -speed, speed))
        action = np.zeros(len(m.scales))
        if slide_scale > 0:  # no slip: roll by -v / r and slide by 2 v
            action[0] = -v / roll_scale if roll_scale > 0 else 0.0
            action[3] = (v - action[0] * roll_scale) / slide_scale
        else:
            action[0] = v / roll_scale
        action[2] = lift_action()
        m.step(action)
