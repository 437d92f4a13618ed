"""The gripper's skills, sharing its geometry: rearrange (grip, carry, let go) and gather (squeeze
the scattered dough to the target's width).

A gripper squeezing fast squirts dough through its fingers, so ``gather`` squeezes at ``GATHER_SPEED``.
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import ToolConfig
from pasta.data.skills.motion import Motion
from pasta.data.skills.scene import CLEARANCE, EXTENT_PERCENTILES, Scene, collides, rotation, world_half_y
from pasta.sim.envs.base import DoughEnv, ToolPose

FINGER_SINK = 0.005  # the gripper fingers' bottom sits this far below the dough's bottom
GRIP_MARGIN = 0.02  # open fingers keep this much room on each side of the piece
GRIP_SQUEEZE = 0.7  # a closed grip leaves this fraction of the piece's width between the fingers
# A gripper may start with its fingers this far into a piece wider than they open (half a cell at grid 48).
FINGER_PRESS = 0.01
# The carry speeds up and slows down over this many steps: starting and stopping at once leaves dough
# behind and throws the piece on (CutRearrange oracle at small: 0.828 -> 0.876, ease 6: 0.876, 8: 0.867).
REARRANGE_EASE = 4
GATHER_SPEED = 0.5  # fraction of full gap speed when squeezing (faster squirts dough through the fingers)
GATHER_SQUEEZE = 0.8  # a gather closes the fingers to this fraction of the target's width
GATHER_HOLD = 4  # steps the closed grip is held before the skill ends


def _gripper_frame(m_rot) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal unit vectors: the gripper's gap axis and the one across it."""
    axis = rotation(m_rot)[:, 0].copy()
    axis[1] = 0.0
    axis /= max(float(np.linalg.norm(axis)), 1e-9)
    return axis, np.cross([0.0, 1.0, 0.0], axis)


