"""Executing a hand-made plan in the simulator: checked policy actions, scripted skills, parked tools."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from pasta.config import load
from pasta.data.configurations import evaluation_problems, tool_clearance
from pasta.evaluate.blowups import load_blowup, replay_blowup
from pasta.evaluate.execution import already_reached, execute_plan, executor_label
from pasta.evaluate.goal_subgoals import goal_subgoals
from pasta.evaluate.policy_action import NonFiniteActionError, checked_action
from pasta.evaluate.problem import prepare_problem
from pasta.models.vae import VAEConfig
from pasta.plan.result import Plan
from pasta.sim.engine import SimulationError
from pasta.sim.envs import make_env
from pasta.sim.tool_points import world_sdf
from pasta.train.bundle import TrainedModels
from tests.evaluate.conftest import FAST


class ScriptedOutputs(nn.Module):
    """A stand-in policy that returns the given actions in turn, whatever it sees."""

    def __init__(self, outputs: list[list[float]]):
        super().__init__()
        self.outputs = outputs
        self.calls = 0
        self.phases: list[float] = []
        self.previous: list[np.ndarray] = []  # the previous action it was given at each call

    def forward(self, obs_points, tool_points, goal_points, phase, previous_action):
        assert obs_points.shape == (1, 1000, 3) and tool_points.shape == (1, 100, 3) and phase.shape == (1,)
        out = torch.tensor([self.outputs[min(self.calls, len(self.outputs) - 1)]])
        self.calls += 1
        self.phases.append(float(phase))
        self.previous.append(previous_action[0].numpy())
        return out


class FixedDecoder(nn.Module):
    """A stand-in VAE whose every latent decodes to the same cloud."""

    def __init__(self, cloud: np.ndarray):
        super().__init__()
        self.config = VAEConfig()
        self.cloud = nn.Parameter(torch.from_numpy(np.array(cloud, np.float32)), requires_grad=False)

    def decode(self, z, t):
        return self.cloud.expand(z.shape[0], -1, -1)


def replaced(bundle: TrainedModels, **models: nn.Module) -> TrainedModels:
    return TrainedModels(bundle.task, bundle.variant, bundle.skill_names, bundle.action_dim, bundle.model_config,
                         bundle.prior, bundle.filter_epsilon, {**bundle.models, **models})


def with_policies(bundle: TrainedModels, policy: nn.Module) -> TrainedModels:
    return replaced(bundle, policy=nn.ModuleList([policy for _ in bundle.skill_names]))


def cut_plan(cfg, bundle):
    """The first evaluation problem, settled, and a one-step plan: cut the box into the target's two pieces."""
    problem = evaluation_problems(cfg)[0]
    prepared = prepare_problem(cfg, bundle, problem, np.random.default_rng(0))
    start, goal = prepared.obs, prepared.goal
    assert start.n_entities == 1 and goal.n_entities == 2
    assert prepared.target.shape == (cfg.sim.observation_points, 3)
    assert np.abs(prepared.settled.dough_points - prepared.initial.dough_points).max() > 0  # it settled
    plan = Plan(skills=("cut",), attention=((0,),), latent_sets=(start.latents, goal.latents), feasibilities=(1.0,),
                cost=0.0, score=0.0, planning_time_s=0.0)
    return prepared.env, plan


def test_checked_action_clips_finite_actions_and_names_bad_ones():
    np.testing.assert_array_equal(checked_action(np.array([2.0, -3.0, 0.5]), "cut", 1, 0), [1.0, -1.0, 0.5])
    with pytest.raises(NonFiniteActionError, match=r"'push' \(plan step 2\).*environment step 7: value inf at index 1"):
        checked_action(np.array([0.0, np.inf]), "push", 2, 7)


def test_a_nan_policy_action_stops_execution_naming_the_step(cfg, bundle):
    env, plan = cut_plan(cfg, bundle)
    dim = bundle.action_dim
    nan_second = with_policies(bundle, ScriptedOutputs([[0.0] * dim, [0.0, float("nan")] + [0.0] * (dim - 2)]))
    with pytest.raises(NonFiniteActionError, match=r"'cut' \(plan step 1\).*environment step 1: value nan at index 1"):
        execute_plan(cfg, nan_second, env, plan, "policy", np.random.default_rng(0))
    assert env.step_count == cfg.sim.settle_steps + 1, "exactly the one finite action was taken"


