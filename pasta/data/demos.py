"""One demonstration: a single skill from a generated configuration to its target.

A demo starts from the configuration, settles the dough, places the skill's tool
(env_spec.md section 2.5), computes the scripted skill's actions and, with
``method="gbto"``, refines them by gradient-based trajectory optimisation. The
chosen actions are then replayed in the ordinary (hard-contact) simulator while
the observations are recorded, and the trajectory is written as one ``.npz``.
"""

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pasta.config.schema import DEMO_METHODS, TaskConfig
from pasta.data.aim_search import search_aim
from pasta.data.configurations import SkillProblem
from pasta.data.gbto import GBTOSettings, optimise_actions
from pasta.data.skills import Aim, place_tool_for_skill, scripted_actions
from pasta.data.storage import validate_trajectory, write_trajectory
from pasta.geometry.distances import earth_movers_distance, normalised_performance
from pasta.geometry.entities import label_entities
from pasta.sim.envs import make_env
from pasta.sim.envs.base import DoughEnv

METHODS = DEMO_METHODS


@dataclass(frozen=True)
class DemoResult:
    """What a demo achieved; ``scripted_performance`` is the warm start's, for comparison."""

    path: Path
    trajectory_id: int
    configuration_id: int
    skill: str
    method: str
    emd_initial: float
    emd_final: float
    normalised_performance: float
    scripted_performance: float
    gbto_performance: float | None
    gbto_losses: tuple[float, ...]
    seconds: float


def check_method(method: str) -> str:
    if method not in METHODS:
        raise ValueError(f"unknown demo method {method!r}; choose one of {list(METHODS)}")
    return method


def attention_mask(points: np.ndarray, attention: tuple[int, ...], cfg: TaskConfig) -> np.ndarray:
    """(P,) bool mask of the observation points in the attended entities (DBSCAN labels, section 2.2)."""
    labels = label_entities(points, eps=cfg.data.dbscan_eps, min_samples=cfg.data.dbscan_min_samples,
                            min_points=cfg.data.dbscan_min_points)
    return np.isin(labels, np.asarray(attention, dtype=labels.dtype))


def contact_reach(cfg: TaskConfig, tool_name: str) -> float:
    """Distance from a tool's reference point to the dough at which the tool touches it."""
    tool = next(t for t in cfg.tools if t.name == tool_name)
    if tool.kind == "knife":
        return tool.blade_depth
    if tool.kind == "rolling_pin":
        return tool.radius
    if tool.kind == "box":
        return tool.half_extents[1]
    return 0.02


def record(env: DoughEnv, actions: np.ndarray, cfg: TaskConfig) -> dict[str, np.ndarray]:
    """Replay ``actions`` (T, A) from the environment's state; observations of all T + 1 frames."""
    frames = [env.observation()]
    for action in actions:
        frames.append(env.step(action))
    dough = np.stack([f.dough_points for f in frames]).astype(np.float32)
    labels = np.stack([
        label_entities(points, eps=cfg.data.dbscan_eps, min_samples=cfg.data.dbscan_min_samples,
                       min_points=cfg.data.dbscan_min_points)
        for points in dough
    ]).astype(np.int16)
    return {
        "dough_points": dough,
        "tool_states": np.stack([f.tool_states for f in frames]).astype(np.float32),
        "tool_points": np.stack([np.concatenate(list(f.tool_points.values())) for f in frames]).astype(np.float32),
        "actions": np.asarray(actions, np.float32),
        "labels": labels,
    }


def shape_distance(points: np.ndarray, target: np.ndarray, seed: int) -> float:
    """Exact EMD between the observation points and as many target points (the task metric)."""
    return earth_movers_distance(points, target[: len(points)], rng=np.random.default_rng(seed))


# Config sections that no demonstration reads: changing them keeps the demonstrations already made.
DEMONSTRATION_IRRELEVANT = ("train", "policy", "plan", "eval")


