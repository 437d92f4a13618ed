"""Scripted (heuristic) skills: an open-loop action sequence for one skill, from point clouds.

PASTA's real-world experiments replaced the learned policies by heuristic ones (appendix section
3.1): each takes the current observation, the subgoal point cloud and the planner's attention mask
(which pieces to act on) and outputs a motion of the tool. This package does the same in
simulation, for every skill of the five tasks; the sequences serve as GBTO warm starts
(env_spec 5.3, :mod:`pasta.data.demos`) and as a baseline executor.

Two calls, in this order::

    place_tool_for_skill(env, "cut", attention, target_points)   # teleports the tool (optional)
    actions = scripted_actions(env, "cut", target_points, attention)
    for a in actions:
        env.step(a)

* :func:`place_tool_for_skill` teleports the skill's tool to its start pose next to the attended
  dough (env_spec 2.5: CRS teleported the active tool before every skill). It does not simulate.
  Skipping it is allowed: the scripted actions then start with an approach motion from wherever
  the tool is (lift clear of the dough, move over, lower), which costs steps out of the budget.
* :func:`scripted_actions` reads the environment (particles, tool poses) and returns
  ``(n_steps, env.action_dim)`` float32 actions in [-1, 1], non-zero only in the skill's tool slice.
  It does not step or change the environment.

Every motion is planned on a kinematic model of the tool (:class:`~pasta.data.skills.motion.Motion`),
which reaches the end point of a straight segment exactly; segments that move dough ramp their
speed up and down so that the dough is not thrown. A sequence shorter than ``n_steps`` is padded
with zero actions; a longer one is cut off.

Modules: :mod:`~pasta.data.skills.scene` (configuration look-ups, the dough and subgoal as the
scripts see them, geometry), :mod:`~pasta.data.skills.motion` (the motion planner), and one module
per tool: :mod:`~pasta.data.skills.cut` (knife), :mod:`~pasta.data.skills.push` (box pusher),
:mod:`~pasta.data.skills.gripper` (rearrange, gather), :mod:`~pasta.data.skills.spread` (rolling
pin), :mod:`~pasta.data.skills.spatula` (lift, move); this module dispatches to them.

The skills (tool kind from ``cfg.skills``):

========== ============ ==================================================================
skill      tool kind    motion
========== ============ ==================================================================
cut        knife        cut x from the length ratio of the two target pieces (appendix 3.1);
                        move above it, go down through the dough at half speed to 0.02 below
                        its bottom, push each piece that must travel towards its target centre
                        (the left one to -x, the right one to +x), slowing down so the piece
                        stops with the knife; lift
push       box          pusher behind the piece at contact height, facing the target; push
                        along the line between the centres of mass, slowing down at the end
rearrange  gripper      open, over the piece, lower, close on it, move horizontally to the
                        target centre, open, lift
spread     rolling pin  press straight down to the target thickness, then roll to and fro
                        without slipping about the target's centre (roll a0 with slide a3)
lift, move box          from under the dough: one smooth path over the whole budget that
                        rises above every support, carries to the target and comes down onto
                        the support there
gather     gripper      close at half speed on the scattered dough to 0.8 of the target's
                        width (gap action +) and hold; no opening, no turn
========== ============ ==================================================================

What was measured at the coarse profiles (grid 32 and 48), and shaped these scripts:

* Fast tool motions throw the dough (it slides on after the tool stops; ground friction 0.5), so
  pushes brake over the steps friction needs, the knife cuts at half speed and the spatula eases.
* Grid nodes inside a tool leave it at its expel rate (``tools[].expel_rate``, else
  ``sim.tool_expel_rate``) of their depth per substep. With 0.1 a spatula lifting dough launches it
  and then carries it on a cushion without friction, so the spatulas, grippers, boards and
  LiftSpread's pin have 0 (and at grid 32 the 0.04-thick spatula also drops the dough when the
  board is high). Opening a gripper after a gather lets the squeezed dough spring back.
* At grid 32 the 0.05-thick knife cannot cut (a piece is launched or stays joined); at grid 48
  the cut leaves two DBSCAN pieces in the 1000 observation points, provided the knife's mid-plane
  lies between two grid columns (the cut x is moved to the middle of its grid cell), and with the
  knife's rate at 0.4 (``small``) no floor smear joins them.
* A rolling pin moving its full span pushes the dough out of the target (RollingPinExt's roll
  alone moves the pin's bottom at twice the pin's speed); pressing does most of the spreading.

Target pieces are found by DBSCAN; the pieces the attention leaves out keep their nearest target
piece, and the target pieces left over are where the attended dough must go
(:func:`~pasta.data.skills.scene.analyse`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pasta.config.schema import TaskConfig, ToolConfig
from pasta.data.skills.aim import Aim
from pasta.data.skills.cut import cut, cut_start
from pasta.data.skills.gripper import gather, gripper_start, rearrange
from pasta.data.skills.motion import Motion
from pasta.data.skills.push import push, push_start
from pasta.data.skills.scene import SKILL_TOOL_KINDS, Scene, analyse, as_cloud, has_script, skill_config
from pasta.data.skills.spatula import lift, spatula_start
from pasta.data.skills.spread import spread, spread_start
from pasta.sim.envs.base import DoughEnv, ToolPose

__all__ = [
    "SKILL_TOOL_KINDS",
    "Aim",
    "available_skills",
    "place_tool_for_skill",
    "scripted_actions",
    "skill_tool",
    "start_pose_for_skill",
]

_SCRIPTS: dict[str, Callable[[DoughEnv, Motion, Scene], None]] = {
    "cut": cut,
    "push": push,
    "rearrange": rearrange,
    "spread": spread,
    "lift": lift,
    "move": lift,
    "gather": gather,
}

_START_POSES: dict[str, Callable[[DoughEnv, str, Scene], ToolPose]] = {
    "cut": cut_start,
    "push": push_start,
    "rearrange": gripper_start,
    "spread": spread_start,
    "lift": spatula_start,
    "move": spatula_start,
    "gather": gripper_start,
}


def available_skills(cfg: TaskConfig) -> tuple[str, ...]:
    """The task's skills that have a script, in ``cfg.skills`` order (all of them for the five tasks)."""
    return tuple(s.name for s in cfg.skills if has_script(cfg, s))


