"""What every script reads: the skill's configuration, the dough and subgoal (:class:`Scene`), geometry.

Target pieces are found by DBSCAN (:func:`~pasta.geometry.entities.label_entities`, the task's
``cfg.data`` parameters). Pieces the attention leaves out are expected to stay where they are: each
is matched to its nearest target piece (by centre), and the target pieces left over are where
the attended dough must go (:func:`analyse`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from pasta.config.schema import SkillConfig, TaskConfig, ToolConfig
from pasta.data.skills.aim import Aim
from pasta.geometry.entities import label_entities, split_entities
from pasta.sim.envs.base import DoughEnv, ToolPose
from pasta.sim.quaternion import quat_to_matrix_np
from pasta.sim.tool_points import tool_world_bounds, world_sdf

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


# ---------------------------------------------------------------------- configuration
def has_script(cfg: TaskConfig, skill: SkillConfig) -> bool:
    kind = SKILL_TOOL_KINDS.get(skill.name)
    tool = next((t for t in cfg.tools if t.name == skill.tool), None)
    return kind is not None and tool is not None and tool.kind == kind


def skill_config(cfg: TaskConfig, skill: str) -> SkillConfig:
    names = [s.name for s in cfg.skills]
    if skill not in names:
        raise ValueError(f"task {cfg.task} has no skill {skill!r}; its skills are {names}")
    skill_cfg = cfg.skills[names.index(skill)]
    if not has_script(cfg, skill_cfg):
        tool = next(t for t in cfg.tools if t.name == skill_cfg.tool)
        expected = SKILL_TOOL_KINDS.get(skill)
        raise ValueError(
            f"no script for skill {skill!r} with a {tool.kind!r} tool ({tool.name!r}); scripted skills: "
            + ", ".join(f"{name} ({kind})" for name, kind in SKILL_TOOL_KINDS.items())
            + (f"; {skill!r} needs a {expected!r}" if expected else "")
        )
    return skill_cfg


# --------------------------------------------------------------------------- geometry
def as_cloud(points, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
        raise ValueError(f"{name} must have shape (P, 3) with P >= 1, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has non-finite coordinates")
    return arr


def extent(values: np.ndarray) -> tuple[float, float]:
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


def rotation(rot: Sequence[float]) -> np.ndarray:
    return quat_to_matrix_np(np.asarray(rot, dtype=np.float64))


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    """Rotation by ``yaw`` about world y: local x goes to (cos yaw, 0, -sin yaw)."""
    return (math.cos(0.5 * yaw), 0.0, math.sin(0.5 * yaw), 0.0)


def yaw_of(rot: Sequence[float]) -> float:
    """Heading of the tool's local x axis about world y (atan2(-x_z, x_x))."""
    R = rotation(rot)
    return math.atan2(-R[2, 0], R[0, 0])


def half_plate_turn(angle: float) -> float:
    """An angle wrapped to [-pi/2, pi/2): a plate or a gripper looks the same turned by pi."""
    return (angle + 0.5 * math.pi) % math.pi - 0.5 * math.pi


def world_half_y(tool: ToolConfig, rot: Sequence[float]) -> float:
    """Half height of one box (spatula, pusher, gripper finger) at this rotation."""
    return float((np.abs(rotation(rot)) @ np.asarray(tool.half_extents))[1])


def support(env: DoughEnv, x: float, z: float) -> tuple[float, bool]:
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


def support_y(env: DoughEnv, x: float, z: float) -> float:
    """Height dough rests at over (x, z): the floor, or the top of a static box (cutting board) there."""
    return support(env, x, z)[0]


def collides(tool: ToolConfig, pose: ToolPose, points: np.ndarray, margin: float = 0.0) -> bool:
    if len(points) == 0:
        return False
    return bool((world_sdf(tool, points, pose.pos, pose.rot, pose.gap) < margin).any())


# ------------------------------------------------------------------------------ scene
@dataclass(frozen=True)
class Scene:
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

    def aimed(self, aim: Aim | None) -> Scene:
        """The scene with its destination pieces moved by ``aim`` (the same scene without one)."""
        if aim is None or aim.is_identity:
            return self
        return replace(self, destinations=aim.apply(self.destinations))


def analyse(env: DoughEnv, skill: SkillConfig, target: np.ndarray | None, attention) -> Scene:
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
        destinations = tuple(_destinations(points, mask, as_cloud(target, "target_points"), cfg,
                                           skill.entities_out))
    centre = attended.mean(axis=0)
    bottom = min(float(np.percentile(attended[:, 1], 1.0)), support_y(env, centre[0], centre[2]))
    return Scene(points=points, attended=attended, destinations=destinations, bottom=bottom,
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
