"""The box pusher's push: from behind the piece along the line between the centres of mass.

The pusher brakes at the end over the steps ground friction needs to stop the dough with it
(:func:`~pasta.data.skills.motion.braking_steps`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pasta.config.schema import ToolConfig
from pasta.data.skills.motion import Motion, braking_steps
from pasta.data.skills.scene import (
    CLEARANCE,
    EXTENT_PERCENTILES,
    Scene,
    half_plate_turn,
    world_half_y,
    yaw_quat,
)
from pasta.sim.envs.base import DoughEnv, ToolPose
from pasta.sim.tool_points import world_sdf

PUSH_SINK = 0.005  # the pusher's bottom sits this far below the dough's bottom
STRAY_SHARE = 0.005  # a start pose may hold this share of the dough's particles (a smear left by a cut)
SMEAR_LIFT = 0.03  # how far the pusher may start above its pushing height to clear a floor smear between pieces
SMEAR_LIFT_STEP = 0.005


@dataclass(frozen=True)
class _PushLine:
    start: np.ndarray  # pusher centre (3,) at contact height behind the dough, before the push
    end: np.ndarray  # pusher centre (3,) when the dough's centre has reached the target's
    yaw: float  # plate heading facing the push direction
    direction: np.ndarray  # unit (3,) horizontal push direction
    back: float  # extent of the dough behind its centre, along the push direction


def _push_line(tool: ToolConfig, scene: Scene, direction: np.ndarray | None, yaw: float | None = None
               ) -> _PushLine | None:
    """Geometry of a push along ``direction`` (None: towards the destination's centre of mass)."""
    centre = scene.centre
    if direction is None:
        goal = scene.destination
        if goal is None:
            return None
        delta = goal.mean(axis=0) - centre
        delta[1] = 0.0
        distance = float(np.linalg.norm(delta))
        if distance < 1e-3:
            return None
        u = delta / distance
    else:
        u = np.asarray(direction, dtype=np.float64)
        distance = 0.0
    face_yaw = math.atan2(-u[2], u[0])
    yaw = half_plate_turn(face_yaw) if yaw is None else yaw
    off = half_plate_turn(yaw - face_yaw)
    hx, hy, hz = tool.half_extents
    half_along = hx * abs(math.cos(off)) + hz * abs(math.sin(off))
    rel = scene.attended - centre
    back = float(np.percentile(-(rel @ u), EXTENT_PERCENTILES[1]))
    y = scene.bottom - PUSH_SINK + hy
    start = centre - u * (back + half_along + CLEARANCE)
    start[1] = y
    end = centre + u * (distance - back - half_along)
    end[1] = y
    return _PushLine(start=start, end=end, yaw=yaw, direction=u, back=back)


def push_start(env: DoughEnv, tool_name: str, scene: Scene) -> ToolPose:
    tool = env.tool(tool_name)
    line = _push_line(tool, scene, None)
    if line is None:  # no target: the +x side, facing -x (env_spec 2.5)
        line = _push_line(tool, scene, np.array([-1.0, 0.0, 0.0]), yaw=0.0)
    rot = yaw_quat(line.yaw)

    def clear(pos: np.ndarray) -> bool:
        inside = world_sdf(tool, scene.points, tuple(pos), rot, 0.0) < 0.0
        return bool(inside.sum() <= STRAY_SHARE * len(scene.points))

    for extra in np.arange(0.0, 0.1, 0.01):  # back off until (nearly) clear of the dough
        pos = line.start - line.direction * extra
        if clear(pos):
            return ToolPose(pos=tuple(pos), rot=rot)
    # A cut can leave the pieces' feet nearly touching on the floor while their bodies stand well apart: start
    # in the gap just above the feet rather than over all of the dough, where a push meets nothing.
    for lift in np.arange(SMEAR_LIFT_STEP, SMEAR_LIFT + 1e-9, SMEAR_LIFT_STEP):
        pos = line.start + np.array([0.0, lift, 0.0])
        if clear(pos):
            return ToolPose(pos=tuple(pos), rot=rot)
    raised = line.start - line.direction * 0.09
    raised[1] = scene.top_all + tool.half_extents[1] + CLEARANCE
    return ToolPose(pos=tuple(raised), rot=rot)


def push(env: DoughEnv, m: Motion, scene: Scene) -> None:
    """From behind the piece (approaching over the dough if the pusher is elsewhere) push along the
    line between the centres of mass until the piece's centre is at the target's; brake at the end."""
    tool = m.tool
    line = _push_line(tool, scene, None, yaw=m.yaw)
    if line is None:
        return
    rel = m.pos - scene.centre
    along = float(rel @ line.direction)
    across = float(np.linalg.norm(rel - along * line.direction - rel[1] * np.array([0.0, 1.0, 0.0])))
    hx, hy, hz = tool.half_extents
    behind = (along < -line.back - 0.5 * hx and across < 0.5 * hz
              and -0.02 < m.pos[1] - line.start[1] < SMEAR_LIFT + 0.02)
    if not behind:  # approach: up, over the start (turning towards the target meanwhile), down
        safe_y = scene.top_all + world_half_y(tool, m.rot) + CLEARANCE
        if m.pos[1] < safe_y:
            m.move(pos=(m.pos[0], safe_y, m.pos[2]))
        aligned = _push_line(tool, scene, None)
        travel = np.abs((aligned.start - m.pos)[[0, 2]]) / np.maximum(m.scales[[0, 2]], 1e-9)
        max_turn = math.ceil(float(travel.max())) * m.scales[4]  # turn only while travelling
        turn = float(np.clip(half_plate_turn(aligned.yaw - m.yaw), -max_turn, max_turn))
        line = _push_line(tool, scene, None, yaw=m.yaw + turn)
        m.move(pos=(line.start[0], safe_y, line.start[2]), yaw=m.yaw + turn)
        m.move(pos=line.start)
        line = _push_line(tool, scene, None, yaw=m.yaw)
    distance = float(np.linalg.norm((line.end - m.pos)[[0, 2]]))
    m.move(pos=line.end, ease=2, ease_out=braking_steps(env, distance, max(tool.action_scales[:3])))
