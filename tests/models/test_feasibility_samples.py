"""Latent prior, latent noise, random and hard negatives, and the assembled feasibility batch."""

from __future__ import annotations

import pytest
import torch

from pasta.models import LatentPrior, add_latent_noise, feasibility_batch, hard_negatives, random_negatives

PRIOR = LatentPrior(2, (0.1, 0.2, 0.3), (0.5, 0.4, 0.9))


def test_prior_samples_z_gaussian_and_t_in_the_box():
    u = PRIOR.sample((20000,), torch.Generator().manual_seed(0))
    assert u.shape == (20000, 5)
    z, t = u[:, :2], u[:, 2:]
    assert z.mean(0).abs().max() < 0.03 and (z.std(0) - 1).abs().max() < 0.03
    low, high = torch.tensor(PRIOR.t_low), torch.tensor(PRIOR.t_high)
    assert bool(((t >= low) & (t <= high)).all())
    assert ((t.min(0).values - low).abs().max() < 0.01) and ((t.max(0).values - high).abs().max() < 0.01)
    again = PRIOR.sample((20000,), torch.Generator().manual_seed(0))
    assert torch.equal(u, again)


def test_prior_from_centres_and_validation():
    centres = torch.tensor([[0.1, 0.5, 0.2], [0.4, 0.3, 0.6]])
    prior = LatentPrior.from_centres(centres, 2)
    assert prior.t_low == pytest.approx((0.1, 0.3, 0.2)) and prior.t_high == pytest.approx((0.4, 0.5, 0.6))
    with pytest.raises(ValueError):
        LatentPrior(2, (0.5, 0.0, 0.0), (0.4, 1.0, 1.0))


def test_random_negatives_shapes():
    obs, goal = random_negatives(PRIOR, 7, 1, 2, torch.Generator().manual_seed(1))
    assert obs.shape == (7, 1, 5) and goal.shape == (7, 2, 5)
    low, high = torch.tensor(PRIOR.t_low), torch.tensor(PRIOR.t_high)
    for u in (obs, goal):
        t = u[..., 2:]
        assert bool(((t >= low) & (t <= high)).all()), "every centre lies inside the prior's box"
    assert not torch.equal(obs[:, 0], goal[:, 0]) and not torch.equal(goal[:, 0], goal[:, 1]), "independent draws"
    again = random_negatives(PRIOR, 7, 1, 2, torch.Generator().manual_seed(1))
    assert torch.equal(again[0], obs) and torch.equal(again[1], goal)
    other = random_negatives(PRIOR, 7, 1, 2, torch.Generator().manual_seed(2))
    assert not torch.equal(other[0], obs) and not torch.equal(other[1], goal)


def test_latent_noise_scales_each_part():
    u = torch.zeros(50000, 5)
    noisy = add_latent_noise(u, 2, 0.02, 0.01, torch.Generator().manual_seed(2))
    std = noisy.std(0)
    torch.testing.assert_close(std, torch.tensor([0.02, 0.02, 0.01, 0.01, 0.01]), atol=5e-4, rtol=0)
    assert torch.equal(add_latent_noise(u, 2, 0.0, 0.0, torch.Generator()), u)
    only_t = add_latent_noise(u, 2, 0.0, 0.1, torch.Generator().manual_seed(3))
    assert torch.equal(only_t[:, :2], u[:, :2]) and bool((only_t[:, 2:] != 0).all())


def test_hard_negatives_differ_in_exactly_one_real_entity():
    gen = torch.Generator().manual_seed(4)
    obs, goal = torch.randn(5, 2, 5, generator=gen), torch.randn(5, 3, 5, generator=gen)
    obs_mask = torch.tensor([[True, True], [True, False], [True, True], [True, False], [True, True]])
    goal_mask = torch.tensor([[True, True, True], [True, False, False]] * 2 + [[True, True, False]])
    hard = hard_negatives(obs, goal, obs_mask, goal_mask, PRIOR, 10, gen)
    assert hard.obs.shape == (50, 2, 5) and hard.goal.shape == (50, 3, 5) and hard.replaced.shape == (50,)
    source = torch.cat([obs, goal], 1).repeat_interleave(10, 0)
    result = torch.cat([hard.obs, hard.goal], 1)
    changed = (result != source).any(-1)  # (50, 5)
    assert bool((changed.sum(1) == 1).all())
    assert torch.equal(changed.float().argmax(1), hard.replaced)
    valid = torch.cat([obs_mask, goal_mask], 1).repeat_interleave(10, 0)
    assert bool(valid[torch.arange(50), hard.replaced].all())  # padded slots are never replaced
    assert torch.equal(torch.cat([hard.obs_mask, hard.goal_mask], 1), valid)
    t = result[torch.arange(50), hard.replaced][:, 2:]
    assert bool(((t >= torch.tensor(PRIOR.t_low)) & (t <= torch.tensor(PRIOR.t_high))).all())
    # both sides get replaced sometimes
    assert bool((hard.replaced < 2).any()) and bool((hard.replaced >= 2).any())


def test_feasibility_batch_layout_labels_and_weights():
    gen = torch.Generator().manual_seed(5)
    obs, goal = torch.randn(4, 1, 5, generator=gen), torch.randn(4, 2, 5, generator=gen)
    batch = feasibility_batch(obs, goal, None, None, PRIOR, sigma_z=0.0, sigma_t=0.0, hard_copies=3, n_random=8,
                              generator=gen)
    assert batch.obs.shape == (4 + 12 + 8, 1, 5) and batch.goal.shape == (24, 2, 5)
    assert torch.equal(batch.labels, torch.cat([torch.ones(4), torch.zeros(20)]))
    torch.testing.assert_close(batch.weights[:4].sum(), torch.tensor(0.5))
    torch.testing.assert_close(batch.weights[4:16].sum(), torch.tensor(0.25))
    torch.testing.assert_close(batch.weights[16:].sum(), torch.tensor(0.25))
    assert torch.equal(batch.obs[:4], obs)  # no noise when both sigmas are 0
    noisy = feasibility_batch(obs, goal, None, None, PRIOR, sigma_z=0.1, sigma_t=0.1, hard_copies=1, n_random=1,
                              generator=gen)
    assert not torch.equal(noisy.obs[:4], obs)
