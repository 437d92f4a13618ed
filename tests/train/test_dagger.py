"""DAgger rounds (pasta.train.dagger): the policies' own rollouts of fresh oracle chains, every step labelled by
the tracking expert; at smoke, with untrained networks (the mechanics do not depend on training)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from pasta.data.configurations import oracle_chain
from pasta.models.latent_prior import LatentPrior
from pasta.train.bundle import untrained
from pasta.train.dagger import DAGGER_GENERATOR_SEED, collect_visits

CHUNK = 3


@pytest.fixture(scope="module")
def setting():
    from pasta.config import load

    cfg = load("CutRearrange", "smoke")
    cfg = cfg.model_copy(update={"policy": cfg.policy.model_copy(update={"chunk": CHUNK, "phase_input": True})})
    prior = LatentPrior(cfg.train.latent_dim, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
    return cfg, untrained(cfg, "pasta", prior, seed=0).eval()


def test_each_step_of_each_skill_is_recorded_with_its_phase_and_an_expert_chunk(setting):
    cfg, bundle = setting
    visits = collect_visits(cfg, bundle, [0], seed=0, expert_share=0.0)
    chain = [step.skill for step in oracle_chain(cfg, 0, DAGGER_GENERATOR_SEED)]
    n, action_dim = cfg.sim.steps_per_skill, bundle.action_dim
    assert set(visits) == set(chain)
    for skill, samples in visits.items():
        runs = chain.count(skill)
        assert len(samples) == runs * n
        assert samples.obs_points.shape == (runs * n, cfg.policy.points, 3)
        assert samples.goal_points.shape == (runs * n, cfg.policy.points, 3)
        assert samples.action_chunks.shape == (runs * n, CHUNK * action_dim)
        np.testing.assert_allclose(samples.phases.numpy(), np.tile(np.arange(n) / n, runs), atol=1e-6)
        chunks = samples.action_chunks.reshape(-1, CHUNK, action_dim)
        torch.testing.assert_close(samples.actions, chunks[:, 0])
        assert torch.isfinite(chunks).all() and chunks.abs().max() <= 1.0
        last = chunks.reshape(runs, n, CHUNK, action_dim)[:, -1]
        assert not last[:, 1:].any()  # after the skill's last step the expert does nothing
        assert chunks.abs().sum() > 0


def test_with_the_expert_acting_the_tool_stays_on_its_path_and_runs_repeat(setting):
    """At ``expert_share`` 1 the expert's chunks are executed: the tool stays on the scripted path, so each
    step's chunk continues the previous step's (the label at ``k + 1`` is the one planned at ``k`` for ``k + 1``)."""
    cfg, bundle = setting
    first = collect_visits(cfg, bundle, [1], seed=3, expert_share=1.0)
    again = collect_visits(cfg, bundle, [1], seed=3, expert_share=1.0)
    n, action_dim = cfg.sim.steps_per_skill, bundle.action_dim
    for skill, samples in first.items():
        torch.testing.assert_close(samples.action_chunks, again[skill].action_chunks)
        torch.testing.assert_close(samples.obs_points, again[skill].obs_points)
        chunks = samples.action_chunks.reshape(-1, n, CHUNK, action_dim)
        torch.testing.assert_close(chunks[:, 1:, 0], chunks[:, :-1, 1], atol=2e-3, rtol=0)
        previous = samples.previous_actions.reshape(-1, n, action_dim)  # what was applied the step before
        assert not previous[:, 0].any()
        torch.testing.assert_close(previous[:, 1:], chunks[:, :-1, 0], atol=2e-3, rtol=0)


def test_with_the_demonstrated_range_the_policys_actions_are_held_to_it_and_the_experts_are_not(setting):
    """A range of zeros in every dimension: the policy's actions are applied as zeros, the expert's unchanged."""
    cfg, bundle = setting
    held = cfg.model_copy(update={"eval": cfg.eval.model_copy(update={"policy_action_range": "demonstrated"})})
    with pytest.raises(ValueError, match="needs a bundle that kept its demonstrations' action range"):
        collect_visits(held, bundle, [0], seed=0, expert_share=0.0)
    zeros = ((0.0,) * bundle.action_dim, (0.0,) * bundle.action_dim)
    ranged = dataclasses.replace(bundle, action_range=(zeros, zeros))
    for samples in collect_visits(held, ranged, [0], seed=0, expert_share=0.0).values():
        assert not samples.previous_actions.any() and samples.action_chunks.abs().sum() > 0
    n, action_dim = cfg.sim.steps_per_skill, bundle.action_dim
    for samples in collect_visits(held, ranged, [1], seed=3, expert_share=1.0).values():
        chunks = samples.action_chunks.reshape(-1, n, CHUNK, action_dim)
        previous = samples.previous_actions.reshape(-1, n, action_dim)
        assert previous.abs().sum() > 0
        torch.testing.assert_close(previous[:, 1:], chunks[:, :-1, 0], atol=2e-3, rtol=0)


def test_a_share_outside_zero_to_one_is_refused(setting):
    cfg, bundle = setting
    with pytest.raises(ValueError, match="expert_share"):
        collect_visits(cfg, bundle, [0], seed=0, expert_share=1.5)


def test_rounds_train_on_their_visits_keep_them_and_resume_without_simulating(tmp_path, cfg, training_data,
                                                                               monkeypatch):
    """Two rounds on the tiny synthetic dataset, whose clouds the smoke simulator cannot produce: the collector
    hands back demonstration samples relabelled with a fixed action (the simulated collection is tested above).
    Each round trains on the visits so far, keeps them and its policy progress beside the stem and reports steps
    counted on from ``first_step``; a rerun (a fresh bundle, as after an interruption) collects nothing and ends
    with the same weights."""
    from pasta.train import dagger
    from pasta.train.policy_loop import PolicySettings
    from tests.train.helpers import heads_inputs

    config, _, latents, prior, sampler, _ = heads_inputs(cfg, training_data, "pasta")
    rng = np.random.default_rng(0)
    held_out = [sampler.policy_samples(k, sampler.transitions[k], rng, 8) for k in range(2)]
    collected = []

    def collect(cfg, bundle, config_ids, *, seed, expert_share):
        collected.append((tuple(config_ids), seed, expert_share))
        samples = sampler.policy_samples(0, sampler.transitions[0], np.random.default_rng(seed), 6)
        label = torch.full_like(samples.actions, 0.5)
        return {"cut": dataclasses.replace(samples, actions=label, action_chunks=label)}

    monkeypatch.setattr(dagger, "collect_visits", collect)
    policy = PolicySettings(steps=3, lr=1e-3, batch_size=4, point_noise=0.0, eval_every=3)
    settings = dagger.DaggerSettings(rounds=2, problems=3, expert_share=0.25, steps=2, lr=1e-3)
    bundle = untrained(cfg, "pasta", prior, model_config=config, seed=0)
    calls = []
    results = dagger.dagger_rounds(cfg, bundle, sampler, held_out, latents, policy, settings, tmp_path / "run",
                                   first_step=3, on_epoch=lambda stage, step, metrics: calls.append((stage, step)))
    assert collected == [((0, 1, 2), 1, 0.25), ((3, 4, 5), 2, 0.25)]  # fresh problems per round
    assert [r.steps for r in results] == [{"cut": 2, "rearrange": 2}] * 2
    assert calls == [("dagger", 3), ("dagger", 5), ("dagger", 5), ("dagger", 7)]
    assert all(dagger.visits_path(tmp_path / "run", r).is_file() for r in (1, 2))
    assert (tmp_path / "run-dagger-2-policy.pt").is_file()

    monkeypatch.setattr(dagger, "collect_visits", lambda *args, **kwargs: pytest.fail("a resumed round collected"))
    again = untrained(cfg, "pasta", prior, model_config=config, seed=1)
    dagger.dagger_rounds(cfg, again, sampler, held_out, latents, policy, settings, tmp_path / "run", first_step=3)
    for a, b in zip(bundle.models["policy"].parameters(), again.models["policy"].parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def test_a_latent_set_policy_cannot_take_visits(tmp_path, cfg, training_data):
    from pasta.train import dagger
    from pasta.train.policy_loop import PolicySettings
    from tests.train.helpers import heads_inputs

    config, _, latents, prior, sampler, _ = heads_inputs(cfg, training_data, "shared_encoder_policy")
    bundle = untrained(cfg, "shared_encoder_policy", prior, model_config=config, seed=0)
    policy = PolicySettings(steps=1, lr=1e-3, batch_size=4, point_noise=0.0)
    settings = dagger.DaggerSettings(rounds=1, problems=1, expert_share=0.5, steps=1, lr=1e-3)
    with pytest.raises(ValueError, match="shared_encoder_policy"):
        dagger.dagger_rounds(cfg, bundle, sampler, [None, None], latents, policy, settings, tmp_path / "run")


def test_a_share_of_the_visits_is_held_out_beside_the_demonstrations(cfg, training_data):
    from pasta.train.dagger import split_visits
    from pasta.train.visits import VisitPool
    from tests.train.helpers import heads_inputs

    _, _, _, _, sampler, _ = heads_inputs(cfg, training_data, "pasta")
    demos = sampler.policy_samples(0, sampler.transitions[0], np.random.default_rng(0), 8)
    visits = sampler.policy_samples(0, sampler.transitions[0], np.random.default_rng(1), 20)
    train, held = split_visits(VisitPool((visits, None)), [demos, None], 0.1, seed=0)
    assert train.count(0) == 18 and train.count(1) == 0
    assert len(held[0]) == 8 + 2 and held[1] is None
    torch.testing.assert_close(held[0].actions[:8], demos.actions)
    kept = torch.cat([train.samples[0].obs_points, held[0].obs_points[8:]])
    assert sorted(kept.sum(dim=(1, 2)).tolist()) == pytest.approx(sorted(visits.obs_points.sum(dim=(1, 2)).tolist()))
