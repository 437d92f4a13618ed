"""The oracle plan: execute an evaluation problem with the generator's own subgoals and attention.

Every evaluation problem is a chain of stages drawn by one generator (:mod:`pasta.data.configurations`);
:func:`pasta.data.configurations.oracle_chain` gives, per skill, the pieces it acts on (by particle identity)
and the stage it must reach. Executing that chain with the scripted skills measures what the physics and the
skills can reach at all (the ceiling of every learned plan); with the learned policies it measures the
policies alone. Together with the learned plan this fills the plan x executor matrix of ``docs/evaluation.md``.

For each step ``h``:

1. the attended dough is the DBSCAN components of the observation whose points mostly belong to the acted
   pieces (particle identity; :func:`attended_components`);
2. the scripted skills aim at the whole next stage (first ``cfg.sim.observation_points`` particles); the
   policies see the acted particles' places in the next stage, split into entities by DBSCAN and encoded
   with the VAE (the new subgoals a learned plan would hand them);
3. the step then runs as a learned plan's step does (:func:`pasta.evaluate.execution.run_skill`: place the
   tool, act, settle), and the tool is parked.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.data.aim_search import Rest
from pasta.data.configurations import OracleStep
from pasta.data.skills import place_tool_for_skill, scripted_actions, skill_tool
from pasta.evaluate.encoding import encode_scene, segment
from pasta.evaluate.execution import Execution, StepRecord, check_executor, park_tool, run_skill
from pasta.sim.envs.base import DoughEnv
from pasta.train.bundle import TrainedModels

__all__ = ["PLAN_SOURCES", "OracleExecution", "OracleStepInputs", "attended_components", "check_plan_source",
           "execute_oracle", "needs_models", "oracle_step_inputs"]

PLAN_SOURCES = ("learned", "oracle")


def needs_models(plan_source: str, executor: str) -> bool:
    """Whether an evaluation needs trained models (every one but the oracle plan run by scripted skills)."""
    return plan_source == "learned" or executor == "policy"


def check_plan_source(plan_source: str) -> str:
    if plan_source not in PLAN_SOURCES:
        raise ValueError(f"unknown plan {plan_source!r}; choose one of {list(PLAN_SOURCES)}")
    return plan_source


@dataclass(frozen=True, eq=False)
class OracleExecution:
    """The executed oracle chain and, per step, the DBSCAN entities of the observation it acted on."""

    execution: Execution
    attention: tuple[tuple[int, ...], ...]


def attended_components(labels: np.ndarray, acted: np.ndarray) -> tuple[int, ...]:
    """The DBSCAN components ``labels`` ``(P,)`` most of whose points are ``acted`` ``(P,)``; if none, those
    holding any acted point. (A cut never splits exactly where the generator's plane did, so a few acted
    particles may sit in a neighbouring piece.)"""
    components = np.unique(labels[acted])
    majority = tuple(int(k) for k in components if acted[labels == k].mean() > 0.5)
    return majority or tuple(int(k) for k in components)


@dataclass(frozen=True, eq=False)
class OracleStepInputs:
    """What one oracle step hands its skill, read from the current observation.

    Attributes:
        attended: the DBSCAN components of the observation it acts on.
        mask: ``(P,)`` bool over the observation points: those components.
        subgoal: ``(P, 3)`` the whole next stage (the scripted skills' target).
        new_points: ``(R, 3)`` the acted particles' places in the next stage.
        goal_points: what the policy sees as its goal: ``new_points`` split into entities and stacked
            ``(K * ENTITY_POINTS, 3)`` when a ``bundle`` encoded them, else ``new_points``.
        goal_latents: ``(K, D_z + 3)`` their latents (None without a ``bundle``).
    """

    attended: tuple[int, ...]
    mask: np.ndarray
    subgoal: np.ndarray
    new_points: np.ndarray
    goal_points: np.ndarray
    goal_latents: torch.Tensor | None


def oracle_step_inputs(cfg: TaskConfig, env: DoughEnv, step: OracleStep, bundle: TrainedModels | None,
                       rng: np.random.Generator) -> OracleStepInputs:
    """The attention and the goals of oracle ``step`` at the environment's current state; with a ``bundle`` the
    new subgoals are encoded by its VAE, as the policy executor needs them."""
    m = cfg.sim.observation_points
    points = np.asarray(env.observation().dough_points)
    acted = np.asarray(step.acted[:m], dtype=bool)
    labels = segment(cfg, points)
    attended = attended_components(labels, acted)
    subgoal = np.asarray(step.subgoal[:m], dtype=np.float32)
    new_points = subgoal[acted]
    goal_latents, goal_points = None, new_points
    if bundle is not None:
        encoded = encode_scene(cfg, bundle, new_points, rng)
        goal_latents, goal_points = encoded.latents, encoded.entities.reshape(-1, 3)
    return OracleStepInputs(attended, np.isin(labels, attended), subgoal, new_points, goal_points, goal_latents)


def scripted_rest(cfg: TaskConfig, skill: str, steps: Sequence[OracleStep], goal: np.ndarray) -> Rest:
    """The chain's remaining ``steps`` executed by the scripts alone, after ``skill``'s tool is parked, as an aim
    search's ``rest`` (:func:`pasta.data.aim_search.search_aim`): returns the final observed dough and ``goal``
    (``(P, 3)``, the chain's last subgoal)."""
    m = cfg.sim.observation_points
    final_goal = np.asarray(goal[:m], np.float64)

    def rest(env: DoughEnv) -> tuple[np.ndarray, np.ndarray]:
        park_tool(env, skill_tool(cfg, skill).name)
        for step in steps:
            inputs = oracle_step_inputs(cfg, env, step, None, np.random.default_rng(0))
            place_tool_for_skill(env, step.skill, inputs.mask, inputs.subgoal)
            for action in scripted_actions(env, step.skill, inputs.subgoal, inputs.mask):
                env.step(action)
            env.settle(cfg.sim.settle_steps)
            park_tool(env, skill_tool(cfg, step.skill).name)
        return np.asarray(env.observation().dough_points), final_goal

    return rest


def execute_oracle(cfg: TaskConfig, env: DoughEnv, chain: Sequence[OracleStep], executor: str,
                   bundle: TrainedModels | None, rng: np.random.Generator) -> OracleExecution:
    """Execute the ground-truth ``chain`` from the environment's current (settled) state.

    ``bundle`` is needed by the policy executor only (its policies, and its VAE for the subgoal latents;
    :func:`pasta.evaluate.execution.run_skill` refuses a policy step without it).
    A step whose simulation blows up stops the execution; its ``failure`` names the step and the value.
    """
    check_executor(executor)
    records: list[StepRecord] = []
    attention: list[tuple[int, ...]] = []
    for h, step in enumerate(chain, start=1):
        inputs = oracle_step_inputs(cfg, env, step, bundle if executor == "policy" else None, rng)
        attention.append(inputs.attended)
        rest = scripted_rest(cfg, step.skill, chain[h:], chain[-1].subgoal) if h < len(chain) else None
        failure = run_skill(env, bundle, step.skill, h, inputs.mask, inputs.subgoal, executor, inputs.goal_points,
                            inputs.goal_latents, rng, rest)
        if failure is not None:
            return OracleExecution(Execution(tuple(records), env.observation(), failure), tuple(attention))
        tool = skill_tool(cfg, step.skill).name
        records.append(StepRecord(step.skill, inputs.subgoal, inputs.new_points, inputs.mask, False,
                                  park_tool(env, tool)))
    return OracleExecution(Execution(tuple(records), env.observation()), tuple(attention))
