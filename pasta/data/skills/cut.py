"""The knife's cut (appendix 3.1): split the attended dough at the target's length ratio, then push
the pieces towards their targets.

Why the knife goes down slowly and in the middle of a grid cell: see the measurements in
:mod:`pasta.data.skills`.
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import ToolConfig
from pasta.data.skills.motion import Motion, braking_steps
from pasta.data.skills.scene import Scene, extent
from pasta.sim.envs.base import DoughEnv, ToolPose
from pasta.sim.shapes import cell_middle

KNIFE_CLEARANCE = 0.03  # knife edge above the dough top before a cut (as CutRearrange's default pose)
CUT_BELOW_BOTTOM = 0.02  # the knife edge goes this far below the dough's bottom
CUT_SPEED = 0.5  # fraction of full speed at which the knife goes through the dough (faster flings the halves)
SEPARATION_TOLERANCE = 0.01  # a piece closer than this (beyond the knife's half thickness) is not pushed
# When the subgoal asks for no push (a learned subgoal's decoded pieces may overlap), the piece that the subgoal
# moves more is still pushed this far beyond the knife's face: without it the pieces stay joined by the cut's
# smear and the next skill carries both (CRS, learned plans at small: -0.83 instead of 0.76 on one configuration).
# The generator's own cut subgoals slide a piece 0.1 or more, so they always ask for a push of their own.
MIN_PUSH = 0.05


def split_along_x(cloud: np.ndarray) -> list[np.ndarray]:
    """Two pieces (left, right) of a ``(M, 3)`` cloud split at the x that minimises the pieces' summed
    squared x deviations (1-D two-means, exact); the cloud itself when it has fewer than two points.

    A learned plan's decoded cut subgoal may hold two pieces that overlap, which segmentation sees as one;
    a cut always yields a left and a right piece, so their boundary is where the cloud splits best along x.
    """
    if len(cloud) < 2:
        return [cloud]
    order = np.argsort(cloud[:, 0], kind="stable")
    x = cloud[order, 0]
    n = len(x)
    count = np.arange(1, n)  # points in the left piece for a split after each sorted point
    left_sum = np.cumsum(x)[:-1]
    left_sq = np.cumsum(x * x)[:-1]
    total, total_sq = x.sum(), (x * x).sum()
    cost = (left_sq - left_sum ** 2 / count) + ((total_sq - left_sq) - (total - left_sum) ** 2 / (n - count))
    split = int(np.argmin(cost)) + 1
    return [cloud[order[:split]], cloud[order[split:]]]


def _cut_plan(scene: Scene) -> tuple[float, list[np.ndarray]]:
    """The cut x and the two target pieces (left, right; empty without a two-piece target).

    The cut splits the attended dough at the target's length ratio: x = left end + length x
    (left length / (left + right length)), which is the left end plus the target's left length
    when the dough is as long as the two target pieces together (appendix 3.1).
    """
    x_lo, x_hi = extent(scene.attended[:, 0])
    pieces = list(scene.destinations)
    if len(pieces) > 2:  # the two target pieces nearest the attended dough
        centre = scene.centre
        pieces.sort(key=lambda p: float(np.linalg.norm(p.mean(axis=0)[[0, 2]] - centre[[0, 2]])))
        pieces = pieces[:2]
    if len(pieces) == 1:  # the target pieces touch (a decoded subgoal): split the target where they meet
        pieces = split_along_x(pieces[0])
    if len(pieces) < 2:
        return 0.5 * (x_lo + x_hi), []
    pieces.sort(key=lambda p: float(p[:, 0].mean()))
    lengths = [np.subtract(*extent(p[:, 0])[::-1]) for p in pieces]
    ratio = lengths[0] / max(lengths[0] + lengths[1], 1e-9)
    return x_lo + ratio * (x_hi - x_lo), pieces


def _knife_safe_y(tool: ToolConfig, scene: Scene) -> float:
    return max(tool.position[1], scene.top + tool.blade_depth + KNIFE_CLEARANCE)


def cut_start(env: DoughEnv, tool_name: str, scene: Scene) -> ToolPose:
    """The knife at the dough's centre z, its edge ``KNIFE_CLEARANCE`` above the dough top, and in x
    (``data.knife_start``) over the attended dough's centre of mass (``centre``, the official reset pose)
    or over the cut (``cut``: :func:`_cut_plan`'s x in the middle of a grid cell).

    Over the cut, the skill, scripted or learned, has nothing to do along x before going down: the
    step that carries the cut's position is taken by the placement, which reads the subgoal exactly.
    """
    tool = env.tool(tool_name)
    centre = scene.centre
    x = centre[0]
    if env.cfg.data.knife_start == "cut":
        x = cell_middle(_cut_plan(scene)[0], env.cfg.sim.n_grid)
    return ToolPose(pos=(x, _knife_safe_y(tool, scene), centre[2]), rot=env.tool_poses()[tool_name].rot)


def cut(env: DoughEnv, m: Motion, scene: Scene) -> None:
    """Above the cut x, down through the dough at ``CUT_SPEED`` to ``CUT_BELOW_BOTTOM`` under its
    bottom, push the piece(s) that must travel towards their target centres, lift."""
    tool = m.tool
    cut_x, pieces = _cut_plan(scene)
    # Cut in the middle of a grid cell: with a grid column on the knife's mid-plane, the direction
    # in which the simulator expels the dough there is arbitrary, and the whole dough drifts
    # (measured at grid 48: cuts on a column lost 0.3-0.75 of the EMD, cuts between gained 0.4-0.6).
    cut_x = cell_middle(cut_x, env.cfg.sim.n_grid)
    safe_y = max(_knife_safe_y(tool, scene), m.pos[1])
    if abs(m.pos[0] - cut_x) > 1e-3 and m.pos[1] - tool.blade_depth < scene.top_all + 0.005:
        m.move(pos=(m.pos[0], safe_y, m.pos[2]))  # lift clear before moving across
    m.move(pos=(cut_x, m.pos[1], m.pos[2]))
    cut_y = scene.bottom - CUT_BELOW_BOTTOM + tool.blade_depth
    touch_y = scene.top + tool.blade_depth + 0.005  # the edge just above the dough
    if m.pos[1] > touch_y:
        m.move(pos=(cut_x, max(touch_y, cut_y), m.pos[2]))
    m.move(pos=(cut_x, cut_y, m.pos[2]), speed=CUT_SPEED)
    if pieces:
        a = scene.attended
        left, right = a[a[:, 0] <= cut_x], a[a[:, 0] > cut_x]
        shift_left = float(pieces[0][:, 0].mean() - left[:, 0].mean()) if len(left) else 0.0
        shift_right = float(pieces[1][:, 0].mean() - right[:, 0].mean()) if len(right) else 0.0
        # The knife can only push (left piece to -x, right piece to +x). Its faces are half its
        # thickness from its centre, so going down already moved each cut face by that much. It
        # slows down gently so that the pushed piece stops with it instead of sliding on.
        half, speed = tool.half_extents[0], tool.action_scales[0]
        pushes = []
        if shift_left < -(half + SEPARATION_TOLERANCE):
            pushes.append(shift_left + half)
        if shift_right > half + SEPARATION_TOLERANCE:
            pushes.append(shift_right - half)
        if not pushes:
            pushes.append(-MIN_PUSH if -shift_left >= shift_right else MIN_PUSH)
        for push in pushes:
            m.move(pos=(cut_x + push, cut_y, m.pos[2]), ease=2,
                   ease_out=braking_steps(env, abs(cut_x + push - m.pos[0]), speed))
    m.move(pos=(m.pos[0], safe_y, m.pos[2]))