def test_scripted_execution_acts_on_the_piece_and_parks_the_tool(cfg, bundle):
    env, plan = cut_plan(cfg, bundle)
    before = env.step_count
    execution = execute_plan(cfg, bundle, env, plan, "scripted", np.random.default_rng(0))
    (step,) = execution.steps
    assert not step.skipped and step.attended.all(), "the only piece is the attended one"
    assert step.new_subgoal_points.shape == (2000, 3) and step.subgoal_points.shape == (2000, 3)
    assert env.step_count == before + cfg.sim.steps_per_skill + cfg.sim.settle_steps
    knife = env.tool("knife")
    pose = env.tool_poses()["knife"]
    back = env.back_pose("knife")
    np.testing.assert_allclose(np.array(pose.pos)[[0, 2]], np.array(back.pos)[[0, 2]], atol=1e-6)
    assert pose.pos[1] >= back.pos[1] - 1e-6
    assert world_sdf(knife, env.particles(), pose.pos, pose.rot, pose.gap).min() >= tool_clearance(cfg) - 1e-6
    np.testing.assert_array_equal(execution.final.dough_points, env.observation().dough_points)


def test_a_finished_entity_is_handed_its_goal_piece_instead_of_its_decoding(cfg, bundle):
    problem = evaluation_problems(cfg)[0]
    prepared = prepare_problem(cfg, bundle, problem, np.random.default_rng(0))
    plan = Plan(skills=("cut",), attention=((0,),), latent_sets=(prepared.obs.latents, prepared.goal.latents),
                feasibilities=(1.0,), cost=0.0, score=0.0, planning_time_s=0.0)
    finished = goal_subgoals(plan, prepared.goal, prepared.target)
    assert sorted(finished) == [(1, 0), (1, 1)], "a one-step plan finishes both of the cut's pieces"
    execution = execute_plan(cfg, bundle, prepared.env, plan, "scripted", np.random.default_rng(0), finished)
    (step,) = execution.steps
    assert step.new_subgoal_points.shape == prepared.target.shape, "the goal's points, not 2 x 1000 decoded ones"
    np.testing.assert_array_equal(np.sort(step.new_subgoal_points, axis=0), np.sort(prepared.target, axis=0))


def test_policy_execution_runs_the_policy_for_the_skill_budget(cfg, bundle, monkeypatch):
    env, plan = cut_plan(cfg, bundle)
    knife_action = np.array([0.2, -0.1, 0.0])  # small: neither the [-1, 1] clip nor the knife's bounds bite
    action = env.action_for("knife", knife_action)
    policy = ScriptedOutputs([action.tolist()])
    steps = []  # (action, tool poses before, tool poses after) of every environment step, as they happen
    real_step = env.step

    def recorded_step(taken):
        before = env.tool_poses()
        observation = real_step(taken)
        steps.append((np.array(taken), before, env.tool_poses()))
        return observation

    monkeypatch.setattr(env, "step", recorded_step)
    execute_plan(cfg, with_policies(bundle, policy), env, plan, "policy", np.random.default_rng(0))
    n = cfg.sim.steps_per_skill
    assert policy.calls == n
    assert policy.phases == pytest.approx([k / n for k in range(n)])
    assert len(steps) == n + cfg.sim.settle_steps
    for taken, _, _ in steps[:n]:
        np.testing.assert_array_equal(taken, action)  # the policy's action reached the simulator
    assert not any(taken.any() for taken, _, _ in steps[n:]), "then the dough settles"
    for (_, _, after), (_, before, _) in itertools.pairwise(steps[:n]):
        np.testing.assert_array_equal(before["knife"].pos, after["knife"].pos)  # no teleport in between
    start, end = steps[0][1], steps[n - 1][2]
    scales = np.array(env.tool("knife").action_scales)
    np.testing.assert_allclose(np.array(end["knife"].pos) - np.array(start["knife"].pos), knife_action * scales * n,
                               rtol=1e-4, atol=1e-6)
    np.testing.assert_array_equal(end["gripper"].pos, start["gripper"].pos)  # only the knife was driven


