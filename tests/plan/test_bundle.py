from __future__ import annotations

import pytest
import torch

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.plan import DEFAULT_HALVING, PlanSettings, bundle_functions, bundle_skills, plan, plan_receding_horizon
from pasta.train import untrained

PRIOR = LatentPrior(2, (0.2, 0.0, 0.2), (0.8, 0.2, 0.8))


def test_settings_from_config():
    cut_rearrange = PlanSettings.from_config(load("CutRearrange", "paper"))
    assert (cut_rearrange.lr, cut_rearrange.iterations, cut_rearrange.samples) == (0.01, 100, 5000)
    assert cut_rearrange.alpha == 10.0 and cut_rearrange.halving == DEFAULT_HALVING
    crs_twice = PlanSettings.from_config(load("CRS-Twice", "paper"), halving=(), seed=3)
    assert (crs_twice.iterations, crs_twice.alpha, crs_twice.halving, crs_twice.seed) == (300, 100.0, (), 3)


def test_the_feasibility_floor_comes_from_the_config():
    """The earlier planner's 0.01 unless the config lowers it; a floor outside (0, 1) is refused by name."""
    assert PlanSettings.from_config(load("CRS", "paper")).feasibility_floor == 0.01
    lowered = load("CRS", "paper", ["plan.feasibility_floor=1e-12"])
    assert PlanSettings.from_config(lowered).feasibility_floor == 1e-12
    with pytest.raises(ValueError, match="feasibility_floor"):
        load("CRS", "paper", ["plan.feasibility_floor=0"])


def test_untrained_bundle_plans_and_keeps_its_parameters_trainable():
    bundle = untrained(load("CutRearrange", "smoke"), "pasta", PRIOR)
    assert [(s.name, s.n_in, s.n_out) for s in bundle_skills(bundle)] == [("cut", 1, 2), ("rearrange", 1, 1)]
    gen = torch.Generator().manual_seed(0)
    obs, goal = PRIOR.sample((1,), gen), PRIOR.sample((2,), gen)
    settings = PlanSettings(lr=0.01, iterations=4, samples=6, alpha=10.0)
    result = plan(bundle, obs, goal, 3, settings)
    assert result.skills.count("cut") == 1 and len(result.skills) == 3
    assert [u.shape for u in result.latent_sets][-1] == (2, 5)
    assert all(0 <= f <= 1 for f in result.feasibilities)
    assert all(p.requires_grad for p in bundle.cost.parameters())
    with pytest.raises(ValueError, match=r"obs must have shape \(K, 5\), got \(1, 7\)"):
        plan(bundle, torch.zeros(1, 7), goal, 3, settings)


def test_untrained_bundle_receding_horizon():
    bundle = untrained(load("CRS", "smoke"), "pasta", PRIOR)
    gen = torch.Generator().manual_seed(0)
    obs, goal = PRIOR.sample((1,), gen), PRIOR.sample((3,), gen)
    settings = PlanSettings(lr=0.01, iterations=3, samples=4, alpha=100.0)
    sequence = ("cut", "push", "spread") * 2
    result = plan_receding_horizon(bundle, obs, goal, sequence, 3, settings)
    assert result.skills == sequence
    assert [u.shape[0] for u in result.latent_sets] == [1, 2, 2, 2, 3, 3, 3]
    torch.testing.assert_close(result.latent_sets[0], obs)
    arity = {s.name: (s.n_in, s.n_out) for s in bundle_skills(bundle)}
    for h, skill in enumerate(sequence, start=1):
        before, after, attended = result.latent_sets[h - 1], result.latent_sets[h], result.attention[h - 1]
        n_in, n_out = arity[skill]
        assert len(attended) == n_in and len(set(attended)) == n_in and max(attended) < before.shape[0]
        kept = [i for i in range(before.shape[0]) if i not in attended]
        assert after.shape[0] == n_out + len(kept)
        torch.testing.assert_close(after[n_out:], before[kept])  # U^h = [the new entities, then the kept ones]


def test_whole_scene_variant_plans_one_entity():
    bundle = untrained(load("CutRearrange", "smoke"), "flat3d", PRIOR)
    assert {(s.n_in, s.n_out) for s in bundle_skills(bundle)} == {(1, 1)}


def test_gather_arities_share_one_feasibility_network():
    bundle = untrained(load("GatherMove", "smoke"), "pasta", PRIOR)
    assert [(s.name, s.n_in) for s in bundle_skills(bundle)] == [("gather", 1), ("gather", 2), ("gather", 3),
                                                                 ("move", 1)]
    functions = bundle_functions(bundle)
    gen = torch.Generator().manual_seed(0)
    two, one = PRIOR.sample((1, 2), gen), PRIOR.sample((1, 1), gen)
    network = bundle.feasibility("gather")
    with torch.no_grad():
        assert torch.equal(functions.feasibility(1, two, one), network(two, one))
        assert torch.equal(functions.feasibility(0, two[:, :1], one), network(two[:, :1], one))
    obs, goal = PRIOR.sample((2,), gen), PRIOR.sample((1,), gen)
    result = plan(bundle, obs, goal, 2, PlanSettings(lr=0.01, iterations=3, samples=8, alpha=100.0))
    gathers = [len(a) for skill, a in zip(result.skills, result.attention, strict=True) if skill == "gather"]
    assert 2 in gathers and [u.shape[0] for u in result.latent_sets][-1] == 1
