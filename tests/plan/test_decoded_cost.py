"""The decoded set cost: subset decoding, Chamfer against a double loop, gradients, and planning with it."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.models.vae import PointCloudVAE, VAEConfig
from pasta.plan import PlanningFunctions, PlanSettings, SkillSpec, bundle_functions, plan, plan_with
from pasta.plan.decoded_cost import decoded_chamfer_cost, subset_decoder
from pasta.train import untrained

PRIOR = LatentPrior(2, (0.2, 0.0, 0.2), (0.8, 0.2, 0.8))


def _vae(dtype: torch.dtype = torch.float32, height_input: bool = False) -> PointCloudVAE:
    torch.manual_seed(0)
    vae = PointCloudVAE(VAEConfig(encoder_channels=(16,), head_hidden=16, decoder_channels=(32, 32),
                                  n_decoded_points=40, height_input=height_input)).to(dtype).eval()
    vae.scale.fill_(0.05)
    return vae


def _slow_chamfer(p: torch.Tensor, q: torch.Tensor) -> float:
    forward = sum(min(float(((x - y) ** 2).sum()) for y in q) for x in p) / len(p)
    backward = sum(min(float(((x - y) ** 2).sum()) for x in p) for y in q) / len(q)
    return forward + backward


def test_subset_decoder_returns_the_full_decoders_strided_points():
    vae = _vae()
    z = torch.randn(5, 2)
    full = vae.decode_shape(z, torch.zeros(5, 3))  # (5, 40, 3)
    with torch.no_grad():
        subset = subset_decoder(vae, 8)(z).view(5, 8, 3)
    torch.testing.assert_close(subset, full[:, ::5].detach())
    assert not any(p.requires_grad for p in subset_decoder(vae, 8).parameters())
    with pytest.raises(ValueError, match=r"cost_points must be in \[1, 40\].*got 41"):
        subset_decoder(vae, 41)


@pytest.mark.parametrize("height_input", [False, True])
def test_decoded_cost_is_the_chamfer_distance_of_the_decoded_clouds(height_input):
    vae = _vae(height_input=height_input)
    cost = decoded_chamfer_cost(vae, 10)
    gen = torch.Generator().manual_seed(1)
    a, b = PRIOR.sample((3,), gen), PRIOR.sample((3,), gen)
    got = cost(a, b)
    assert got.shape == (3,)
    with torch.no_grad():
        pa = vae.decode(a[:, :2], a[:, 2:])[:, ::4]
        pb = vae.decode(b[:, :2], b[:, 2:])[:, ::4]
    for i in range(3):
        assert float(got[i]) == pytest.approx(_slow_chamfer(pa[i], pb[i]), rel=1e-4, abs=1e-7)
    assert float(cost(a[:1], a[:1])[0]) == pytest.approx(0.0, abs=1e-6)
    # broadcasting: (2, 3, E) against (3, E)
    assert cost(torch.stack([a, b]), b).shape == (2, 3)


@pytest.mark.parametrize("height_input", [False, True])
def test_decoded_cost_gradients_match_finite_differences(height_input):
    vae = _vae(torch.float64, height_input)
    cost = decoded_chamfer_cost(vae, 10)
    gen = torch.Generator().manual_seed(2)
    a = PRIOR.sample((2,), gen).double().requires_grad_(True)
    b = PRIOR.sample((2,), gen).double().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x, y: cost(x, y), (a, b), eps=1e-6, atol=1e-5)


def test_planning_with_the_decoded_cost():
    cfg = load("CutRearrange", "smoke", ["plan.cost=decoded", "plan.cost_points=16"])
    settings = PlanSettings.from_config(cfg)
    assert (settings.cost, settings.cost_points) == ("decoded", 16)
    bundle = untrained(cfg, "pasta", PRIOR)
    gen = torch.Generator().manual_seed(0)
    obs, goal = PRIOR.sample((1,), gen), PRIOR.sample((2,), gen)
    small = dataclasses.replace(settings, samples=6, iterations=4)
    result = plan(bundle, obs, goal, 3, small)
    # the plan's cost is the decoded Chamfer of its final set against the goal, not the cost network's
    functions = bundle_functions(bundle, cost="decoded", cost_points=16)
    with torch.no_grad():
        final = result.latent_sets[-1]
        pairs = functions.pair_cost(final.unsqueeze(1).expand(-1, 2, -1), goal.unsqueeze(0).expand(2, -1, -1))
    assert result.cost == pytest.approx(min(float(pairs[0, 0] + pairs[1, 1]), float(pairs[0, 1] + pairs[1, 0])),
                                        rel=1e-5)
    assert result.cost >= 0
    with pytest.raises(ValueError, match="cost must be one of.*'exact'"):
        dataclasses.replace(settings, cost="exact")


@pytest.mark.gpu
def test_decoded_cost_plans_the_same_on_cuda():
    cfg = load("CutRearrange", "smoke", ["plan.cost=decoded", "plan.cost_points=16"])
    bundle = untrained(cfg, "pasta", PRIOR)
    gen = torch.Generator().manual_seed(0)
    obs, goal = PRIOR.sample((1,), gen), PRIOR.sample((2,), gen)
    settings = dataclasses.replace(PlanSettings.from_config(cfg), samples=32, iterations=10)
    on_cpu = plan(bundle, obs, goal, 3, settings)
    on_gpu = plan(bundle, obs, goal, 3, settings, device="cuda")
    assert on_gpu.skills == on_cpu.skills
    assert on_gpu.score == pytest.approx(on_cpu.score, abs=1e-3)


def test_decoded_cost_keeps_planned_latents_where_a_regression_is_exploited():
    """A cost regression fitted on ``|z| <= 2`` may extrapolate below its target beyond that range; the
    planner then lands there, where the cost is (clamped) 0. The decoded cost has no such region."""
    vae = _vae()
    decoded = decoded_chamfer_cost(vae, 40)
    fitted_radius = 2.0

    def regression_like(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """Exact inside ``|z_a| <= 2``, falling linearly outside it."""
        return decoded(a, b) - 0.1 * (a[..., :2].norm(dim=-1) - fitted_radius).clamp_min(0.0)

    skills = (SkillSpec("shape", 1, 1),)
    prior = LatentPrior(2, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))

    def feasible(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        return torch.ones(inputs.shape[0])

    obs = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.0]])
    goal = torch.tensor([[0.5, -0.5, 0.0, 0.0, 0.0]])
    settings = PlanSettings(lr=0.05, iterations=100, samples=64, alpha=1000.0, seed=0, halving=())
    planned = {}
    for name, cost in (("regression", regression_like), ("decoded", decoded)):
        result = plan_with(PlanningFunctions(skills, prior, feasible, cost), obs, goal, 1, settings)
        planned[name] = result.latent_sets[-1][0, :2]
    assert planned["regression"].norm() > fitted_radius + 0.5
    assert planned["decoded"].norm() < fitted_radius
    assert (planned["decoded"] - goal[0, :2]).norm() < 0.2