def _width_along(points: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> float:
    proj = (points - centre) @ axis
    return 2.0 * float(np.percentile(np.abs(proj), EXTENT_PERCENTILES[1]))


def _grip_geometry(tool: ToolConfig, rot, scene: Scene) -> tuple[float, float, float, float]:
    """(open gap, grip gap, grip height, safe height) of a gripper at rotation ``rot``."""
    axis, _ = _gripper_frame(rot)
    width = _width_along(scene.attended, scene.centre, axis)
    thick = 2.0 * tool.half_extents[0]
    open_gap = float(np.clip(width + thick + 2 * GRIP_MARGIN, tool.min_gap, tool.max_gap))
    grip_gap = float(np.clip(GRIP_SQUEEZE * width + thick, tool.min_gap, tool.max_gap))
    half_y = world_half_y(tool, rot)
    return open_gap, grip_gap, scene.bottom - FINGER_SINK + half_y, scene.top_all + half_y + CLEARANCE


def straddle_centre(scene: Scene, axis: np.ndarray) -> np.ndarray:
    """``(3,)`` the attended dough's centre moved along the gripper's gap ``axis`` to the middle of its extent.

    A piece just cut bulges to one side, so its mean lies off the middle of its extent: open fingers centred
    on the mean can touch its far edge where fingers centred on the middle of its extent clear both.
    """
    centre = scene.centre
    along = (scene.attended - centre) @ axis
    return centre + axis * 0.5 * float(along.min() + along.max())


def gripper_start(env: DoughEnv, tool_name: str, scene: Scene) -> ToolPose:
    """Open fingers at grip height straddling the attended dough: around its centre, else around the middle
    of its extent along the gap axis (:func:`straddle_centre`), else there with the fingers pressed at most
    ``FINGER_PRESS`` into the dough (a piece wider than the open fingers); above all dough only where all three
    would touch it.

    Every demonstration starts straddling its piece, so a start above the dough is one the policies never saw
    (measured at ``small``: all 100 rearrange demonstrations of CutRearrange's set start at grip height, and a
    piece bulged by a real cut made the policy carry an empty gripper through the air, docs/training.md).
    """
    tool = env.tool(tool_name)
    current = env.tool_poses()[tool_name]
    open_gap, _, grip_y, safe_y = _grip_geometry(tool, current.rot, scene)
    axis, _ = _gripper_frame(current.rot)
    middle = straddle_centre(scene, axis)
    for centre, margin in ((scene.centre, 0.0), (middle, 0.0), (middle, -FINGER_PRESS)):
        pose = ToolPose(pos=(centre[0], grip_y, centre[2]), rot=current.rot, gap=open_gap)
        if not collides(tool, pose, scene.points, margin=margin):
            return pose
    centre = scene.centre
    return ToolPose(pos=(centre[0], safe_y, centre[2]), rot=current.rot, gap=open_gap)


def _gripper_approach(m: Motion, scene: Scene, open_gap: float, grip_y: float, safe_y: float) -> None:
    """Unless already straddling the dough at grip height: open, up, over the dough, down."""
    centre = scene.centre
    axis, _ = _gripper_frame(m.rot)
    inner = m.gap - 2.0 * m.tool.half_extents[0]

    def near(point: np.ndarray) -> bool:
        return bool(np.linalg.norm((m.pos - point)[[0, 2]]) < 0.02)

    # Around the centre with room for the piece, or where gripper_start straddles it, opened as wide as it puts it.
    around = abs(m.pos[1] - grip_y) < 0.03 and (
        (near(centre) and inner >= _width_along(scene.attended, centre, axis))
        or (near(straddle_centre(scene, axis)) and m.gap >= open_gap - 1e-9))
    if around:
        return
    if m.gap < open_gap:
        m.move(gap=open_gap)
    if not (np.linalg.norm((m.pos - centre)[[0, 2]]) < 0.02):
        if m.pos[1] < safe_y and m.scales[1] > 0:
            m.move(pos=(m.pos[0], safe_y, m.pos[2]))
        m.move(pos=(centre[0], m.pos[1], centre[2]))
    m.move(pos=(m.pos[0], grip_y, m.pos[2]))


def rearrange(env: DoughEnv, m: Motion, scene: Scene) -> None:
    """Straddle the piece (approach if needed), close to ``GRIP_SQUEEZE`` of its width, move the
    piece's centre to the target's horizontally (eased over ``REARRANGE_EASE`` steps), open, lift."""
    goal = scene.destination
    open_gap, grip_gap, grip_y, safe_y = _grip_geometry(m.tool, m.rot, scene)
    _gripper_approach(m, scene, open_gap, grip_y, safe_y)
    m.move(gap=grip_gap)
    if goal is not None:
        shift = goal.mean(axis=0) - scene.centre
        m.move(pos=(m.pos[0] + shift[0], m.pos[1], m.pos[2] + shift[2]), ease=REARRANGE_EASE)
    m.move(gap=open_gap)
    m.move(pos=(m.pos[0], safe_y, m.pos[2]))


def gather(env: DoughEnv, m: Motion, scene: Scene) -> None:
    """Squeeze along the gap axis at ``GATHER_SPEED`` to ``GATHER_SQUEEZE`` of the target's width (plus the
    fingers' thickness), then hold the grip for ``GATHER_HOLD`` steps without opening or turning.

    Measured on GatherMove at small (8 configurations, gripper expel rate 0): this scored a median 0.32;
    opening at the end lets the squeezed dough spring back (0.179 -> 0.266 wide) and turning with open
    fingers smears it (two passes with a turn: 0.13).
    """
    tool = m.tool
    goal = scene.destination if scene.destination is not None else scene.attended
    goal_centre = goal.mean(axis=0)
    thick = 2.0 * tool.half_extents[0]
    open_gap, _, grip_y, safe_y = _grip_geometry(tool, m.rot, scene)
    _gripper_approach(m, scene, open_gap, grip_y, safe_y)
    axis, _ = _gripper_frame(m.rot)
    target_along = _width_along(goal, goal_centre, axis)
    m.move(gap=GATHER_SQUEEZE * target_along + thick, speed=GATHER_SPEED)
    for _ in range(GATHER_HOLD):
        m.step(np.zeros(len(m.scales)))
