"""Planning an evaluation problem: receding horizon for CRS-Twice, plan() otherwise, and a problem it cannot plan."""

from __future__ import annotations

import dataclasses

import numpy as np

from pasta.config import load
from pasta.data.configurations import evaluation_problems
from pasta.evaluate import render_result_strip
from pasta.evaluate.encoding import encode_scene
from pasta.evaluate.problem import evaluate_problem, make_plan
from pasta.plan import PlanSettings
from pasta.train.bundle import untrained
from tests.evaluate.conftest import FAST, PRIOR


def encoded(cfg, bundle, problem):
    rng = np.random.default_rng(0)
    m = cfg.sim.observation_points
    obs = encode_scene(cfg, bundle, problem.initial.particles[:m], rng)
    goal = encode_scene(cfg, bundle, problem.target[:m], rng)
    return obs.latents, goal.latents


def test_crs_twice_plans_its_fixed_six_skills_by_receding_horizon():
    cfg = load("CRS-Twice", "smoke", list(FAST))
    bundle = untrained(cfg, "pasta", PRIOR).eval()
    problem = evaluation_problems(cfg)[0]
    obs, goal = encoded(cfg, bundle, problem)
    plan = make_plan(cfg, bundle, problem, obs, goal, PlanSettings.from_config(cfg))
    assert plan.skills == problem.skill_sequence and len(plan.skills) == 6
    assert len(plan.latent_sets) == 7
    assert plan.latent_sets[-1].shape[0] == obs.shape[0] + 2, "two cuts add two pieces"


def test_other_tasks_search_the_skill_sequences(cfg, bundle):
    problem = evaluation_problems(cfg)[0]
    obs, goal = encoded(cfg, bundle, problem)
    plan = make_plan(cfg, bundle, problem, obs, goal, PlanSettings.from_config(cfg))
    assert len(plan.skills) == cfg.horizon
    assert plan.skills.count("cut") == goal.shape[0] - obs.shape[0] == 1


def test_a_problem_without_a_skill_sequence_is_recorded_as_a_planning_failure(tmp_path):
    """A goal of three pieces from one, with a horizon of one skill (cut makes two): nothing to plan."""
    cfg = load("CutRearrange", "smoke", [*FAST, "plan.horizon=1"])
    bundle = untrained(cfg, "pasta", PRIOR).eval()
    problem = evaluation_problems(cfg)[0]
    points = np.asarray(problem.initial.particles, np.float32)  # one piece, cut into thirds below
    thirds = np.digitize(points[:, 0], np.quantile(points[:, 0], [1 / 3, 2 / 3]))
    three_pieces = points + (thirds[:, None] - 1) * np.array([0.1, 0.0, 0.0], np.float32)
    result = evaluate_problem(cfg, bundle, dataclasses.replace(problem, target=three_pieces), 0, "policy",
                              PlanSettings.from_config(cfg))
    assert result.failure.startswith("planning: no skill sequence of horizon 1 takes 1 entities to 3")
    assert result.skills == () and result.skipped == ()
    assert np.isnan(result.emd_planned_goal) and np.isfinite(result.performance)
    assert result.emd_reached_goal == result.emd_final
    assert [frame.title for frame in result.frames] == ["initial", "reached (not planned)", "target"]
    strip = render_result_strip(result, tmp_path / "strip.png")
    assert strip.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
