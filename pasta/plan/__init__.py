"""Batched latent planning over skill sequences and attention structures, and receding-horizon planning.

See ``docs/planning.md``.
"""

from pasta.plan.attention import Structures, sample_structures
from pasta.plan.from_bundle import bundle_functions, bundle_skills, frozen_parameters, settings_functions
from pasta.plan.functions import PlanningFunctions
from pasta.plan.matching import best_matching, matched_pair_cost
from pasta.plan.planner import plan, plan_with
from pasta.plan.receding import plan_receding_horizon, plan_receding_horizon_with
from pasta.plan.result import Plan
from pasta.plan.sequences import NoSkillSequenceError, SkillSpec, enumerate_sequences, resolve_sequence, set_sizes
from pasta.plan.settings import DEFAULT_HALVING, PlanSettings

__all__ = [
    "DEFAULT_HALVING",
    "Plan",
    "PlanSettings",
    "PlanningFunctions",
    "SkillSpec",
    "Structures",
    "best_matching",
    "bundle_functions",
    "bundle_skills",
    "NoSkillSequenceError",
    "enumerate_sequences",
    "frozen_parameters",
    "matched_pair_cost",
    "plan",
    "plan_receding_horizon",
    "plan_receding_horizon_with",
    "plan_with",
    "resolve_sequence",
    "sample_structures",
    "set_sizes",
    "settings_functions",
]