def test_a_chunking_policy_is_asked_once_per_chunk_and_its_actions_are_acted_out_in_order(cfg, bundle,
                                                                                         monkeypatch):
    env, plan = cut_plan(cfg, bundle)
    first, second, third = (env.action_for("knife", np.array([v, 0.0, 0.0])) for v in (0.1, -0.2, 0.3))
    policy = ScriptedOutputs([np.concatenate([first, second, third]).tolist()])  # chunks of 3 steps
    taken = []
    real_step = env.step
    monkeypatch.setattr(env, "step", lambda action: (taken.append(np.array(action)), real_step(action))[1])
    execute_plan(cfg, with_policies(bundle, policy), env, plan, "policy", np.random.default_rng(0))
    n = cfg.sim.steps_per_skill
    assert policy.calls == -(-n // 3)
    assert policy.phases == pytest.approx([k / n for k in range(0, n, 3)])
    for k in range(n):
        np.testing.assert_array_equal(taken[k], (first, second, third)[k % 3])
    assert not policy.previous[0].any()  # nothing was applied before the skill's first step
    for call, k in enumerate(range(3, n, 3), start=1):
        np.testing.assert_array_equal(policy.previous[call], taken[k - 1])  # the action applied just before


def test_the_demonstrated_range_holds_every_policy_action_the_executor_applies(bundle, monkeypatch):
    cfg = load("CutRearrange", "smoke", [*FAST, "eval.policy_action_range=demonstrated"])
    env, plan = cut_plan(cfg, bundle)
    policy = ScriptedOutputs([env.action_for("knife", np.array([0.8, -0.4, 0.0])).tolist()])
    low, high = env.action_for("knife", np.array([0.0, -0.2, 0.0])), env.action_for("knife", np.array([0.5, 0.9, 0.0]))
    demonstrated = tuple(tuple(float(v) for v in bound) for bound in (low, high))
    ranged = dataclasses.replace(with_policies(bundle, policy), action_range=(demonstrated, demonstrated))
    taken = []
    real_step = env.step
    monkeypatch.setattr(env, "step", lambda action: (taken.append(np.array(action)), real_step(action))[1])
    execute_plan(cfg, ranged, env, plan, "policy", np.random.default_rng(0))
    n = cfg.sim.steps_per_skill
    for action in taken[:n]:
        np.testing.assert_allclose(action, env.action_for("knife", np.array([0.5, -0.2, 0.0])))
    assert policy.previous[1] == pytest.approx(taken[0])  # the policy hears the action applied, not the one it asked
    env, plan = cut_plan(cfg, bundle)
    with pytest.raises(ValueError, match="needs a bundle that kept its demonstrations' action range"):
        execute_plan(cfg, with_policies(bundle, policy), env, plan, "policy", np.random.default_rng(0))


def test_an_ensembling_executor_asks_every_step_and_acts_the_mean_of_the_chunks_predictions(bundle, monkeypatch):
    cfg = load("CutRearrange", "smoke", [*FAST, "policy.chunk_execution=ensemble", "policy.ensemble_decay=0"])
    env, plan = cut_plan(cfg, bundle)
    first, second, third = (env.action_for("knife", np.array([v, 0.0, 0.0])) for v in (0.1, -0.2, 0.3))
    policy = ScriptedOutputs([np.concatenate([first, second, third]).tolist()])  # the same chunk of 3 every call
    taken = []
    real_step = env.step
    monkeypatch.setattr(env, "step", lambda action: (taken.append(np.array(action)), real_step(action))[1])
    execute_plan(cfg, with_policies(bundle, policy), env, plan, "policy", np.random.default_rng(0))
    n = cfg.sim.steps_per_skill
    assert n == 2 and policy.calls == n
    np.testing.assert_allclose(taken[0], first)
    np.testing.assert_allclose(taken[1], (second + first) / 2, rtol=1e-6)  # call 0's second, call 1's first
    assert not policy.previous[0].any()
    np.testing.assert_array_equal(policy.previous[1], taken[0])  # the ensembled action applied, not a prediction


def test_skills_left_to_the_scripts_run_their_scripted_actions_under_the_policy_executor(bundle):
    cfg = load("CutRearrange", "smoke", [*FAST, "eval.scripted_skills=[cut]"])
    policy = ScriptedOutputs([[1.0] * bundle.action_dim])
    env, plan = cut_plan(cfg, bundle)
    mixed = execute_plan(cfg, with_policies(bundle, policy), env, plan, "policy", np.random.default_rng(0))
    env, plan = cut_plan(cfg, bundle)
    scripted = execute_plan(cfg, bundle, env, plan, "scripted", np.random.default_rng(0))
    assert policy.calls == 0
    np.testing.assert_array_equal(mixed.final.dough_points, scripted.final.dough_points)
    # tagged apart, so the matrix's learned-policies cell never takes such a run
    assert executor_label(cfg, "policy") == "policy+scripted:cut" and executor_label(cfg, "scripted") == "scripted"
    assert executor_label(load("CutRearrange", "smoke", list(FAST)), "policy") == "policy"
    with pytest.raises(ValueError, match=r"\['lift'\]"):
        load("CutRearrange", "smoke", ["eval.scripted_skills=[cut, lift]"])


def test_a_step_whose_subgoal_is_already_reached_is_skipped(cfg, bundle):
    env, cut = cut_plan(cfg, bundle)
    start = cut.latent_sets[0]
    plan = Plan(skills=("rearrange",), attention=((0,),), latent_sets=(start, start), feasibilities=(1.0,), cost=0.0,
                score=0.0, planning_time_s=0.0)
    before = env.step_count
    reached = replaced(bundle, vae=FixedDecoder(env.observation().dough_points))
    execution = execute_plan(cfg, reached, env, plan, "policy", np.random.default_rng(0))
    assert execution.steps[0].skipped and not execution.steps[0].attended.any()
    assert env.step_count == before


def test_already_reached_needs_the_same_pieces_and_a_small_chamfer():
    rng = np.random.default_rng(0)
    points = rng.uniform((0.4, 0.1, 0.4), (0.6, 0.15, 0.5), size=(500, 3))
    labels = np.zeros(500, dtype=np.int64)
    assert already_reached(points, labels, points[::-1], n_entities=1)
    assert not already_reached(points, labels, points, n_entities=2), "a planned cut is not skipped"
    assert not already_reached(points, labels, points + [0.0, 0.0, 0.2], n_entities=1)


def test_unknown_executor_is_refused(cfg, bundle):
    with pytest.raises(ValueError, match="'magic'.*policy.*scripted"):
        execute_plan(cfg, bundle, None, None, "magic", np.random.default_rng(0))


def test_a_skill_that_blows_up_the_simulation_is_undone_and_reported(cfg, bundle, monkeypatch, tmp_path):
    monkeypatch.setenv("PASTA_HOME", str(tmp_path))
    env, plan = cut_plan(cfg, bundle)
    before = env.particles().copy()
    real_step = env.step

    def blow_up_on_third_step(action):
        if env.step_count >= cfg.sim.settle_steps + 2:
            raise SimulationError(f"simulation blew up at step {env.step_count}: non-finite particle state")
        return real_step(action)

    monkeypatch.setattr(env, "step", blow_up_on_third_step)
    execution = execute_plan(cfg, bundle, env, plan, "scripted", np.random.default_rng(0))
    assert execution.steps == ()
    assert execution.failure is not None and execution.failure.startswith("plan step 1 (cut): simulation blew up")
    np.testing.assert_array_equal(env.particles(), before)
    np.testing.assert_array_equal(execution.final.dough_points, env.observation().dough_points)


def test_a_real_blow_up_is_kept_and_replays_without_the_models(cfg, bundle, monkeypatch, tmp_path):
    """Dough a thousand times stiffer than the task's blows up on the cut's first step; the execution keeps the
    start and the actions, and a replay from the file alone raises the same error."""
    monkeypatch.setenv("PASTA_HOME", str(tmp_path))
    env, plan = cut_plan(cfg, bundle)
    stiff = cfg.model_copy(update={"material": cfg.material.model_copy(update={"youngs_modulus_pa": 5e6})})
    stiff_env = make_env(stiff)
    stiff_env.set_state(env.get_state())
    execution = execute_plan(stiff, bundle, stiff_env, plan, "scripted", np.random.default_rng(0))
    failure = execution.failure
    assert failure is not None and "simulation blew up" in failure, failure
    kept = Path(failure.rsplit("kept for replay: ", 1)[1].rstrip(")"))
    assert kept.parent == tmp_path / "blowups" and kept.is_file()
    kept_cfg, _, actions, message = load_blowup(kept)
    assert kept_cfg == stiff and len(actions) >= 1 and message in failure
    with pytest.raises(SimulationError) as replayed:
        replay_blowup(kept)
    assert str(replayed.value) == message
    before = replay_blowup(kept, n_actions=len(actions) - 1)  # the step before the one that blew up
    assert np.isfinite(before.particles()).all()
