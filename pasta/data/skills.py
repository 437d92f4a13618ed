"""Scripted (heuristic) skills: an open-loop action sequence for one skill, from point clouds.

PASTA's real-world experiments replaced the learned policies by heuristic ones (appendix section
3.1): each takes the current observation, the subgoal point cloud and the planner's attention mask
(which pieces to act on) and outputs a motion of the tool. This module does the same in
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

Every motion is planned on a kinematic model of the tool (:class:`_Motion`): an action ``a`` moves
the tool by ``a * action_scale`` per environment step (env_spec 1.5), so a straight segment reaches
its end point exactly (tool-tool collisions, e.g. the spatula resting on the cutting board, are not
modelled; the scripts only run into them on the last lowering). Segments that move dough ramp
their speed up and down so that the dough is not thrown (see ``_braking_steps``). A sequence
shorter than ``n_steps`` is padded with zero actions; a longer one is cut off.

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
lift, move box          from under the dough, lift (eased) above the board, carry to the
                        target, lower onto the support there
gather     gripper      close on the scattered dough to the target's width (gap action +),
                        open, turn 90 degrees if the other axis is still too wide, close
                        again, open a little to let go
========== ============ ==================================================================

What was measured at the coarse profiles (grid 32 and 48), and shaped these scripts:

* Fast tool motions throw the dough (it slides on after the tool stops; ground friction 0.5), so
  pushes brake over the steps friction needs, the knife cuts at half speed and the spatula eases.
* Grid nodes inside a tool leave it at ``sim.tool_expel_rate`` of their depth per substep. With
  the default 0.1 a spatula lifting dough launches it and then carries it on a cushion without
  friction, so ``lift`` / ``move`` only work with that rate at 0 (and at grid 48; at grid 32 the
  0.04-thick spatula also drops the dough when the board is high); a gripper holding dough
  squeezed squirts it through its fingers, so ``gather`` opens a little at the end.
* At grid 32 the 0.05-thick knife cannot cut (a piece is launched or stays joined); at grid 48
  the cut leaves two DBSCAN pieces in the 1000 observation points, provided the knife's mid-plane
  lies between two grid columns (the cut x is moved to the middle of its grid cell).
* A rolling pin moving its full span pushes the dough out of the target (RollingPinExt's roll
  alone moves the pin's bottom at twice the pin's speed); pressing does most of the spreading.

Target pieces are found by DBSCAN (:func:`~pasta.geometry.entities.label_entities`, the task's
``cfg.data`` parameters). Pieces the attention leaves out are expected to stay where they are: each
is matched to its nearest target piece (by centre), and the target pieces left over are where
the attended dough must go.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pasta.config.schema import SkillConfig, TaskConfig, ToolConfig
from pasta.geometry.entities import label_entities, split_entities
from pasta.sim.envs.base import DoughEnv, ToolPose
from pasta.sim.quaternion import quat_to_matrix_np
from pasta.sim.tool_points import tool_world_bounds, world_sdf

__all__ = [
    "SKILL_TOOL_KINDS",
    "available_skills",
    "place_tool_for_skill",
    "scripted_actions",
    "skill_tool",
    "start_pose_for_skill",
]

# The tool kind each scripted skill drives.
SKILL_TOOL_KINDS: dict[str, str] = {
    "cut": "knife",
    "push": "box",
    "rearrange": "gripper",
    "spread": "rolling_pin",
    "lift": "box",
    "move": "box",
    "gather": "gripper",
}

CLEARANCE = 0.02  # gap kept between a tool and the dough while approaching
EXTENT_PERCENTILES = (0.5, 99.5)  # robust extents of point clouds
MAX_BRAKING_STEPS = 30  # a pushing tool slows down over at most this many steps
# cut
KNIFE_CLEARANCE = 0.03  # knife edge above the dough top before a cut (as CutRearrange's default pose)
CUT_BELOW_BOTTOM = 0.02  # the knife edge goes this far below the dough's bottom
CUT_SPEED = 0.5  # fraction of full speed at which the knife goes through the dough (faster flings the halves)
SEPARATION_TOLERANCE = 0.01  # a piece closer than this (beyond the knife's half thickness) is not pushed
# push
PUSH_SINK = 0.005  # the pusher's bottom sits this far below the dough's bottom
# rearrange, gather
FINGER_SINK = 0.005  # the gripper fingers' bottom sits this far below the dough's bottom
GRIP_MARGIN = 0.02  # open fingers keep this much room on each side of the piece
GRIP_SQUEEZE = 0.7  # a closed grip leaves this fraction of the piece's width between the fingers
GATHER_SPEED = 0.5  # fraction of full gap speed when squeezing (faster squirts dough through the fingers)
GATHER_RELEASE = 0.04  # the gripper opens this much at the end of a gather
GATHER_TOLERANCE = 0.02  # turn and squeeze again when the pile is this much wider than the target
# lift, move
SPATULA_CLEARANCE = 0.015  # the carrying spatula's bottom clears the highest support by this
SPATULA_EASE = 4  # steps over which the spatula speeds up and slows down (the dough must not take off)
# spread
ROLL_CLEARANCE = 0.01  # the rolling pin starts this far above the dough
PIN_GAP_CELLS = 1.5  # the rolling pin stops this many grid cells above a static support (the board)
ROLL_SPAN = 0.2  # the rolling pin rolls over this fraction of the target's half length each side
ROLL_ONLY_SPEED = 0.15  # roll action of a pin without a slide action (its bottom slips at twice its speed)


# --------------------------------------------------------------------------- public API
def available_skills(cfg: TaskConfig) -> tuple[str, ...]:
    """The task's skills that have a script, in ``cfg.skills`` order (all of them for the five tasks)."""
    return tuple(s.name for s in cfg.skills if _has_script(cfg, s))


