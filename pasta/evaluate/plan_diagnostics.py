"""Plan diagnostics: a learned plan beside the generator's ground-truth chain, per test configuration.

* ``sequence_match``: the plan's skills are the chain's.
* ``attention_match``: every step acts on the entities the chain acts on. At step 1 the plan's attended
  indices and the ground truth's are both DBSCAN components of the observation the plan was encoded from
  (``U^0`` is the same set), so they are compared as they are. At a later step the plan's ``U^{h-1}`` is its
  own; each attended entity stands for the ground-truth entity of ``U^{h-1}`` whose centre ``t`` is nearest
  its planned centre, distinct while there are enough (:func:`pasta.evaluate.selection.nearest_components`,
  the rule by which the executor finds the dough of a later step, applied to the ground truth's entities).
* ``subgoal_emd``: per step ``h``, EMD between the decoded ``U^h`` (entities stacked) and the chain's stage ``h``.
* ``plan_score`` and ``ground_truth_score``: the planner's objective
  ``sum_h log max(f_h, floor) - alpha * max(C(U^H, goal), 0)`` of its chosen plan and of the ground truth's
  latents (:mod:`pasta.evaluate.ground_truth`). If the ground truth scores higher, the optimiser missed a
  better plan (``optimiser failed``); if lower, the networks prefer a plan that is not the ground truth
  (``networks wrong``).

EMD(planned goal, goal) is the evaluation's own ``emd_planned_goal`` (:mod:`pasta.evaluate.metrics`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import torch

from pasta.config.schema import DecodedEntityWeights, TaskConfig
from pasta.data.configurations import EvaluationProblem, oracle_chain
from pasta.evaluate.encoding import EncodedScene
from pasta.evaluate.execution import decode_set
from pasta.evaluate.ground_truth import GroundTruthPlan, ground_truth_plan
from pasta.evaluate.metrics import planned_goal_distance
from pasta.evaluate.selection import nearest_components
from pasta.plan import Plan, PlanningFunctions, PlanSettings, SkillSpec, frozen_parameters, settings_functions
from pasta.plan.planner import score_of, set_cost
from pasta.train.bundle import TrainedModels

__all__ = ["NETWORKS_WRONG", "OPTIMISER_FAILED", "SCORES_TIE", "PlanDiagnostics", "attention_in_ground_truth",
           "diagnose", "diagnose_learned_plan", "diagnostics_row", "plan_objective", "verdict"]

OPTIMISER_FAILED = "optimiser failed"  # the ground truth scores higher than the chosen plan
NETWORKS_WRONG = "networks wrong"  # the chosen plan scores higher than the ground truth
SCORES_TIE = "tie"  # the objective cannot tell them apart
SCORE_TOLERANCE = 1e-6  # scores closer than this tie
GROUND_TRUTH_STREAM = 1  # the ground truth's resampling draws from its own stream, not the execution's

Decoder = Callable[[torch.Tensor], np.ndarray]  # (K, D_z + 3) latents -> (K, M, 3) decoded entity clouds


def verdict(plan_score: float, ground_truth_score: float) -> str:
    """Which half a plan that differs from the ground truth blames: the optimiser (the ground truth scores
    higher, so a better plan was missed) or the networks (they score their plan above the ground truth)."""
    if ground_truth_score > plan_score + SCORE_TOLERANCE:
        return OPTIMISER_FAILED
    if ground_truth_score < plan_score - SCORE_TOLERANCE:
        return NETWORKS_WRONG
    return SCORES_TIE


def _skill_index(skills: Sequence[SkillSpec], name: str, n_in: int) -> int:
    """The index of skill ``name`` with ``n_in`` inputs, or of its first arity when it has no such one (the
    arities of a skill share its feasibility network)."""
    named = [i for i, spec in enumerate(skills) if spec.name == name]
    if not named:
        raise KeyError(f"unknown skill {name!r}; known: {sorted({s.name for s in skills})}")
    exact = [i for i in named if skills[i].n_in == n_in]
    return (exact or named)[0]


def plan_objective(functions: PlanningFunctions, settings: PlanSettings, skills: Sequence[str],
                   attention: Sequence[Sequence[int]], latent_sets: Sequence[torch.Tensor], goal: torch.Tensor
                   ) -> float:
    """The planner's objective of a plan's latents (its ``Plan.score`` for a plan it chose).

    Args:
        skills: ``H`` skill names.
        attention: per step, positions in ``U^{h-1}`` of the attended entities.
        latent_sets: ``U^0 .. U^H``, each ``(K_h, D_z + 3)``; ``U^h`` = [the step's new entities, the kept ones].
        goal: ``(K_g, D_z + 3)`` goal entities, on the device of ``functions``.
    """
    device = goal.device
    feasibilities, penalties = [], []
    with torch.no_grad():
        for h, (skill, attended) in enumerate(zip(skills, attention, strict=True), start=1):
            before, after = latent_sets[h - 1].to(device), latent_sets[h].to(device)
            n_out = after.shape[0] - (before.shape[0] - len(attended))
            index = _skill_index(functions.skills, skill, len(attended))
            inputs, outputs = before[list(attended)].unsqueeze(0), after[:n_out].unsqueeze(0)
            feasibilities.append(float(functions.feasibility(index, inputs, outputs)[0]))
            penalties.append(float(functions.step_penalty(index, inputs, outputs)[0]))
    return score_of(tuple(feasibilities), set_cost(functions, latent_sets[-1], goal), settings, tuple(penalties))


def attention_in_ground_truth(plan: Plan, truth: GroundTruthPlan, latent_dim: int) -> tuple[tuple[int, ...], ...]:
    """The plan's attention as positions in the ground truth's ``U^{h-1}``, sorted, for the steps both have.

    Step 1 keeps its indices (both index the observation's components); a later step maps each attended
    entity to the ground-truth entity whose centre is nearest its planned centre (see the module's notes).
    """
    mapped = []
    steps = zip(plan.attention, plan.latent_sets, truth.latent_sets[:-1], strict=False)  # the shorter plan's steps
    for h, (attended, planned, true_set) in enumerate(steps):
        if h == 0:
            mapped.append(tuple(sorted(int(i) for i in attended)))
            continue
        centres = planned[list(attended), latent_dim:].detach().cpu().numpy()
        true_centres = true_set[:, latent_dim:].detach().cpu().numpy()
        mapped.append(tuple(sorted(nearest_components(true_centres, np.arange(len(true_centres)), centres))))
    return tuple(mapped)


@dataclass(frozen=True)
class PlanDiagnostics:
    """A learned plan beside the ground truth (see the module's notes).

    Attributes:
        ground_truth_skills: the chain's skills, length ``H_gt``.
        ground_truth_attention: per step, the positions in the ground truth's ``U^{h-1}`` it acts on.
        attention_in_ground_truth: the plan's attention in those positions, per step both plans have.
        sequence_match: the plan's skills equal ``ground_truth_skills``.
        attention_match: as many steps, each attending the ground truth's entities.
        subgoal_emd: per step both plans have, EMD(decoded ``U^h``, stage ``h``).
        plan_score: the planner's objective of its chosen plan.
        ground_truth_score: the same objective of the ground truth's latents.
    """

    ground_truth_skills: tuple[str, ...]
    ground_truth_attention: tuple[tuple[int, ...], ...]
    attention_in_ground_truth: tuple[tuple[int, ...], ...]
    sequence_match: bool
    attention_match: bool
    subgoal_emd: tuple[float, ...]
    plan_score: float
    ground_truth_score: float

    @property
    def verdict(self) -> str:
        return verdict(self.plan_score, self.ground_truth_score)

    @property
    def mean_subgoal_emd(self) -> float:
        return float(np.mean(self.subgoal_emd)) if self.subgoal_emd else math.nan

    def row(self) -> dict[str, Any]:
        """The configuration's diagnostic fields (``tables/evaluation.json``; :func:`diagnostics_row`)."""
        return {
            "ground_truth_skills": list(self.ground_truth_skills),
            "ground_truth_attention": [list(a) for a in self.ground_truth_attention],
            "attention_in_ground_truth": [list(a) for a in self.attention_in_ground_truth],
            "sequence_match": self.sequence_match, "attention_match": self.attention_match,
            "subgoal_emd": list(self.subgoal_emd), "subgoal_emd_mean": self.mean_subgoal_emd,
            "plan_score": self.plan_score, "ground_truth_score": self.ground_truth_score, "verdict": self.verdict,
            "optimiser_failed": float(self.verdict == OPTIMISER_FAILED),
        }


def diagnostics_row(diagnostics: PlanDiagnostics | None) -> dict[str, Any]:
    """``diagnostics.row()``; for a configuration the planner had no plan for, the same fields saying so: no
    match, no EMD or scores (NaN), no verdict."""
    if diagnostics is not None:
        return diagnostics.row()
    return {"ground_truth_skills": None, "ground_truth_attention": None, "attention_in_ground_truth": None,
            "sequence_match": False, "attention_match": False, "subgoal_emd": [], "subgoal_emd_mean": math.nan,
            "plan_score": math.nan, "ground_truth_score": math.nan, "verdict": None, "optimiser_failed": math.nan}


def diagnose(plan: Plan, truth: GroundTruthPlan, functions: PlanningFunctions, settings: PlanSettings,
             goal: torch.Tensor, decode: Decoder, seed: int, weights: DecodedEntityWeights = "volume",
             masses: Sequence[np.ndarray] | None = None) -> PlanDiagnostics:
    """Compare ``plan`` with ``truth`` under the planner's ``functions`` and ``settings``.

    Args:
        goal: ``(K_g, D_z + 3)`` the goal entities the plan was made for, on the device of ``functions``.
        decode: latents ``(K, D_z + 3)`` -> decoded clouds ``(K, M, 3)``.
        seed: subsamples the clouds of the EMDs.
        weights: how each decoded subgoal set becomes one cloud (:func:`pasta.evaluate.metrics.planned_goal_distance`).
        masses: per ``U^0 .. U^H`` of ``plan``, its entities' masses (:mod:`pasta.evaluate.plan_masses`); needed
            by ``weights="carried"``.
    """
    mapped = attention_in_ground_truth(plan, truth, functions.prior.latent_dim)
    same_length = len(plan.attention) == len(truth.attention)
    step_masses = masses[1:] if masses is not None else [None] * (len(plan.latent_sets) - 1)
    subgoal_emd = tuple(planned_goal_distance(decode(u), stage, seed, weights, m)
                        for u, stage, m in zip(plan.latent_sets[1:], truth.stages, step_masses, strict=False))
    return PlanDiagnostics(
        ground_truth_skills=truth.skills,
        ground_truth_attention=truth.attention,
        attention_in_ground_truth=mapped,
        sequence_match=tuple(plan.skills) == truth.skills,
        attention_match=same_length and mapped == truth.attention,
        subgoal_emd=subgoal_emd,
        plan_score=plan_objective(functions, settings, plan.skills, plan.attention, plan.latent_sets, goal),
        ground_truth_score=plan_objective(functions, settings, truth.skills, truth.attention, truth.latent_sets,
                                          goal),
    )


def diagnose_learned_plan(cfg: TaskConfig, bundle: TrainedModels, problem: EvaluationProblem, plan: Plan,
                          start: EncodedScene, goal: torch.Tensor, settings: PlanSettings, seed: int,
                          masses: Sequence[np.ndarray] | None = None) -> PlanDiagnostics:
    """Diagnose the plan an evaluation made for ``problem`` from ``start`` (the encoded settled observation) to
    ``goal`` ``(K_g, D_z + 3)``, with the bundle's networks and the objective of ``settings`` (``masses``: the
    plan's, see :func:`diagnose`)."""
    chain = oracle_chain(cfg, problem.config_id, problem.generator_seed)
    rng = np.random.default_rng([seed, problem.config_id, GROUND_TRUTH_STREAM])
    truth = ground_truth_plan(cfg, bundle, chain, start, rng)
    device = next(bundle.vae.parameters()).device
    with frozen_parameters(bundle):
        functions = settings_functions(bundle, settings)
        return diagnose(plan, truth, functions, settings, goal.to(device), partial(decode_set, bundle), seed,
                        cfg.eval.decoded_entity_weights, masses)
