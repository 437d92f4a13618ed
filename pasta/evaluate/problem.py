"""Evaluate one test configuration: encode, plan, execute, score (model_spec §5-7).

:func:`evaluate_problem` resets the task's environment to the problem's initial configuration, measures
``emd_initial``, settles the dough (``cfg.sim.settle_steps`` zero actions, as before every demo), encodes
the settled observation and the goal into entity latents, plans (receding horizon when
``cfg.plan.receding_horizon`` is set, i.e. CRS-Twice, with the problem's fixed skill sequence; otherwise
over every skill sequence of ``cfg.plan.horizon`` (default ``cfg.horizon``) whose entity count ends at
the goal's), executes the plan and scores the final observation. A learned plan is then set beside the
generator's ground-truth chain (:mod:`pasta.evaluate.plan_diagnostics`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import partial
from types import MappingProxyType
from typing import Any

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.data.configurations import EvaluationProblem, oracle_chain
from pasta.evaluate.encoding import EncodedScene, encode_scene
from pasta.evaluate.execution import Execution, check_executor, decode_set, execute_plan
from pasta.evaluate.goal_subgoals import goal_subgoals
from pasta.evaluate.metrics import planned_goal_distance, shape_distance
from pasta.evaluate.oracle import check_plan_source, execute_oracle, needs_models
from pasta.evaluate.plan_diagnostics import PlanDiagnostics, diagnose_learned_plan, diagnostics_row
from pasta.evaluate.plan_masses import observed_masses, plan_masses
from pasta.geometry.distances import is_success, normalised_performance
from pasta.plan import NoSkillSequenceError, Plan, PlanSettings, plan, plan_receding_horizon
from pasta.sim.envs import make_env
from pasta.sim.envs.base import DoughEnv, Observation
from pasta.train.bundle import TrainedModels
from pasta.train.device import training_device

__all__ = ["EvaluationResult", "Frame", "PreparedProblem", "evaluate_problem", "make_plan", "prepare_problem"]


@dataclass(frozen=True, eq=False)
class Frame:
    """One picture of the image strip (``pasta.sim.render.render_strip`` reads these attributes).

    ``dough_points`` ``(N, 3)``; ``target_points`` ``(M, 3)`` drawn faintly behind, or None;
    ``tool_points`` tool name -> ``(P, 3)``.
    """

    title: str
    dough_points: np.ndarray
    target_points: np.ndarray | None = None
    tool_points: Mapping[str, np.ndarray] = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True, eq=False)
class EvaluationResult:
    """The outcome of one evaluation problem.

    ``attention``: per step, the plan's attended entity indices; ``skipped``: per step, whether the dough
    already matched the subgoal; ``frames``: initial, each decoded subgoal set, reached, target;
    ``failure``: why execution stopped early (a simulation that blew up), scored from the state before it;
    ``diagnostics``: a learned plan beside the ground truth (None for the oracle's, or when nothing was planned).
    """

    config_id: int
    skills: tuple[str, ...]
    attention: tuple[tuple[int, ...], ...]
    performance: float
    success: bool
    planning_time_s: float
    emd_initial: float
    emd_final: float
    emd_planned_goal: float
    emd_reached_goal: float
    executor: str
    skipped: tuple[bool, ...]
    frames: tuple[Frame, ...]
    failure: str | None = None
    plan_source: str = "learned"
    diagnostics: PlanDiagnostics | None = None

    def row(self) -> dict[str, Any]:
        """The table row (``tables/evaluation.json``); a learned plan's row adds its diagnostics' fields."""
        row = {
            "config_id": self.config_id, "skills": list(self.skills), "attention": [list(a) for a in self.attention],
            "performance": self.performance, "success": self.success, "planning_time_s": self.planning_time_s,
            "emd_initial": self.emd_initial, "emd_final": self.emd_final, "emd_planned_goal": self.emd_planned_goal,
            "emd_reached_goal": self.emd_reached_goal, "failure": self.failure,
        }
        if self.plan_source == "learned":
            row.update(diagnostics_row(self.diagnostics))
        return row


def make_plan(cfg: TaskConfig, bundle: TrainedModels, problem: EvaluationProblem, obs: torch.Tensor,
              goal: torch.Tensor, settings: PlanSettings) -> Plan:
    """Receding-horizon planning over the problem's skill sequence when the config asks for it, else ``plan``;
    on CUDA when torch sees a GPU (``training_device``), else on the CPU."""
    device = training_device()
    if cfg.plan.receding_horizon is not None:
        return plan_receding_horizon(bundle, obs, goal, problem.skill_sequence, cfg.plan.receding_horizon, settings,
                                     device, warm_start=cfg.plan.receding_warm_start)
    return plan(bundle, obs, goal, cfg.plan.horizon or cfg.horizon, settings, device)


def _frames(initial: Observation, execution: Execution, target: np.ndarray, reached: str = "reached"
            ) -> tuple[Frame, ...]:
    frames = [Frame("initial", initial.dough_points, tool_points=initial.tool_points)]
    for h, step in enumerate(execution.steps, start=1):
        note = " (skipped)" if step.skipped else ""
        frames.append(Frame(f"subgoal {h}: {step.skill}{note}", step.subgoal_points))
    final = execution.final
    frames.append(Frame(reached, final.dough_points, target_points=target, tool_points=final.tool_points))
    frames.append(Frame("target", target))
    return tuple(frames)


@dataclass(frozen=True, eq=False)
class PreparedProblem:
    """A problem set up in the simulator and encoded for the planner.

    Attributes:
        env: the task's environment, in the settled state.
        initial: the observation at reset, before settling.
        settled: the observation after ``cfg.sim.settle_steps`` zero actions (what the plan starts from).
        target: ``(P, 3)`` the goal's first ``cfg.sim.observation_points`` points.
        obs: the settled dough, encoded (None without trained models).
        goal: the target, encoded (None without trained models).
    """

    env: DoughEnv
    initial: Observation
    settled: Observation
    target: np.ndarray
    obs: EncodedScene | None
    goal: EncodedScene | None


def prepare_problem(cfg: TaskConfig, bundle: TrainedModels | None, problem: EvaluationProblem,
                    rng: np.random.Generator) -> PreparedProblem:
    """Reset the task's environment to ``problem``, settle it, and encode the settled dough and the goal
    (in that order, resampling with ``rng``); without a ``bundle`` nothing is encoded (``obs``, ``goal`` None)."""
    target = np.asarray(problem.target, np.float32)[: cfg.sim.observation_points]
    env = make_env(cfg)
    initial = env.reset(problem.initial)
    settled = env.settle(cfg.sim.settle_steps)
    if bundle is None:
        return PreparedProblem(env, initial, settled, target, None, None)
    obs = encode_scene(cfg, bundle, settled.dough_points, rng)
    return PreparedProblem(env, initial, settled, target, obs, encode_scene(cfg, bundle, target, rng))


@dataclass(frozen=True, eq=False)
class _Outcome:
    skills: tuple[str, ...]
    attention: tuple[tuple[int, ...], ...]
    planning_time_s: float
    emd_planned_goal: float
    execution: Execution
    planned: bool
    diagnostics: PlanDiagnostics | None = None


def _learned_outcome(cfg: TaskConfig, bundle: TrainedModels, problem: EvaluationProblem, prepared: PreparedProblem,
                     executor: str, settings: PlanSettings, rng: np.random.Generator, seed: int) -> _Outcome:
    started = time.perf_counter()
    try:
        the_plan = make_plan(cfg, bundle, problem, prepared.obs.latents, prepared.goal.latents, settings)
    except NoSkillSequenceError as error:
        execution = Execution(steps=(), final=prepared.settled, failure=f"planning: {error}")
        return _Outcome((), (), time.perf_counter() - started, float("nan"), execution, False)
    finished = None
    if cfg.eval.final_subgoals == "goal":
        finished = goal_subgoals(the_plan, prepared.goal, prepared.target)
    execution = execute_plan(cfg, bundle, prepared.env, the_plan, executor, rng, finished)
    masses = None
    if cfg.eval.decoded_entity_weights == "carried":  # the only weighting that reads them (each step decoded)
        masses = plan_masses(the_plan, partial(decode_set, bundle),
                             observed_masses(prepared.obs.labels, prepared.obs.n_entities))
    return _Outcome(
        skills=tuple(the_plan.skills),
        attention=tuple(tuple(int(i) for i in a) for a in the_plan.attention),
        planning_time_s=float(the_plan.planning_time_s),
        emd_planned_goal=planned_goal_distance(decode_set(bundle, the_plan.latent_sets[-1]), prepared.target, seed,
                                               cfg.eval.decoded_entity_weights,
                                               None if masses is None else masses[-1]),
        execution=execution,
        planned=True,
        diagnostics=diagnose_learned_plan(cfg, bundle, problem, the_plan, prepared.obs, prepared.goal.latents,
                                          settings, seed, masses),
    )


def _oracle_outcome(cfg: TaskConfig, bundle: TrainedModels | None, problem: EvaluationProblem,
                    prepared: PreparedProblem, executor: str, rng: np.random.Generator) -> _Outcome:
    chain = oracle_chain(cfg, problem.config_id, problem.generator_seed)
    done = execute_oracle(cfg, prepared.env, chain, executor, bundle, rng)
    # The oracle's last subgoal is the goal itself: its planned-goal distance is 0 by construction.
    return _Outcome(tuple(step.skill for step in chain), done.attention, 0.0, 0.0, done.execution, True)


def evaluate_problem(cfg: TaskConfig, bundle: TrainedModels | None, problem: EvaluationProblem, seed: int,
                     executor: str, settings: PlanSettings, plan_source: str = "learned") -> EvaluationResult:
    """Plan (or take the oracle's chain) and execute one problem; ``seed`` replaces ``settings.seed`` and seeds
    every resampling.

    ``plan_source`` ``"learned"`` plans with ``bundle``'s networks; ``"oracle"`` executes the generator's own
    subgoals and attention (:mod:`pasta.evaluate.oracle`), and needs no ``bundle`` with the scripted executor.
    A problem the planner has no skill sequence for (the observation's entity count cannot reach the
    goal's with the task's skills in the horizon) is not executed: its ``failure`` says why, it is scored
    as the dough lies, and ``emd_planned_goal`` is NaN.
    """
    check_executor(executor)
    check_plan_source(plan_source)
    if problem.task != cfg.task:
        raise ValueError(f"problem {problem.config_id} is a {problem.task} problem, the config is {cfg.task}")
    if bundle is None and needs_models(plan_source, executor):
        raise ValueError(f"plan {plan_source!r} with executor {executor!r} needs trained models")
    settings = dataclasses.replace(settings, seed=seed)
    rng = np.random.default_rng([seed, problem.config_id])
    prepared = prepare_problem(cfg, bundle, problem, rng)
    initial, target = prepared.initial, prepared.target
    emd_initial = shape_distance(initial.dough_points, problem.target, seed)
    if plan_source == "oracle":
        outcome = _oracle_outcome(cfg, bundle, problem, prepared, executor, rng)
    else:
        outcome = _learned_outcome(cfg, bundle, problem, prepared, executor, settings, rng, seed)
    execution = outcome.execution
    emd_final = shape_distance(execution.final.dough_points, problem.target, seed)
    performance = float(normalised_performance(emd_initial, emd_final))
    return EvaluationResult(
        config_id=problem.config_id,
        skills=outcome.skills,
        attention=outcome.attention,
        performance=performance,
        success=bool(is_success(performance, cfg.eval.success_threshold)),
        planning_time_s=outcome.planning_time_s,
        emd_initial=emd_initial,
        emd_final=emd_final,
        emd_planned_goal=outcome.emd_planned_goal,
        emd_reached_goal=emd_final,
        executor=executor,
        skipped=tuple(step.skipped for step in execution.steps),
        frames=_frames(initial, execution, target, reached="reached" if outcome.planned else "reached (not planned)"),
        failure=execution.failure,
        plan_source=plan_source,
        diagnostics=outcome.diagnostics,
    )
