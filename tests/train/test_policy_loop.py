"""The policies' own loop: the step budget, the learning-rate schedule, early stopping with the best weights
restored, the logged step counts and an exact resume."""

from __future__ import annotations

import copy
import dataclasses
import math
from collections import Counter

import numpy as np
import pytest
import torch

from pasta.models import variant_spec
from pasta.models.checkpoint import load_checkpoint
from pasta.models.policy_ensemble import PolicyEnsemble
from pasta.train import policy_loop
from pasta.train.bundle import load_trained, save_trained, untrained
from pasta.train.datasets import TransitionSampler
from pasta.train.entities import PairChamfer
from pasta.train.policy_loop import PolicySettings, lr_at, train_policies, weighted_rows
from tests.train.helpers import heads_inputs

SETTINGS = PolicySettings(steps=7, lr=3e-3, batch_size=4, point_noise=0.005, eval_every=3)


@pytest.fixture()
def setup(cfg, training_data):
    """A fresh bundle, the training sampler, the latents and held-out samples for both skills (drawn from the
    training transitions: the tiny held-out split has no rearrange trajectory)."""
    config, _, latents, prior, sampler, _ = heads_inputs(cfg, training_data, "pasta")
    rng = np.random.default_rng(0)
    held_out = [sampler.policy_samples(k, sampler.transitions[k], rng, 8) for k in range(2)]
    return untrained(cfg, "pasta", prior, model_config=config, seed=0), sampler, latents, held_out


def _states(policies):
    return [copy.deepcopy(policy.state_dict()) for policy in policies]


def _equal(a, b):
    return all(torch.equal(x[key], y[key]) for x, y in zip(a, b, strict=True) for key in x)


def test_cosine_schedule_falls_from_lr_towards_zero_and_constant_stays():
    cosine = PolicySettings(steps=100, lr=1e-3, batch_size=10, point_noise=0.0, lr_schedule="cosine")
    values = [lr_at(step, cosine) for step in range(100)]
    assert values[0] == pytest.approx(1e-3)
    assert values[50] == pytest.approx(0.5e-3)
    assert values[99] == pytest.approx(1e-3 * 0.5 * (1 + math.cos(math.pi * 0.99)))
    assert all(a > b > 0 for a, b in zip(values, values[1:], strict=False))
    constant = dataclasses.replace(cosine, lr_schedule="constant")
    assert {lr_at(step, constant) for step in range(100)} == {1e-3}


@pytest.mark.parametrize("bad", [dict(steps=0), dict(eval_every=0), dict(patience=0), dict(lr=0.0),
                                 dict(lr_schedule="step")])
def test_settings_refuse_bad_values(bad):
    with pytest.raises(ValueError):
        dataclasses.replace(SETTINGS, **bad)


def test_without_early_stop_every_skill_takes_exactly_the_budget(tmp_path, setup):
    bundle, sampler, latents, held_out = setup
    calls = []
    result = train_policies(bundle, sampler, held_out, latents, SETTINGS, tmp_path / "p.pt",
                            on_epoch=lambda stage, step, metrics: calls.append((stage, step, metrics)))
    assert result.steps == {"cut": 7, "rearrange": 7}
    assert result.metrics()["policy_steps_cut"] == result.metrics()["policy_steps_rearrange"] == 7
    # Adam counts the updates of every parameter: 7 for each of both policies
    state = load_checkpoint(tmp_path / "p.pt").optimiser_states["policy"]["state"]
    assert len(state) == len(list(bundle.models["policy"].parameters()))
    assert {float(s["step"]) for s in state.values()} == {7.0}
    # evaluated untrained, then after each round of 3 steps and after the last, shorter one
    assert [(stage, step) for stage, step, _ in calls] == [("policy", s) for s in (0, 3, 6, 7)]
    assert [s for s, _ in result.curve] == [0, 3, 6, 7]
    for step, metrics in result.curve:
        assert {"policy_heldout_mse_cut", "policy_heldout_mse_rearrange"} <= set(metrics)
        if step:  # the rate of the round's last step follows the cosine schedule
            assert metrics["policy_lr"] == pytest.approx(lr_at(step - 1, SETTINGS))