def skill_tool(cfg: TaskConfig, skill: str) -> ToolConfig:
    """The tool a skill drives (``cfg.skills``); raises ``ValueError`` for an unknown or unscripted skill."""
    skill_cfg = _skill_config(cfg, skill)
    return next(t for t in cfg.tools if t.name == skill_cfg.tool)


def start_pose_for_skill(env: DoughEnv, skill: str, attention: np.ndarray | None = None,
                         target_points: np.ndarray | None = None) -> ToolPose:
    """Where :func:`place_tool_for_skill` puts the skill's tool (nothing is changed).

    ============ =========================================================================
    skill        start pose (dough = the attended particles)
    ============ =========================================================================
    cut          knife over the dough's centre of mass (x, z), its edge 0.03 above the dough
                 top (at least the configured height), as env_spec 2.5 / CutRearrange
    push         pusher at contact height just behind the dough, facing the target's centre
                 of mass (turned about y); without ``target_points``, on the +x side facing
                 -x (env_spec 2.5)
    rearrange    gripper straddling the dough at grip height, fingers open around it
    spread       rolling pin over the centre of mass, 0.01 above the dough top
    lift, move   spatula right under the dough (its top at the dough's bottom)
    gather       gripper centred on the dough at grip height, open wide enough
    ============ =========================================================================

    A pose whose tool would intersect dough it should not touch is moved away (the pusher further
    back, the gripper and spatula up above the dough).
    """
    skill_cfg = _skill_config(env.cfg, skill)
    scene = _analyse(env, skill_cfg, target_points, attention)
    return _START_POSES[skill_cfg.name](env, skill_cfg.tool, scene)


def place_tool_for_skill(env: DoughEnv, skill: str, attention: np.ndarray | None = None,
                         target_points: np.ndarray | None = None) -> ToolPose:
    """Teleport the skill's tool to its start pose (:func:`start_pose_for_skill`); returns the pose.

    Run it after the dough has settled and before :func:`scripted_actions`, whose first motions
    then cost no steps. Only the push needs ``target_points`` to face the target; the other tools'
    start poses depend on the attended dough alone. No simulation step is taken
    (:meth:`DoughEnv.teleport_tool`).

    Some tools cannot approach the dough by themselves, so their skills need this placement: a
    rolling pin has no action along its axis, the GatherMove gripper none in y and the spatulas
    none in z. The others approach within the step budget, at a cost (measured at smoke: push
    0.88 placed vs -0.02 to 0.58 not placed, rearrange 0.90 vs 0.56).
    """
    skill_cfg = _skill_config(env.cfg, skill)
    pose = start_pose_for_skill(env, skill, attention, target_points)
    env.teleport_tool(skill_cfg.tool, pose.pos, pose.rot, pose.gap)
    return env.tool_poses()[skill_cfg.tool]


def scripted_actions(env: DoughEnv, skill: str, target_points: np.ndarray, attention: np.ndarray | None = None,
                     n_steps: int | None = None) -> np.ndarray:
    """Open-loop actions of one scripted skill, from the environment's current state.

    Args:
        env: a reset environment (it is read, not stepped).
        skill: a skill of ``env.cfg.skills`` (see :func:`available_skills`).
        target_points: ``(P, 3)`` subgoal point cloud (the whole scene after the skill).
        attention: ``(N,)`` bool mask over the current particles selecting the pieces to act on
            (``N`` = ``cfg.sim.n_particles``, or ``cfg.sim.observation_points`` for a mask over the
            observation's dough points); ``None`` acts on all dough.
        n_steps: sequence length (default ``cfg.sim.steps_per_skill``).

    Returns:
        ``(n_steps, env.action_dim)`` float32 in [-1, 1]; only the skill's tool slice is non-zero.
    """
    cfg = env.cfg
    skill_cfg = _skill_config(cfg, skill)
    n = cfg.sim.steps_per_skill if n_steps is None else int(n_steps)
    if n < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    target = _as_cloud(target_points, "target_points")
    scene = _analyse(env, skill_cfg, target, attention)
    motion = _Motion(env, skill_cfg.tool, n)
    _SCRIPTS[skill_cfg.name](env, motion, scene)
    actions = np.zeros((n, env.action_dim), np.float32)
    actions[:, env.tool_action_slice(skill_cfg.tool)] = motion.finish()
    return np.clip(actions, -1.0, 1.0)


# ---------------------------------------------------------------------- configuration
def _has_script(cfg: TaskConfig, skill: SkillConfig) -> bool:
    kind = SKILL_TOOL_KINDS.get(skill.name)
    tool = next((t for t in cfg.tools if t.name == skill.tool), None)
    return kind is not None and tool is not None and tool.kind == kind