def skill_tool(cfg: TaskConfig, skill: str) -> ToolConfig:
    """The tool a skill drives (``cfg.skills``); raises ``ValueError`` for an unknown or unscripted skill."""
    skill_cfg = skill_config(cfg, skill)
    return next(t for t in cfg.tools if t.name == skill_cfg.tool)


def start_pose_for_skill(env: DoughEnv, skill: str, attention: np.ndarray | None = None,
                         target_points: np.ndarray | None = None, aim: Aim | None = None) -> ToolPose:
    """Where :func:`place_tool_for_skill` puts the skill's tool (nothing is changed).

    ============ =========================================================================
    skill        start pose (dough = the attended particles)
    ============ =========================================================================
    cut          knife over the dough's centre of mass (x, z), or with ``data.knife_start: cut``
                 over the target's split (x in a grid cell's middle; the dough's middle without a
                 two-piece target); its edge 0.03 above the dough top (at least the configured
                 height), as env_spec 2.5 / CutRearrange
    push         pusher at contact height just behind the dough, facing the target's centre
                 of mass (turned about y); without ``target_points``, on the +x side facing
                 -x (env_spec 2.5)
    rearrange    gripper straddling the dough at grip height, fingers open around it
    spread       rolling pin over the centre of mass, 0.01 above the dough top
    lift, move   spatula right under the dough (its top at the dough's bottom)
    gather       gripper centred on the dough at grip height, open wide enough
    ============ =========================================================================

    A pose whose tool would intersect dough it should not touch is moved away (the pusher further
    back, the gripper and spatula up above the dough). With an ``aim``, the pose is the one for the
    destination the aim makes of the subgoal's (:class:`~pasta.data.skills.aim.Aim`).
    """
    skill_cfg = skill_config(env.cfg, skill)
    scene = analyse(env, skill_cfg, target_points, attention).aimed(aim)
    return _START_POSES[skill_cfg.name](env, skill_cfg.tool, scene)


def place_tool_for_skill(env: DoughEnv, skill: str, attention: np.ndarray | None = None,
                         target_points: np.ndarray | None = None, aim: Aim | None = None) -> ToolPose:
    """Teleport the skill's tool to its start pose (:func:`start_pose_for_skill`); returns the pose.

    Run it after the dough has settled and before :func:`scripted_actions`, whose first motions
    then cost no steps. The push needs ``target_points`` to face the target, and the cut
    (``data.knife_start: cut``) to find the split; the other tools' start poses depend on the
    attended dough alone. No simulation step is taken (:meth:`DoughEnv.teleport_tool`).

    Some tools cannot approach the dough by themselves, so their skills need this placement: a
    rolling pin has no action along its axis, the GatherMove gripper none in y and the spatulas
    none in z. The others approach within the step budget, at a cost (measured at smoke: push
    0.88 placed vs -0.02 to 0.58 not placed, rearrange 0.90 vs 0.56).
    """
    skill_cfg = skill_config(env.cfg, skill)
    pose = start_pose_for_skill(env, skill, attention, target_points, aim)
    env.teleport_tool(skill_cfg.tool, pose.pos, pose.rot, pose.gap)
    return env.tool_poses()[skill_cfg.tool]


def scripted_actions(env: DoughEnv, skill: str, target_points: np.ndarray, attention: np.ndarray | None = None,
                     n_steps: int | None = None, aim: Aim | None = None) -> np.ndarray:
    """Open-loop actions of one scripted skill, from the environment's current state.

    Args:
        env: a reset environment (it is read, not stepped).
        skill: a skill of ``env.cfg.skills`` (see :func:`available_skills`).
        target_points: ``(P, 3)`` subgoal point cloud (the whole scene after the skill).
        attention: ``(N,)`` bool mask over the current particles selecting the pieces to act on
            (``N`` = ``cfg.sim.n_particles``, or ``cfg.sim.observation_points`` for a mask over the
            observation's dough points); ``None`` acts on all dough.
        n_steps: sequence length (default ``cfg.sim.steps_per_skill``).
        aim: where the skill is told its destination is, relative to the subgoal's (None: the
            subgoal's own; :class:`~pasta.data.skills.aim.Aim`).

    Returns:
        ``(n_steps, env.action_dim)`` float32 in [-1, 1]; only the skill's tool slice is non-zero.
    """
    cfg = env.cfg
    skill_cfg = skill_config(cfg, skill)
    n = cfg.sim.steps_per_skill if n_steps is None else int(n_steps)
    if n < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    target = as_cloud(target_points, "target_points")
    scene = analyse(env, skill_cfg, target, attention).aimed(aim)
    motion = Motion(env, skill_cfg.tool, n)
    _SCRIPTS[skill_cfg.name](env, motion, scene)
    actions = np.zeros((n, env.action_dim), np.float32)
    actions[:, env.tool_action_slice(skill_cfg.tool)] = motion.finish()
    return np.clip(actions, -1.0, 1.0)
