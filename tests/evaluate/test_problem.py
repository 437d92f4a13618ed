"""Planning an evaluation problem: receding horizon with the fixed sequence for CRS-Twice, plan() otherwise."""

from __future__ import annotations

import numpy as np

from pasta.config import load
from pasta.data.configurations import evaluation_problems
from pasta.evaluate.encoding import encode_scene
from pasta.evaluate.problem import make_plan
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