def _skill_config(cfg: TaskConfig, skill: str) -> SkillConfig:
    names = [s.name for s in cfg.skills]
    if skill not in names:
        raise ValueError(f"task {cfg.task} has no skill {skill!r}; its skills are {names}")
    skill_cfg = cfg.skills[names.index(skill)]
    if not _has_script(cfg, skill_cfg):
        tool = next(t for t in cfg.tools if t.name == skill_cfg.tool)
        expected = SKILL_TOOL_KINDS.get(skill)
        raise ValueError(
            f"no script for skill {skill!r} with a {tool.kind!r} tool ({tool.name!r}); scripted skills: "
            + ", ".join(f"{name} ({kind})" for name, kind in SKILL_TOOL_KINDS.items())
            + (f"; {skill!r} needs a {expected!r}" if expected else "")
        )
    return skill_cfg


# --------------------------------------------------------------------------- geometry
def _as_cloud(points, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
        raise ValueError(f"{name} must have shape (P, 3) with P >= 1, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has non-finite coordinates")
    return arr


def _extent(values: np.ndarray) -> tuple[float, float]:
    lo, hi = np.percentile(values, EXTENT_PERCENTILES)
    return float(lo), float(hi)


def _entities(points: np.ndarray, cfg: TaskConfig) -> list[np.ndarray]:
    """DBSCAN pieces of a cloud (the whole cloud when DBSCAN keeps no cluster)."""
    try:
        labels = label_entities(points, eps=cfg.data.dbscan_eps, min_samples=cfg.data.dbscan_min_samples,
                                min_points=cfg.data.dbscan_min_points)
    except ValueError:
        return [points]
    return split_entities(points, labels)


def _rotation(rot: Sequence[float]) -> np.ndarray:
    return quat_to_matrix_np(np.asarray(rot, dtype=np.float64))


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def _axis_angle_quat(w: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = np.asarray(w, dtype=np.float64) / theta
    return np.array([math.cos(0.5 * theta), *(math.sin(0.5 * theta) * axis)])


def _yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    """Rotation by ``yaw`` about world y: local x goes to (cos yaw, 0, -sin yaw)."""
    return (math.cos(0.5 * yaw), 0.0, math.sin(0.5 * yaw), 0.0)


def _yaw_of(rot: Sequence[float]) -> float:
    """Heading of the tool's local x axis about world y (atan2(-x_z, x_x))."""
    R = _rotation(rot)
    return math.atan2(-R[2, 0], R[0, 0])


def _half_plate_turn(angle: float) -> float:
    """An angle wrapped to [-pi/2, pi/2): a plate or a gripper looks the same turned by pi."""
    return (angle + 0.5 * math.pi) % math.pi - 0.5 * math.pi


def _world_half_y(tool: ToolConfig, rot: Sequence[float]) -> float:
    """Half height of one box (spatula, pusher, gripper finger) at this rotation."""
    return float((np.abs(_rotation(rot)) @ np.asarray(tool.half_extents))[1])


def _support(env: DoughEnv, x: float, z: float) -> tuple[float, bool]:
    """Height dough rests at over (x, z), and whether that is a static box (cutting board) or the floor."""
    y, on_tool = env.floor_y, False
    poses = None
    for tool in env.tools:
        if not (tool.static and tool.kind == "box"):
            continue
        poses = poses or env.tool_poses()
        pose = poses[tool.name]
        lo, hi = tool_world_bounds(tool, pose.pos, pose.rot)
        if lo[0] <= x <= hi[0] and lo[2] <= z <= hi[2] and hi[1] > y:
            y, on_tool = float(hi[1]), True
    return y, on_tool


def _support_y(env: DoughEnv, x: float, z: float) -> float:
    """Height dough rests at over (x, z): the floor, or the top of a static box (cutting board) there."""
    return _support(env, x, z)[0]


def _braking_steps(env: DoughEnv, distance: float, top_speed: float) -> int:
    """Steps over which a tool pushing dough along the ground must slow down so that the dough,
    braked by ground friction alone, keeps up with it instead of sliding on.

    Ground friction takes ``mu |g| T^2`` off the dough's displacement per step every step (``T`` the
    time of one step). A push of ``distance`` at up to ``top_speed`` per step stops over
    ``min(top_speed, sqrt(2 distance brake)) / brake`` steps.
    """
    sim = env.cfg.sim
    brake = env.cfg.material.ground_friction * abs(sim.gravity_m_s2[1]) * (sim.dt_s * sim.substeps_per_step) ** 2
    if brake <= 0 or distance <= 0:
        return 0
    return min(math.ceil(min(top_speed, math.sqrt(2.0 * distance * brake)) / brake), MAX_BRAKING_STEPS)


def _collides(tool: ToolConfig, pose: ToolPose, points: np.ndarray, margin: float = 0.0) -> bool:
    if len(points) == 0:
        return False
    return bool((world_sdf(tool, points, pose.pos, pose.rot, pose.gap) < margin).any())


# ------------------------------------------------------------------------------ scene
@dataclass(frozen=True)
class _Scene:
    """What the scripts need to know about the dough and the subgoal.

    ``points`` every current dough point, ``attended`` those the skill acts on;
    ``destinations`` the target pieces the attended dough should become (empty without a target);
    ``bottom`` the height the attended dough rests at; ``top`` its highest point; ``top_all`` the
    highest point of all dough.
    """

    points: np.ndarray
    attended: np.ndarray
    destinations: tuple[np.ndarray, ...]
    bottom: float
    top: float
    top_all: float

    @property
    def centre(self) -> np.ndarray:
        return self.attended.mean(axis=0)

    @property
    def destination(self) -> np.ndarray | None:
        """All destination pieces as one cloud."""
        return np.concatenate(self.destinations) if self.destinations else None


def _analyse(env: DoughEnv, skill: SkillConfig, target: np.ndarray | None, attention) -> _Scene:
    cfg = env.cfg
    points = env.particles().astype(np.float64)
    if attention is None:
        mask = np.ones(len(points), bool)
    else:
        mask = np.asarray(attention).reshape(-1)
        if mask.dtype != bool:
            if not np.isin(mask, (0, 1)).all():
                raise ValueError("attention must be a bool mask (or 0/1 values)")
            mask = mask.astype(bool)
        if len(mask) == cfg.sim.observation_points and len(mask) != len(points):
            points = env.observation().dough_points.astype(np.float64)
        elif len(mask) != len(points):
            raise ValueError(
                f"attention has {len(mask)} values; expected one per particle ({len(points)}) or per "
                f"observation point ({cfg.sim.observation_points})"
            )
        if not mask.any():
            raise ValueError("attention selects no dough")
    attended = points[mask]
    destinations: tuple[np.ndarray, ...] = ()
    if target is not None:
        destinations = tuple(_destinations(points, mask, _as_cloud(target, "target_points"), cfg,
                                           skill.entities_out))
    centre = attended.mean(axis=0)
    bottom = min(float(np.percentile(attended[:, 1], 1.0)), _support_y(env, centre[0], centre[2]))
    return _Scene(points=points, attended=attended, destinations=destinations, bottom=bottom,
                  top=float(attended[:, 1].max()), top_all=float(points[:, 1].max()))


def _destinations(points: np.ndarray, mask: np.ndarray, target: np.ndarray, cfg: TaskConfig,
                  keep: int) -> list[np.ndarray]:
    """Target pieces for the attended dough: those not claimed by an unattended current piece.

    Each unattended current piece (largest first) removes the target piece nearest its centre,
    as long as more than ``keep`` (the skill's ``entities_out``) target pieces are left.
    """
    goal = _entities(target, cfg)
    if mask.all() or len(goal) <= keep:
        return goal
    try:
        labels = label_entities(points, eps=cfg.data.dbscan_eps, min_samples=cfg.data.dbscan_min_samples,
                                min_points=cfg.data.dbscan_min_points)
    except ValueError:
        return goal
    unattended = [points[labels == k] for k in np.unique(labels) if mask[labels == k].mean() < 0.5]
    remaining = list(goal)
    for piece in sorted(unattended, key=len, reverse=True):
        if len(remaining) <= keep:
            break
        centre = piece.mean(axis=0)
        nearest = int(np.argmin([np.linalg.norm(g.mean(axis=0) - centre) for g in remaining]))
        remaining.pop(nearest)
    return remaining


# ----------------------------------------------------------------------------- motion
class _Motion:
    """Kinematic model of one tool that records the actions moving it (env_spec 1.5 semantics).

    Per environment step an action ``a`` (clipped to [-1, 1]) moves a knife, box or gripper by
    ``a[:3] * scale`` and turns it by the axis-angle ``a[3:6] * scale`` (box: world frame; gripper:
    body frame); a positive gripper gap action closes by ``a[6] * scale``; a rolling pin rolls by
    ``a0 * scale`` radians about its axis (moving ``radius`` times that across), lifts by
    ``a2 * scale`` and slides by ``a3 * scale``. Like the engine, a step is integrated in
    ``substeps_per_step`` equal parts, each clipping the position to the tool's bounds and the gap to
    [min_gap, max_gap].
    """

    def __init__(self, env: DoughEnv, tool_name: str, n_steps: int):
        self.tool = env.tool(tool_name)
        self.scales = np.asarray(self.tool.action_scales, dtype=np.float64)
        pose = env.tool_poses()[tool_name]
        self.pos = np.asarray(pose.pos, dtype=np.float64)
        self.rot = np.asarray(pose.rot, dtype=np.float64)
        self.gap = float(pose.gap)
        self.n_steps = n_steps
        self.substeps = env.cfg.sim.substeps_per_step
        self.actions: list[np.ndarray] = []

    @property
    def left(self) -> int:
        return self.n_steps - len(self.actions)

    @property
    def yaw(self) -> float:
        return _yaw_of(self.rot)

    @property
    def R(self) -> np.ndarray:
        return _rotation(self.rot)

    def finish(self) -> np.ndarray:
        out = np.zeros((self.n_steps, len(self.scales)), np.float32)
        if self.actions:
            out[: len(self.actions)] = np.asarray(self.actions, np.float32)
        return out

    def clip_pos(self, pos) -> np.ndarray:
        return np.clip(np.asarray(pos, dtype=np.float64), self.tool.lower_bound, self.tool.upper_bound)

    def step(self, action) -> bool:
        """Record one action and advance the model; False once the step budget is used up."""
        if self.left <= 0:
            return False
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        a[self.scales == 0.0] = 0.0
        self.actions.append(a)
        d = a * self.scales / self.substeps  # the engine spreads a step's motion over its substeps
        kind = self.tool.kind
        for _ in range(self.substeps):
            if kind == "rolling_pin":
                axis = _rotation(self.rot) @ np.array([0.0, 0.0, 1.0])
                direction = np.cross([0.0, 1.0, 0.0], axis)
                self.pos = self.pos + direction * (d[0] * self.tool.radius + d[3]) + np.array([0.0, d[2], 0.0])
                self.rot = _quat_mul(_quat_mul(_axis_angle_quat(np.array([0.0, -d[1], 0.0])), self.rot),
                                     _axis_angle_quat(np.array([0.0, 0.0, d[0]])))
            else:
                self.pos = self.pos + d[:3]
                if kind == "box":
                    self.rot = _quat_mul(_axis_angle_quat(d[3:6]), self.rot)
                elif kind == "gripper":
                    self.rot = _quat_mul(self.rot, _axis_angle_quat(d[3:6]))
                    self.gap = float(np.clip(self.gap - d[6], self.tool.min_gap, self.tool.max_gap))
            self.rot = self.rot / np.linalg.norm(self.rot)
            self.pos = self.clip_pos(self.pos)
        return True

    def wait(self, n: int) -> None:
        for _ in range(max(int(n), 0)):
            self.step(np.zeros(len(self.scales)))

    def move(self, pos=None, gap: float | None = None, yaw: float | None = None, speed: float = 1.0,
             ease: int = 0, ease_out: int | None = None) -> None:
        """A straight segment to ``pos`` (and ``gap``; box: world ``yaw``), as fast as ``speed`` allows.

        The speed ramps up linearly over ``ease`` steps and down over ``ease_out`` steps (default
        ``ease``): dough resting on a tool leaves it when the tool stops faster than gravity, and
        dough pushed along the floor slides on when the pusher stops faster than friction would.
        Dimensions without an action (scale 0) are left as they are.
        """
        units = np.zeros(len(self.scales))  # total action (in units of one full step) per dimension
        if pos is not None:
            delta = self.clip_pos(pos) - self.pos
            for i in range(3):
                if self.tool.kind != "rolling_pin" and self.scales[i] > 0:
                    units[i] = delta[i] / self.scales[i]
        if gap is not None and self.tool.kind == "gripper" and self.scales[6] > 0:
            g = float(np.clip(gap, self.tool.min_gap, self.tool.max_gap))
            units[6] = -(g - self.gap) / self.scales[6]
        if yaw is not None and self.tool.kind == "box" and self.scales[4] > 0:
            units[4] = _half_plate_turn(yaw - self.yaw) / self.scales[4]
        self._segment(units, speed, ease, ease if ease_out is None else ease_out)

    def turn_about_vertical(self, angle: float, speed: float = 1.0) -> bool:
        """Turn a gripper by ``angle`` about world y with its actuated body axis that is vertical."""
        if self.tool.kind != "gripper":
            return False
        R = self.R
        for j in range(3):
            alignment = float(R[1, j])  # world y component of body axis j
            if self.scales[3 + j] > 0 and abs(alignment) > 0.9:
                units = np.zeros(len(self.scales))
                units[3 + j] = math.copysign(angle, alignment) / self.scales[3 + j]
                self._segment(units, speed)
                return True
        return False

    def _segment(self, units: np.ndarray, speed: float, ease_in: int = 0, ease_out: int = 0) -> None:
        """Steps whose actions sum to ``units``: at most ``speed`` per step, ramped at both ends."""
        largest = float(np.abs(units).max()) if len(units) else 0.0
        if largest < 1e-6:
            return
        ramp_in = np.arange(1, ease_in + 1) / (ease_in + 1)
        ramp_out = np.arange(ease_out, 0, -1) / (ease_out + 1)
        cruise = max(0, math.ceil(largest / speed - ramp_in.sum() - ramp_out.sum() - 1e-6))
        weights = np.concatenate([ramp_in, np.ones(cruise), ramp_out])
        for w in weights / weights.sum():
            if not self.step(units * w):
                return


# ----------------------------------------------------------------------------- scripts
def _cut_plan(scene: _Scene) -> tuple[float, list[np.ndarray]]:
    """The cut x and the two target pieces (left, right; empty without a two-piece target).

    The cut splits the attended dough at the target's length ratio: x = left end + length x
    (left length / (left + right length)), which is the left end plus the target's left length
    when the dough is as long as the two target pieces together (appendix 3.1).
    """
    x_lo, x_hi = _extent(scene.attended[:, 0])
    pieces = list(scene.destinations)
    if len(pieces) > 2:  # the two target pieces nearest the attended dough
        centre = scene.centre
        pieces.sort(key=lambda p: float(np.linalg.norm(p.mean(axis=0)[[0, 2]] - centre[[0, 2]])))
        pieces = pieces[:2]
    if len(pieces) < 2:
        return 0.5 * (x_lo + x_hi), []
    pieces.sort(key=lambda p: float(p[:, 0].mean()))
    lengths = [np.subtract(*_extent(p[:, 0])[::-1]) for p in pieces]
    ratio = lengths[0] / max(lengths[0] + lengths[1], 1e-9)
    return x_lo + ratio * (x_hi - x_lo), pieces


def _knife_safe_y(tool: ToolConfig, scene: _Scene) -> float:
    return max(tool.position[1], scene.top + tool.blade_depth + KNIFE_CLEARANCE)


def _cut_start(env: DoughEnv, tool_name: str, scene: _Scene) -> ToolPose:
    tool = env.tool(tool_name)
    centre = scene.centre
    return ToolPose(pos=(centre[0], _knife_safe_y(tool, scene), centre[2]), rot=env.tool_poses()[tool_name].rot)


def _cut(env: DoughEnv, m: _Motion, scene: _Scene) -> None:
    """Above the cut x, down through the dough at ``CUT_SPEED`` to ``CUT_BELOW_BOTTOM`` under its
    bottom, push the piece(s) that must travel towards their target centres, lift."""
    tool = m.tool
    cut_x, pieces = _cut_plan(scene)
    # Cut in the middle of a grid cell: with a grid column on the knife's mid-plane, the direction
    # in which the simulator expels the dough there is arbitrary, and the whole dough drifts
    # (measured at grid 48: cuts on a column lost 0.3-0.75 of the EMD, cuts between gained 0.4-0.6).
    dx = 1.0 / env.cfg.sim.n_grid
    cut_x = (math.floor(cut_x / dx) + 0.5) * dx
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
        for push in pushes:
            m.move(pos=(cut_x + push, cut_y, m.pos[2]), ease=2,
                   ease_out=_braking_steps(env, abs(cut_x + push - m.pos[0]), speed))
    m.move(pos=(m.pos[0], safe_y, m.pos[2]))


@dataclass(frozen=True)
class _PushLine:
    start: np.ndarray  # pusher centre (3,) at contact height behind the dough, before the push
    end: np.ndarray  # pusher centre (3,) when the dough's centre has reached the target's
    yaw: float  # plate heading facing the push direction
    direction: np.ndarray  # unit (3,) horizontal push direction
    back: float  # extent of the dough behind its centre, along the push direction


def _push_line(tool: ToolConfig, scene: _Scene, direction: np.ndarray | None, yaw: float | None = None
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
    yaw = _half_plate_turn(face_yaw) if yaw is None else yaw
    off = _half_plate_turn(yaw - face_yaw)
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


def _push_start(env: DoughEnv, tool_name: str, scene: _Scene) -> ToolPose:
    tool = env.tool(tool_name)
    line = _push_line(tool, scene, None)
    if line is None:  # no target: the +x side, facing -x (env_spec 2.5)
        line = _push_line(tool, scene, np.array([-1.0, 0.0, 0.0]), yaw=0.0)
    pose = ToolPose(pos=tuple(line.start), rot=_yaw_quat(line.yaw))
    for extra in np.arange(0.0, 0.1, 0.01):  # back off until clear of every particle
        pose = ToolPose(pos=tuple(line.start - line.direction * extra), rot=_yaw_quat(line.yaw))
        if not _collides(tool, pose, scene.points):
            return pose
    raised = np.array(pose.pos)
    raised[1] = scene.top_all + tool.half_extents[1] + CLEARANCE
    return ToolPose(pos=tuple(raised), rot=pose.rot)


def _push(env: DoughEnv, m: _Motion, scene: _Scene) -> None:
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
    behind = along < -line.back - 0.5 * hx and across < 0.5 * hz and abs(m.pos[1] - line.start[1]) < 0.02
    if not behind:  # approach: up, over the start (turning towards the target meanwhile), down
        safe_y = scene.top_all + _world_half_y(tool, m.rot) + CLEARANCE
        if m.pos[1] < safe_y:
            m.move(pos=(m.pos[0], safe_y, m.pos[2]))
        aligned = _push_line(tool, scene, None)
        travel = np.abs((aligned.start - m.pos)[[0, 2]]) / np.maximum(m.scales[[0, 2]], 1e-9)
        max_turn = math.ceil(float(travel.max())) * m.scales[4]  # turn only while travelling
        turn = float(np.clip(_half_plate_turn(aligned.yaw - m.yaw), -max_turn, max_turn))
        line = _push_line(tool, scene, None, yaw=m.yaw + turn)
        m.move(pos=(line.start[0], safe_y, line.start[2]), yaw=m.yaw + turn)
        m.move(pos=line.start)
        line = _push_line(tool, scene, None, yaw=m.yaw)
    distance = float(np.linalg.norm((line.end - m.pos)[[0, 2]]))
    m.move(pos=line.end, ease=2, ease_out=_braking_steps(env, distance, max(tool.action_scales[:3])))


def _gripper_frame(m_rot) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal unit vectors: the gripper's gap axis and the one across it."""
    axis = _rotation(m_rot)[:, 0].copy()
    axis[1] = 0.0
    axis /= max(float(np.linalg.norm(axis)), 1e-9)
    return axis, np.cross([0.0, 1.0, 0.0], axis)


def _width_along(points: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> float:
    proj = (points - centre) @ axis
    return 2.0 * float(np.percentile(np.abs(proj), EXTENT_PERCENTILES[1]))


def _grip_geometry(tool: ToolConfig, rot, scene: _Scene) -> tuple[float, float, float, float]:
    """(open gap, grip gap, grip height, safe height) of a gripper at rotation ``rot``."""
    axis, _ = _gripper_frame(rot)
    width = _width_along(scene.attended, scene.centre, axis)
    thick = 2.0 * tool.half_extents[0]
    open_gap = float(np.clip(width + thick + 2 * GRIP_MARGIN, tool.min_gap, tool.max_gap))
    grip_gap = float(np.clip(GRIP_SQUEEZE * width + thick, tool.min_gap, tool.max_gap))
    half_y = _world_half_y(tool, rot)
    return open_gap, grip_gap, scene.bottom - FINGER_SINK + half_y, scene.top_all + half_y + CLEARANCE


def _gripper_start(env: DoughEnv, tool_name: str, scene: _Scene) -> ToolPose:
    tool = env.tool(tool_name)
    current = env.tool_poses()[tool_name]
    open_gap, _, grip_y, safe_y = _grip_geometry(tool, current.rot, scene)
    centre = scene.centre
    pose = ToolPose(pos=(centre[0], grip_y, centre[2]), rot=current.rot, gap=open_gap)
    if _collides(tool, pose, scene.points):
        pose = ToolPose(pos=(centre[0], safe_y, centre[2]), rot=current.rot, gap=open_gap)
    return pose


def _gripper_approach(m: _Motion, scene: _Scene, open_gap: float, grip_y: float, safe_y: float) -> None:
    """Unless already straddling the dough at grip height: open, up, over the dough, down."""
    centre = scene.centre
    axis, _ = _gripper_frame(m.rot)
    inner = m.gap - 2.0 * m.tool.half_extents[0]
    around = (np.linalg.norm((m.pos - centre)[[0, 2]]) < 0.02 and abs(m.pos[1] - grip_y) < 0.03
              and inner >= _width_along(scene.attended, centre, axis))
    if around:
        return
    if m.gap < open_gap:
        m.move(gap=open_gap)
    if not (np.linalg.norm((m.pos - centre)[[0, 2]]) < 0.02):
        if m.pos[1] < safe_y and m.scales[1] > 0:
            m.move(pos=(m.pos[0], safe_y, m.pos[2]))
        m.move(pos=(centre[0], m.pos[1], centre[2]))
    m.move(pos=(m.pos[0], grip_y, m.pos[2]))


def _rearrange(env: DoughEnv, m: _Motion, scene: _Scene) -> None:
    """Straddle the piece (approach if needed), close to ``GRIP_SQUEEZE`` of its width, move the
    piece's centre to the target's horizontally, open, lift."""
    goal = scene.destination
    open_gap, grip_gap, grip_y, safe_y = _grip_geometry(m.tool, m.rot, scene)
    _gripper_approach(m, scene, open_gap, grip_y, safe_y)
    m.move(gap=grip_gap)
    if goal is not None:
        shift = goal.mean(axis=0) - scene.centre
        m.move(pos=(m.pos[0] + shift[0], m.pos[1], m.pos[2] + shift[2]))
    m.move(gap=open_gap)
    m.move(pos=(m.pos[0], safe_y, m.pos[2]))


def _pin_frame(rot) -> np.ndarray:
    """Horizontal unit direction a rolling pin travels in when it rolls forward."""
    axis = _rotation(rot) @ np.array([0.0, 0.0, 1.0])
    direction = np.cross([0.0, 1.0, 0.0], axis)
    return direction / max(float(np.linalg.norm(direction)), 1e-9)


def _spread_start(env: DoughEnv, tool_name: str, scene: _Scene) -> ToolPose:
    tool = env.tool(tool_name)
    current = env.tool_poses()[tool_name]
    centre = scene.centre
    y = max(scene.top + tool.radius + ROLL_CLEARANCE, tool.lower_bound[1])
    return ToolPose(pos=(centre[0], y, centre[2]), rot=current.rot)


def _spread(env: DoughEnv, m: _Motion, scene: _Scene) -> None:
    """Press straight down to the target's thickness, then roll to and fro about the target's centre.

    The pin's bottom goes to the dough's support height plus the target's thickness. The to-and-fro
    spans ``ROLL_SPAN`` of the target's half length on each side of its centre and rolls without
    slipping: with RollingPinExt kinematics (env_spec 1.5) a roll action alone moves the pin's
    bottom at twice the pin's speed, which flings the dough ahead, so the roll (a0) is combined
    with a slide (a3) that cancels the slip. Wide passes push the dough out of the target instead
    of flattening it (measured at grids 32 and 48: pressing does most of the spreading).
    """
    tool = m.tool
    r = tool.radius
    direction = _pin_frame(m.rot)
    goal = scene.destination if scene.destination is not None else scene.attended
    g_lo, g_hi = _extent(goal[:, 1])
    press_y = max(scene.bottom + max(g_hi - g_lo, 1e-3) + r, tool.lower_bound[1])
    centre = scene.centre
    support, on_tool = _support(env, centre[0], centre[2])
    if on_tool:
        # Dough squeezed into less than a grid cell between the pin and a static tool (the
        # cutting board) is thrown out of the gap, and the simulation can blow up.
        press_y = max(press_y, support + PIN_GAP_CELLS / env.cfg.sim.n_grid + r)
    origin = m.pos.copy()
    s_lo, s_hi = _extent((goal - origin) @ direction)
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


def _spatula_heights(env: DoughEnv, tool: ToolConfig, rot, scene: _Scene, goal_centre: np.ndarray | None
                     ) -> tuple[float, float, float]:
    """(under-dough height, carrying height, height resting at the goal) of a spatula's centre."""
    half_y = _world_half_y(tool, rot)
    under = scene.bottom - half_y - 0.002
    centre = scene.centre
    path = [centre] if goal_centre is None else [centre + t * (goal_centre - centre) for t in np.linspace(0, 1, 21)]
    highest = max(_support_y(env, p[0], p[2]) for p in path)
    carry = max(highest, scene.bottom) + half_y + SPATULA_CLEARANCE
    rest = (_support_y(env, goal_centre[0], goal_centre[2]) if goal_centre is not None else scene.bottom) + half_y
    return under, carry, rest


def _spatula_start(env: DoughEnv, tool_name: str, scene: _Scene) -> ToolPose:
    tool = env.tool(tool_name)
    current = env.tool_poses()[tool_name]
    under, _, _ = _spatula_heights(env, tool, current.rot, scene, None)
    centre = scene.centre
    for extra in np.arange(0.0, 0.03, 0.005):  # lower until clear of the dough
        pose = ToolPose(pos=(centre[0], max(under - extra, tool.lower_bound[1]), centre[2]), rot=current.rot)
        if not _collides(tool, pose, scene.points):
            return pose
    return pose


def _lift(env: DoughEnv, m: _Motion, scene: _Scene) -> None:
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
        safe_y = scene.top_all + _world_half_y(tool, m.rot) + CLEARANCE
        if abs(m.pos[0] - beside) > 0.01:
            m.move(pos=(m.pos[0], max(m.pos[1], safe_y), m.pos[2]))
            m.move(pos=(beside, m.pos[1], centre[2]))
        m.move(pos=(beside, under, centre[2]))
        m.move(pos=(centre[0], under, centre[2]))
    m.move(pos=(m.pos[0], carry, m.pos[2]), ease=SPATULA_EASE)
    if goal_centre is not None:
        shift = goal_centre - centre
        m.move(pos=(m.pos[0] + shift[0], carry, m.pos[2] + shift[2]), ease=SPATULA_EASE)
        m.move(pos=(m.pos[0], rest, m.pos[2]), ease=SPATULA_EASE)


def _gather(env: DoughEnv, m: _Motion, scene: _Scene) -> None:
    """Squeeze along the gap axis to the target's width, then (if the pile is still wider than the
    target across) open around the pile, turn 90 degrees and squeeze across; finally let go a little.
    Squeezing runs at ``GATHER_SPEED``: faster, or holding the squeeze, squirts dough through the fingers.
    """
    tool = m.tool
    centre = scene.centre
    goal = scene.destination if scene.destination is not None else scene.attended
    goal_centre = goal.mean(axis=0)
    thick = 2.0 * tool.half_extents[0]
    open_gap, _, grip_y, safe_y = _grip_geometry(tool, m.rot, scene)
    _gripper_approach(m, scene, open_gap, grip_y, safe_y)
    axis, across = _gripper_frame(m.rot)
    target_along = _width_along(goal, goal_centre, axis)
    target_across = _width_along(goal, goal_centre, across)
    m.move(gap=target_along + thick, speed=GATHER_SPEED)  # squeeze along the gap axis to the target's width
    width_across = _width_along(scene.attended, centre, across)
    if width_across > target_across + GATHER_TOLERANCE:
        # Open just enough for the fingers to turn around the squeezed pile, turn, squeeze across.
        rel = scene.attended - centre
        q1 = np.minimum(np.abs(rel @ axis), 0.5 * target_along)
        radius = float(np.percentile(np.hypot(q1, rel @ across), EXTENT_PERCENTILES[1]))
        m.move(gap=2.0 * (radius + 0.5 * thick + GRIP_MARGIN))
        if m.turn_about_vertical(0.5 * math.pi):
            m.move(gap=target_across + thick, speed=GATHER_SPEED)
    if GATHER_RELEASE:
        m.move(gap=m.gap + GATHER_RELEASE)


_SCRIPTS: dict[str, Callable[[DoughEnv, _Motion, _Scene], None]] = {
    "cut": _cut,
    "push": _push,
    "rearrange": _rearrange,
    "spread": _spread,
    "lift": _lift,
    "move": _lift,
    "gather": _gather,
}

_START_POSES: dict[str, Callable[[DoughEnv, str, _Scene], ToolPose]] = {
    "cut": _cut_start,
    "push": _push_start,
    "rearrange": _gripper_start,
    "spread": _spread_start,
    "lift": _spatula_start,
    "move": _spatula_start,
    "gather": _gripper_start,
}