def test_learning_rate_of_every_step_follows_the_schedule(tmp_path, setup, monkeypatch):
    bundle, sampler, latents, held_out = setup
    seen = []
    step = torch.optim.Adam.step

    def recording_step(self, *args, **kwargs):
        seen.append(self.param_groups[0]["lr"])
        return step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.Adam, "step", recording_step)
    train_policies(bundle, sampler, held_out, latents, SETTINGS, tmp_path / "p.pt")
    assert seen == pytest.approx([lr_at(s, SETTINGS) for s in range(SETTINGS.steps)])


def test_early_stopping_stops_after_patience_and_restores_the_best_weights(tmp_path, setup, monkeypatch):
    bundle, sampler, latents, held_out = setup
    # held-out MSE per evaluation of each policy (steps 0, 2, 4, 6, ...): best at step 2, then rising
    scripted = [1.0, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    evaluations = Counter()

    def fake_mse(policy, *args):
        evaluations[id(policy)] += 1
        return scripted[evaluations[id(policy)] - 1]

    monkeypatch.setattr(policy_loop, "heldout_mse", fake_mse)
    settings = dataclasses.replace(SETTINGS, steps=12, eval_every=2, patience=2)
    weights = {}

    def remember(stage, step, metrics):
        weights[step] = _states(bundle.models["policy"])

    result = train_policies(bundle, sampler, held_out, latents, settings, tmp_path / "p.pt", on_epoch=remember)
    # no better value at steps 4 and 6: both skills stop after 6 of their 12 steps
    assert result.steps == {"cut": 6, "rearrange": 6}
    assert result.best_steps == {"cut": 2, "rearrange": 2}
    assert [s for s, _ in result.curve] == [0, 2, 4, 6]
    assert [m["policy_heldout_mse_cut"] for _, m in result.curve] == [1.0, 0.5, 0.6, 0.7]
    final = _states(bundle.models["policy"])
    assert _equal(final, weights[2])
    assert not _equal(final, weights[6])


def test_resume_after_an_interruption_ends_like_an_uninterrupted_run(tmp_path, cfg, training_data):
    class Interrupt(Exception):
        pass

    def stop(stage, step, metrics):
        if step == 3:
            raise Interrupt

    def fresh():
        config, _, latents, prior, sampler, _ = heads_inputs(cfg, training_data, "pasta")
        held_out = [sampler.policy_samples(k, sampler.transitions[k], np.random.default_rng(0), 8) for k in range(2)]
        return untrained(cfg, "pasta", prior, model_config=config, seed=0), sampler, latents, held_out

    bundle, sampler, latents, held_out = fresh()
    straight = train_policies(bundle, sampler, held_out, latents, SETTINGS, tmp_path / "a.pt")
    resumed_bundle, sampler, latents, held_out = fresh()
    with pytest.raises(Interrupt):
        train_policies(resumed_bundle, sampler, held_out, latents, SETTINGS, tmp_path / "b.pt", on_epoch=stop)
    resumed_bundle, sampler, latents, held_out = fresh()
    steps = []
    resumed = train_policies(resumed_bundle, sampler, held_out, latents, SETTINGS, tmp_path / "b.pt",
                             on_epoch=lambda stage, step, metrics: steps.append(step))
    assert steps == [6, 7]
    assert _equal(_states(bundle.models["policy"]), _states(resumed_bundle.models["policy"]))
    assert (resumed.steps, resumed.best_steps) == (straight.steps, straight.best_steps)
    untimed = [[(s, {k: v for k, v in m.items() if k != "policy_round_s"}) for s, m in r.curve]
               for r in (straight, resumed)]
    assert untimed[0] == untimed[1]


def test_bf16_training_runs_the_policy_in_bfloat16_and_still_lowers_its_loss(tmp_path, setup, monkeypatch):
    bundle, sampler, latents, held_out = setup
    seen_dtypes = []
    forward = policy_loop.policy_forward

    def recording(*args, **kwargs):
        actions = forward(*args, **kwargs)
        seen_dtypes.append(actions.dtype)
        return actions

    monkeypatch.setattr(policy_loop, "policy_forward", recording)
    settings = dataclasses.replace(SETTINGS, steps=12, eval_every=12, precision="bf16")
    result = train_policies(bundle, sampler, held_out, latents, settings, tmp_path / "p.pt")
    # the training forwards ran under bf16 autocast; the held-out evaluations stay float32
    assert torch.bfloat16 in seen_dtypes and torch.float32 in seen_dtypes
    first, last = result.curve[0][1], result.curve[-1][1]
    for skill in ("cut", "rearrange"):
        assert math.isfinite(last[f"policy_heldout_mse_{skill}"])
        assert last[f"policy_heldout_mse_{skill}"] < first[f"policy_heldout_mse_{skill}"], (first, last)
    assert all(p.dtype == torch.float32 for p in bundle.models["policy"].parameters())


def test_an_unknown_precision_is_refused_by_name():
    with pytest.raises(ValueError, match="'fp16'"):
        dataclasses.replace(SETTINGS, precision="fp16")


def test_a_chunking_policy_with_dough_frame_and_phase_fits_every_step_of_its_chunks(tmp_path, cfg, training_data):
    """``policy.chunk: 3``, ``frame: dough``, ``phase_input``: the loss compares all three predicted steps with
    the demonstrated ones (a loss over the first step alone would leave the other outputs where they started),
    and the held-out MSE is that of the first."""
    config, _, latents, prior, _, _ = heads_inputs(cfg, training_data, "pasta")
    cfg = cfg.model_copy(update={"policy": cfg.policy.model_copy(update={"frame": "dough", "phase_input": True,
                                                                         "chunk": 3})})
    bundle = untrained(cfg, "pasta", prior, model_config=config, seed=0)
    assert bundle.model_config.policy.chunk == 3 and bundle.model_config.policy.frame == "dough"
    sampler = TransitionSampler(training_data.demos, training_data.table, cfg.skills, training_data.heads_train,
                                0.0, PairChamfer(training_data.table), chunk=3)
    rows = sampler.transitions[0]
    held_out = [sampler.policy_samples(k, sampler.transitions[k], np.random.default_rng(0), 8) for k in range(2)]
    samples = held_out[0]

    def later_steps_error() -> float:
        with torch.no_grad():
            predicted = policy_loop.policy_forward(bundle.models["policy"][0].eval(), variant_spec("pasta"), samples,
                                                   latents, 2)
        assert predicted.shape == (len(samples), 3 * bundle.action_dim) and len(rows)
        return float((predicted[:, bundle.action_dim :] - samples.action_chunks[:, bundle.action_dim :]).square()
                     .sum(1).mean())

    before = later_steps_error()
    settings = dataclasses.replace(SETTINGS, steps=30, eval_every=30)
    result = train_policies(bundle, sampler, held_out, latents, settings, tmp_path / "p.pt")
    assert later_steps_error() < 0.7 * before
    first = policy_loop.heldout_mse(bundle.models["policy"][0], variant_spec("pasta"), samples, latents, 2)
    assert first == pytest.approx(result.curve[-1][1]["policy_heldout_mse_cut"], rel=1e-5)


def test_visited_states_join_every_batch_and_pull_the_policy_to_their_labels(tmp_path, setup):
    """DAgger's visits (``VisitPool``): states no demonstration shows (dough and tool 0.3 higher), labelled with an
    action no demonstration takes. Trained with them, the cut policy learns that action there; without, not."""
    from pasta.train.visits import VisitPool, take_samples

    bundle, sampler, latents, held_out = setup
    states = held_out[0]
    label = torch.zeros_like(states.actions)
    label[:, :2] = torch.tensor([-0.8, 0.8])
    lift = torch.tensor([0.0, 0.3, 0.0])
    visited = dataclasses.replace(take_samples(states, np.arange(len(states))), obs_points=states.obs_points + lift,
                                  tool_points=states.tool_points + lift, actions=label, action_chunks=label)
    pool = VisitPool((visited, None))
    assert pool.count(0) == len(states) and pool.count(1) == 0
    assert pool.draw(1, 4, np.random.default_rng(0)) is None
    assert len(pool.draw(0, 3 * len(states), np.random.default_rng(0))) == 3 * len(states)
    spec = variant_spec("pasta")
    settings = dataclasses.replace(SETTINGS, steps=40, eval_every=40)
    without = copy.deepcopy(bundle)
    train_policies(bundle, sampler, [visited, held_out[1]], latents, settings, tmp_path / "with.pt", visits=pool)
    train_policies(without, sampler, [visited, held_out[1]], latents, settings, tmp_path / "without.pt")
    error_with = policy_loop.heldout_mse(bundle.models["policy"][0], spec, visited, latents, 2)
    error_without = policy_loop.heldout_mse(without.models["policy"][0], spec, visited, latents, 2)
    assert error_with < 0.5 * error_without, (error_with, error_without)


def test_mirrored_training_with_shape_and_gap_features_learns_and_is_set_for_cloud_set_policies_only(
        tmp_path, cfg, training_data):
    """``train.policy_mirror``, ``policy.shape_quantiles`` and ``policy.gap_features``: the set policy trains on
    reflected samples (the batch's actions sign-flipped as the tools' kinematics say, ``pasta.train.mirror``) and
    its held-out MSE falls; the policies that read latents or a tool state are left unmirrored."""
    cfg = cfg.model_copy(update={
        "policy": cfg.policy.model_copy(update={"frame": "dough", "shape_quantiles": 5, "gap_features": True}),
        "train": cfg.train.model_copy(update={"policy_mirror": "xz"})})
    mirrored = PolicySettings.from_config(cfg, "pasta")
    assert mirrored.mirror_signs is not None and len(mirrored.mirror_signs[0]) == 10  # knife 3 + gripper 7
    assert PolicySettings.from_config(cfg, "shared_encoder_policy").mirror_signs is None
    assert PolicySettings.from_config(cfg, "tool_concat_policy").mirror_signs is None
    config, _, latents, prior, _, _ = heads_inputs(cfg, training_data, "pasta")
    bundle = untrained(cfg, "pasta", prior, model_config=config, seed=0)
    assert bundle.model_config.policy.shape_quantiles == 5 and bundle.model_config.policy.gap_features
    sampler = TransitionSampler(training_data.demos, training_data.table, cfg.skills, training_data.heads_train,
                                0.0, PairChamfer(training_data.table))
    held_out = [sampler.policy_samples(k, sampler.transitions[k], np.random.default_rng(0), 8) for k in range(2)]
    settings = dataclasses.replace(SETTINGS, steps=30, eval_every=30, mirror_signs=mirrored.mirror_signs)
    result = train_policies(bundle, sampler, held_out, latents, settings, tmp_path / "p.pt")
    start, end = result.curve[0][1], result.curve[-1][1]
    assert end["policy_heldout_mse_cut"] < 0.8 * start["policy_heldout_mse_cut"], result.curve


def test_first_steps_are_offered_first_step_weight_times_as_often(cfg):
    settings = PolicySettings.from_config(cfg.model_copy(update={"train": cfg.train.model_copy(
        update={"policy_first_step_weight": 7, "policy_mirror": "x"})}), "pasta")
    assert settings.first_step_weight == 7 and settings.mirror_planes == "x"
    assert PolicySettings.from_config(cfg, "pasta").mirror_signs is None  # "none" by default
    transitions = np.array([(0, 0), (0, 1), (0, 2), (3, 0), (3, 1)])
    rows = weighted_rows(transitions, 4)
    counts = np.bincount(rows, minlength=len(transitions))
    assert counts.tolist() == [4, 1, 1, 4, 1]
    assert np.array_equal(weighted_rows(transitions, 1), np.arange(5))



def test_mirroring_reflects_the_previous_action_as_it_reflects_the_chunk(cfg, training_data):
    """``train.policy_mirror`` with ``policy.previous_action``: the previous action is a tool motion like the
    chunk's, so a reflected sample's previous action gets the same sign flips as its actions."""
    sampler = TransitionSampler(training_data.demos, training_data.table, cfg.skills, training_data.heads_train,
                                0.0, PairChamfer(training_data.table), chunk=2)
    samples = sampler.policy_samples(0, sampler.transitions[0], np.random.default_rng(0), 16)
    width = samples.actions.shape[1]
    same = dataclasses.replace(samples, previous_actions=samples.actions.clone())  # previous = this step's action
    signs = PolicySettings.from_config(cfg.model_copy(update={
        "train": cfg.train.model_copy(update={"policy_mirror": "xz"})}), "pasta").mirror_signs
    mirrored = policy_loop._mirrored(same, signs, "xz", torch.Generator().manual_seed(3))
    torch.testing.assert_close(mirrored.previous_actions, mirrored.actions)
    torch.testing.assert_close(mirrored.actions, mirrored.action_chunks[:, :width])
    assert not torch.equal(mirrored.actions, samples.actions)  # some samples were reflected


def test_an_ensemble_trains_each_member_on_its_own_loss_acts_their_mean_and_survives_a_save(
        tmp_path, cfg, training_data):
    """``policy.members: 2``: both members start apart, each one's own held-out error falls (the loss is the mean
    of the members' losses, not the loss of their mean), the ensemble predicts the members' mean, and the bundle
    saved and loaded again predicts the same."""
    config, _, latents, prior, sampler, _ = heads_inputs(cfg, training_data, "pasta")
    cfg = cfg.model_copy(update={"policy": cfg.policy.model_copy(update={"members": 2})})
    bundle = untrained(cfg, "pasta", prior, model_config=config, seed=0)
    ensemble = bundle.models["policy"][0]
    assert isinstance(ensemble, PolicyEnsemble) and bundle.model_config.policy_members == 2
    first, second = ensemble.members
    assert not _equal([first.state_dict()], [second.state_dict()])
    rng = np.random.default_rng(0)
    held_out = [sampler.policy_samples(k, sampler.transitions[k], rng, 8) for k in range(2)]
    spec, samples = variant_spec("pasta"), held_out[0]

    def error(policy) -> float:
        return policy_loop.heldout_mse(policy, spec, samples, latents, 2)

    before = [error(member) for member in ensemble.members]
    settings = dataclasses.replace(SETTINGS, steps=30, eval_every=30)
    train_policies(bundle, sampler, held_out, latents, settings, tmp_path / "p.pt")
    after = [error(member) for member in ensemble.members]
    assert all(a < 0.7 * b for a, b in zip(after, before, strict=True))
    with torch.no_grad():
        members = [policy_loop.policy_forward(m.eval(), spec, samples, latents, 2) for m in ensemble.members]
        mean = policy_loop.policy_forward(ensemble.eval(), spec, samples, latents, 2)
    torch.testing.assert_close(mean, (members[0] + members[1]) / 2)
    save_trained(tmp_path / "models.pt", bundle)
    loaded = load_trained(tmp_path / "models.pt")
    assert loaded.model_config.policy_members == 2
    with torch.no_grad():
        again = policy_loop.policy_forward(loaded.models["policy"][0], spec, samples, latents, 2)
    torch.testing.assert_close(again, mean)


def test_the_ensemble_loss_is_the_mean_of_the_members_losses(cfg, training_data):
    """Without input noise the ensemble's training loss equals the mean of its members' losses, and a member's
    gradient is its own loss's over the member count: no member is trained through the others (the loss of the
    members' mean action would give every member a gradient that depends on the others' actions)."""
    config, _, latents, prior, sampler, _ = heads_inputs(cfg, training_data, "pasta")
    cfg = cfg.model_copy(update={"policy": cfg.policy.model_copy(update={"members": 3})})
    ensemble = untrained(cfg, "pasta", prior, model_config=config, seed=0).models["policy"][1]
    samples = sampler.policy_samples(1, sampler.transitions[1], np.random.default_rng(0), 8)
    settings, spec = dataclasses.replace(SETTINGS, point_noise=0.0), variant_spec("pasta")

    def loss(policy) -> torch.Tensor:
        return policy_loop.policy_loss(policy, spec, settings, samples, latents, 2, torch.Generator())

    members = [float(loss(member)) for member in ensemble.members]
    first = ensemble.members[0]
    ensemble.zero_grad()
    total = loss(ensemble)
    total.backward()
    together = [p.grad.clone() for p in first.parameters()]
    ensemble.zero_grad()
    loss(first).backward()
    for shared, alone in zip(together, first.parameters(), strict=True):
        torch.testing.assert_close(shared, alone.grad / 3)
    assert float(total) == pytest.approx(np.mean(members), rel=1e-5)
    with torch.no_grad():
        mean_action = policy_loop.policy_forward(ensemble, spec, samples, latents, 2)
    loss_of_mean = float((mean_action - samples.action_chunks[:, : mean_action.shape[1]]).square().sum(1).mean())
    assert loss_of_mean < float(np.mean(members))
