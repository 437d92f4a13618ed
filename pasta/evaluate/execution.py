"""Run a plan in the simulator, skill by skill, open loop (model_spec §5.6; env_spec §2.5).

For each plan step ``h`` (skill ``k_h``, attention ``A_h``):

1. decode every latent of ``U^h`` to points (``bundle.vae.decode``); the first ``N_out`` are the new
   subgoals (the planner puts them first); with ``eval.final_subgoals: goal`` a new entity that no later step
   attends is handed its goal piece instead (:mod:`pasta.evaluate.goal_subgoals`);
2. skip the skill when the current dough already is the decoded ``U^h`` (as many pieces, Chamfer <
   ``SKIP_CHAMFER``);
3. find the attended dough (:func:`pasta.evaluate.selection.attended_mask`) and freeze its observation
   indices for the whole skill;
4. place the skill's tool next to it (:func:`pasta.data.skills.place_tool_for_skill`);
5. act for ``cfg.sim.steps_per_skill`` steps with the learned policy (closed loop on the frozen points
   resampled to ``cfg.policy.points`` every time it is asked, the tool's points and the stacked subgoals
   resampled once to as many; a policy with ``policy.chunk`` > 1 is asked every ``chunk`` steps and its
   actions are acted out in between; each action clipped to [-1, 1] and, with ``eval.policy_action_range:
   demonstrated``, to the range the skill's demonstrations span) or the scripted skill (open loop,
   toward the subgoals; appendix §3.1's real-robot executor);
6. ``cfg.sim.settle_steps`` zero-action steps, then park the tool at its back pose.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.data.aim_search import Rest, search_aim
from pasta.data.configurations import tool_clearance
from pasta.data.skills import place_tool_for_skill, scripted_actions, skill_tool
from pasta.evaluate.blowups import save_blowup
from pasta.evaluate.chunk_ensemble import ChunkEnsemble
from pasta.evaluate.encoding import segment
from pasta.evaluate.goal_subgoals import GoalSubgoal, step_subgoals
from pasta.evaluate.policy_action import PolicyInput, checked_action, policy_action, skill_action_range
from pasta.evaluate.selection import attended_mask
from pasta.geometry.distances import chamfer_distance
from pasta.geometry.entities import resample
from pasta.sim.engine import SimulationError
from pasta.sim.envs.base import DoughEnv, Observation
from pasta.sim.tool_points import world_sdf
from pasta.train.bundle import TrainedModels
from pasta.train.entities import decode_latents

if TYPE_CHECKING:
    from pasta.plan.result import Plan

__all__ = ["EXECUTORS", "SKIP_CHAMFER", "Execution", "StepRecord", "already_reached", "check_executor", "decode_set",
           "execute_plan", "executor_label", "park_tool", "policy_view", "run_skill"]

EXECUTORS = ("policy", "scripted")
SKIP_CHAMFER = 1e-3  # official exec_threshold: the dough already is the subgoal (squared Chamfer units)
PARK_RAISE = 0.02  # a parked tool is raised in these steps until it clears the dough


@dataclass(frozen=True, eq=False)
class StepRecord:
    """One executed plan step.

    Attributes:
        skill: the skill's name.
        subgoal_points: ``(K_h * M, 3)`` every decoded entity of ``U^h``, stacked (new subgoals first).
        new_subgoal_points: ``(Q, 3)`` the new subgoals the skill was handed, stacked (the policy's goal): the
            decoded ones (``N_out * M`` points), or goal pieces where ``eval.final_subgoals`` is ``goal``.
        attended: ``(P,)`` bool mask of the observation points the skill acted on (all False when skipped).
        skipped: the dough already matched ``U^h``, so no action was taken.
        observation: the observation after the skill, the settling and the tool reset.
    """

    skill: str
    subgoal_points: np.ndarray
    new_subgoal_points: np.ndarray
    attended: np.ndarray
    skipped: bool
    observation: Observation


@dataclass(frozen=True, eq=False)
class Execution:
    """Every executed step of a plan and the final observation.

    ``failure`` names the skill whose simulation blew up (with the simulator's message: step and value);
    that skill's effect is undone, the plan stops there and ``final`` is the state before the skill.
    """

    steps: tuple[StepRecord, ...]
    final: Observation
    failure: str | None = None


def executor_label(cfg: TaskConfig, executor: str) -> str:
    """The executor as runs are tagged: ``executor``, or for the policy executor with ``eval.scripted_skills``,
    ``policy+scripted:<skills>`` (e.g. ``policy+scripted:cut``), so that such a diagnostic run never counts as
    the learned policies' cell of the plan x executor matrix."""
    if executor == "policy" and cfg.eval.scripted_skills:
        return f"policy+scripted:{','.join(cfg.eval.scripted_skills)}"
    return executor


def check_executor(executor: str) -> str:
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; choose one of {list(EXECUTORS)}")
    return executor


def decode_set(bundle: TrainedModels, latents: torch.Tensor) -> np.ndarray:
    """``(K, D_z + 3)`` latents -> ``(K, M, 3)`` float32 decoded entity clouds."""
    latent_dim = bundle.vae.config.latent_dim
    u = latents.detach().float().cpu()
    if u.ndim != 2 or u.shape[1] != latent_dim + 3:
        raise ValueError(f"latents must have shape (K, {latent_dim + 3}), got {tuple(u.shape)}")
    return decode_latents(bundle.vae, u)


def park_tool(env: DoughEnv, tool_name: str) -> Observation:
    """Teleport a tool to its back pose, raised until it keeps ``tool_clearance`` from every particle.

    At coarse grids the dough sits higher than in the original, where some back poses (the knife's)
    would cut into it.
    """
    tool = env.tool(tool_name)
    back = env.back_pose(tool_name)
    particles = env.particles()
    x, y, z = back.pos
    clearance = tool_clearance(env.cfg)
    while y < tool.upper_bound[1] and world_sdf(tool, particles, (x, y, z), back.rot, back.gap).min() < clearance:
        y += PARK_RAISE
    return env.teleport_tool(tool_name, (x, min(y, tool.upper_bound[1]), z), back.rot, back.gap)


def already_reached(points: np.ndarray, labels: np.ndarray, subgoal_points: np.ndarray, n_entities: int) -> bool:
    """Whether the dough ``(P, 3)`` (DBSCAN ``labels``) already is the decoded subgoal set: as many pieces as
    its ``n_entities`` and Chamfer to the stacked ``(Q, 3)`` subgoal points below ``SKIP_CHAMFER``."""
    if int(np.unique(labels).size) != n_entities:
        return False
    with torch.no_grad():
        gap = chamfer_distance(torch.from_numpy(np.array(points, np.float32)),
                               torch.from_numpy(np.array(subgoal_points, np.float32)))
    return float(gap) < SKIP_CHAMFER


def policy_view(env: DoughEnv, tool: str, indices: np.ndarray, goal_points: np.ndarray, goal_latents: torch.Tensor,
                step: int, rng: np.random.Generator, previous_action: np.ndarray) -> PolicyInput:
    """What a skill's policy sees at ``step`` of the skill: the dough at the frozen observation ``indices``
    resampled to ``cfg.policy.points``, the tool's points and state, the ``goal_points`` (already resampled once
    per skill, as training builds its goal cloud), the phase ``step / steps_per_skill`` and the ``(A,)`` action
    applied at the step before (zeros at the first)."""
    obs = env.observation()
    return PolicyInput(
        obs_points=resample(obs.dough_points[indices], env.cfg.policy.points, rng),
        tool_points=obs.tool_points[tool],
        tool_state=obs.tool_states[env.tool_names.index(tool)],
        goal_points=goal_points,
        goal_latents=goal_latents,
        phase=step / env.cfg.sim.steps_per_skill,
        previous_action=np.asarray(previous_action, dtype=np.float32),
    )


def _run_policy(env: DoughEnv, bundle: TrainedModels, skill: str, tool: str, plan_step: int, indices: np.ndarray,
                goal_points: np.ndarray, goal_latents: torch.Tensor, rng: np.random.Generator) -> None:
    goal_points = resample(goal_points, env.cfg.policy.points, rng)  # one cloud of the new subgoals, as in training
    if env.cfg.policy.chunk_execution == "ensemble":
        _run_policy_ensembled(env, bundle, skill, tool, plan_step, indices, goal_points, goal_latents, rng)
        return
    action_range = skill_action_range(bundle, skill, env.cfg.eval.policy_action_range)
    chunk = np.zeros((0, env.action_dim))
    applied = np.zeros(env.action_dim, dtype=np.float32)
    for k in range(env.cfg.sim.steps_per_skill):
        if len(chunk) == 0:  # ask the policy; a chunking policy answers for several steps
            seen = policy_view(env, tool, indices, goal_points, goal_latents, k, rng, applied)
            chunk = policy_action(bundle, skill, seen).reshape(-1, env.action_dim)
        applied = checked_action(chunk[0], skill, plan_step, k, action_range)
        env.step(applied)
        chunk = chunk[1:]


def _run_policy_ensembled(env: DoughEnv, bundle: TrainedModels, skill: str, tool: str, plan_step: int,
                          indices: np.ndarray, goal_points: np.ndarray, goal_latents: torch.Tensor,
                          rng: np.random.Generator) -> None:
    """The policy asked at every step; each step acts the temporal ensemble of the chunks' predictions for it."""
    n_steps = env.cfg.sim.steps_per_skill
    ensemble = ChunkEnsemble(n_steps, env.action_dim, env.cfg.policy.ensemble_decay)
    action_range = skill_action_range(bundle, skill, env.cfg.eval.policy_action_range)
    applied = np.zeros(env.action_dim, dtype=np.float32)
    for k in range(n_steps):
        seen = policy_view(env, tool, indices, goal_points, goal_latents, k, rng, applied)
        ensemble.add(k, policy_action(bundle, skill, seen).reshape(-1, env.action_dim))
        applied = checked_action(ensemble.action(k), skill, plan_step, k, action_range)
        env.step(applied)


def run_skill(env: DoughEnv, bundle: TrainedModels | None, skill: str, plan_step: int, mask: np.ndarray,
              target: np.ndarray, executor: str, goal_points: np.ndarray, goal_latents: torch.Tensor | None,
              rng: np.random.Generator, rest: Rest | None = None) -> str | None:
    """One plan step in the simulator: place the skill's tool by the attended dough, act for the skill's budget
    (scripted toward ``target``, or the policy toward the new subgoals), settle. The tool is left where it is.

    Args:
        mask: ``(P,)`` bool over the observation points: the dough the skill acts on.
        target: ``(Q, 3)`` the whole scene after the skill (the scripted skills' subgoal).
        goal_points: ``(N_g, 3)`` the new subgoals stacked, and ``goal_latents`` ``(N_out, D_z + 3)`` their
            latents: what the policy sees (unused by the scripted skills; ``bundle`` may then be None).
        rest: the plan's remaining skills, scripted, for a scripted skill's aim search
            (``eval.aim_search_rollouts`` > 1; :func:`pasta.data.aim_search.search_aim`).

    Returns:
        None, or why the simulation blew up (step and value, and where it is kept for a replay without the
        models: :mod:`pasta.evaluate.blowups`); the state before the skill is then restored.
    """
    cfg = env.cfg
    before_skill = env.get_state()
    start, actions = None, []
    try:
        scripted = executor == "scripted" or skill in cfg.eval.scripted_skills
        if scripted and cfg.eval.aim_search_rollouts > 1:
            search_aim(env, skill, target, mask, cfg.eval.aim_search_rollouts, cfg.sim.settle_steps, rest)
            return None  # the environment is at the end of the best rollout, settled
        place_tool_for_skill(env, skill, mask, target)
        start = env.get_state()
        with env.logging_actions() as actions:
            if scripted:
                for action in scripted_actions(env, skill, target, mask):
                    env.step(action)
            else:
                if bundle is None:
                    raise ValueError(f"the policy executor needs trained models (skill {skill!r})")
                _run_policy(env, bundle, skill, skill_tool(cfg, skill).name, plan_step, np.flatnonzero(mask),
                            goal_points, goal_latents, rng)
            env.settle(cfg.sim.settle_steps)
    except SimulationError as error:
        kept = "" if start is None else f" (kept for replay: {save_blowup(cfg, start, actions, str(error))})"
        env.set_state(before_skill)
        return f"plan step {plan_step} ({skill}): {error}{kept}"
    return None


def execute_plan(cfg: TaskConfig, bundle: TrainedModels, env: DoughEnv, plan: Plan, executor: str,
                 rng: np.random.Generator, finished: Mapping[tuple[int, int], GoalSubgoal] | None = None
                 ) -> Execution:
    """Execute ``plan`` from the environment's current (settled) state, the one ``U^0`` was encoded from.

    ``finished``: goal pieces handed to the new entities no later step attends, keyed ``(h, i)`` (step, index among
    the step's new entities; :func:`pasta.evaluate.goal_subgoals.goal_subgoals`) in place of their decoded clouds.
    """
    check_executor(executor)
    finished = finished or {}
    latent_dim = bundle.vae.config.latent_dim
    records: list[StepRecord] = []
    for h, (skill, attention) in enumerate(zip(plan.skills, plan.attention, strict=True), start=1):
        tool = skill_tool(cfg, skill).name
        before, after = plan.latent_sets[h - 1], plan.latent_sets[h]
        n_out = after.shape[0] - (before.shape[0] - len(attention))
        decoded = decode_set(bundle, after)
        everything = decoded.reshape(-1, 3)
        points = np.asarray(env.observation().dough_points)
        labels = segment(cfg, points)
        if already_reached(points, labels, everything, after.shape[0]):
            records.append(StepRecord(skill, everything, decoded[:n_out].reshape(-1, 3), np.zeros(len(points), bool),
                                      True, env.observation()))
            continue
        centres = None if h == 1 else before[list(attention), latent_dim:].detach().cpu().numpy()
        mask = attended_mask(points, labels, attention, centres)
        handed = [finished.get((h, i)) for i in range(n_out)]
        new_subgoals = step_subgoals(decoded[:n_out], handed, int(mask.sum()), rng)
        new_latents = torch.stack([after[i] if goal is None else goal.latent.to(after)
                                   for i, goal in enumerate(handed)])
        target = np.concatenate([new_subgoals, points[~mask]])
        failure = run_skill(env, bundle, skill, h, mask, target, executor, new_subgoals, new_latents, rng)
        if failure is not None:
            return Execution(steps=tuple(records), final=env.observation(), failure=failure)
        records.append(StepRecord(skill, everything, new_subgoals, mask, False, park_tool(env, tool)))
    return Execution(steps=tuple(records), final=env.observation())