def demonstration_key(cfg: TaskConfig, method: str, seed: int) -> str:
    """A digest of all that decides a demonstration: the resolved config less ``DEMONSTRATION_IRRELEVANT``,
    the method and the seed. Stored with each demonstration; a rerun reuses a file only under an equal key."""
    decided = {"config": cfg.model_dump(mode="json", exclude=set(DEMONSTRATION_IRRELEVANT)),
               "method": method, "seed": int(seed)}
    return hashlib.sha256(json.dumps(decided, sort_keys=True).encode()).hexdigest()[:16]


def generate_demo(cfg: TaskConfig, problem: SkillProblem, trajectory_id: int, method: str, out_dir: Path,
                  seed: int = 0) -> DemoResult:
    """Make, replay and store one demo; returns where it went and how well it did."""
    check_method(method)
    started = time.perf_counter()
    skill = next(s for s in cfg.skills if s.name == problem.skill)
    n_steps = cfg.sim.steps_per_skill
    target = np.asarray(problem.target, np.float32)

    env = make_env(cfg)
    env.reset(problem.initial)
    env.settle(cfg.sim.settle_steps)
    mask = attention_mask(env.observation().dough_points, problem.attention, cfg)
    aim = None
    if cfg.data.aim_search_rollouts > 1:
        settled = env.get_state()
        aim = search_aim(env, problem.skill, target, mask, cfg.data.aim_search_rollouts, settle_steps=0).aim
        env.set_state(settled)
    place_tool_for_skill(env, problem.skill, mask, target, aim)
    start_state = env.get_state()
    emd_initial = shape_distance(env.observation().dough_points, target, seed)
    warm_start = scripted_actions(env, problem.skill, target, mask, n_steps, aim)
    env.set_state(start_state)

    scripted = record(env, warm_start, cfg)
    scripted_perf = normalised_performance(emd_initial, shape_distance(scripted["dough_points"][-1], target, seed))
    losses: tuple[float, ...] = ()
    optimised_perf: float | None = None
    chosen = scripted
    if method == "gbto":
        grad_env = make_env(cfg, differentiable=True)
        grad_env.set_state(start_state)
        settings = GBTOSettings(iterations=cfg.data.gbto_iterations, lr=cfg.data.gbto_lr,
                                velocity_weight=cfg.data.gbto_velocity_weight,
                                softness=cfg.sim.optimisation_contact_softness)
        tool_index = [t.name for t in cfg.tools].index(skill.tool)
        result = optimise_actions(grad_env.simulator, grad_env.simulator.get_state(), target, tool_index,
                                  contact_reach(cfg, skill.tool), warm_start, settings, np.random.default_rng(seed))
        losses = tuple(float(v) for v in result.losses)
        env.set_state(start_state)
        optimised = record(env, result.actions, cfg)
        optimised_perf = normalised_performance(
            emd_initial, shape_distance(optimised["dough_points"][-1], target, seed))
        if optimised_perf >= scripted_perf:
            chosen = optimised
    emd_final = shape_distance(chosen["dough_points"][-1], target, seed)
    performance = normalised_performance(emd_initial, emd_final)
    arrays = {**chosen, "target_points": target}
    validate_trajectory(arrays)
    path = Path(out_dir) / f"trajectory_{trajectory_id:06d}.npz"
    metadata = {
        "task": cfg.task, "profile": cfg.profile, "trajectory_id": trajectory_id,
        "configuration_id": problem.config_id, "skill": problem.skill, "tool": skill.tool, "method": method,
        "emd_initial": emd_initial, "emd_final": emd_final, "normalised_performance": performance,
        "scripted_normalised_performance": scripted_perf, "gbto_normalised_performance": optimised_perf,
        "gbto_losses": list(losses), "seed": seed,
        "aim_shift": list((aim or Aim()).shift), "aim_scale": list((aim or Aim()).scale),
        "demonstration_key": demonstration_key(cfg, method, seed),
    }
    write_trajectory(path, arrays, metadata)
    return DemoResult(path, trajectory_id, problem.config_id, problem.skill, method, emd_initial, emd_final,
                      performance, scripted_perf, optimised_perf, losses, time.perf_counter() - started)
