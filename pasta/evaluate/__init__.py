"""Evaluation: encode observation and goal, plan, execute the plan in the simulator, score it.

See ``docs/evaluation.md``. Modules: ``encoding`` (clouds to entity latents), ``selection`` (the dough a
step acts on), ``policy_action`` (one checked policy action), ``execution`` (a plan in the simulator),
``metrics`` (EMDs, performance, the logged metric names), ``problem`` (one test configuration end to end),
``strip`` (its picture), ``oracle`` (the generator's own chain executed), ``ground_truth`` (that chain written
as a plan) and ``plan_diagnostics`` (a learned plan beside it).
"""

from pasta.evaluate.encoding import ENTITY_POINTS, EncodedScene, encode_scene, segment
from pasta.evaluate.execution import (
    EXECUTORS,
    Execution,
    StepRecord,
    check_executor,
    decode_set,
    execute_plan,
    executor_label,
    park_tool,
)
from pasta.evaluate.metrics import plan_quality_metrics, planned_goal_distance, shape_distance, summary_metrics
from pasta.evaluate.policy_action import NonFiniteActionError, PolicyInput, checked_action, policy_action
from pasta.evaluate.problem import EvaluationResult, Frame, evaluate_problem, make_plan
from pasta.evaluate.selection import attended_mask, nearest_components
from pasta.evaluate.strip import render_result_strip

__all__ = [
    "ENTITY_POINTS",
    "EXECUTORS",
    "EncodedScene",
    "EvaluationResult",
    "Execution",
    "Frame",
    "NonFiniteActionError",
    "PolicyInput",
    "StepRecord",
    "attended_mask",
    "check_executor",
    "checked_action",
    "decode_set",
    "encode_scene",
    "evaluate_problem",
    "execute_plan",
    "executor_label",
    "make_plan",
    "nearest_components",
    "park_tool",
    "plan_quality_metrics",
    "planned_goal_distance",
    "policy_action",
    "render_result_strip",
    "segment",
    "shape_distance",
    "summary_metrics",
]
