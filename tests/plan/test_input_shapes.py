"""The input-shape guard: zero inside the training inputs' cloud, growing with the distance beyond it."""

import dataclasses

import pytest
import torch

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.plan import PlanSettings, bundle_functions
from pasta.plan.input_shapes import input_shape_penalty, leave_one_out_radius, skill_input_shapes, sum_penalties
from pasta.train.bundle import load_trained, save_trained, untrained
from tests.models.synthetic import tiny_model_config

PRIOR = LatentPrior(2, (0.0, 0.0, 0.0), (1.0, 0.2, 1.0))


def test_leave_one_out_radius_is_the_largest_nearest_neighbour_distance():
    shapes = torch.tensor([[0.0, 0.0], [0.1, 0.0], [0.5, 0.0]])
    assert leave_one_out_radius(shapes) == pytest.approx(0.4)
    assert leave_one_out_radius(shapes[:1]) == 0.0


def test_skill_input_shapes_keeps_the_shape_part_of_every_input_entity():
    inputs = [torch.arange(10.0).reshape(2, 5), torch.empty(0, 5), torch.ones(1, 5)]
    shapes = skill_input_shapes(inputs, latent_dim=2)
    assert torch.equal(shapes, torch.tensor([[0.0, 1.0], [5.0, 6.0], [1.0, 1.0]]))


def test_penalty_is_zero_within_the_radius_and_quadratic_beyond_it():
    training = torch.tensor([[0.0, 0.0], [0.2, 0.0]])  # radius 0.2
    penalty = input_shape_penalty([training, None], latent_dim=2, softness=0.1)
    centre = torch.tensor([0.5, 0.5, 0.5])

    def entity(z0: float) -> torch.Tensor:
        return torch.cat([torch.tensor([z0, 0.0]), centre])

    inputs = torch.stack([entity(0.1), entity(0.35), entity(-0.5)])[:, None, :]  # (3, 1, 5)
    outputs = torch.zeros(3, 1, 5)
    got = penalty(0, inputs, outputs)
    assert got[0] == 0.0  # 0.1 from the nearest training input, within the radius
    assert got[1] == pytest.approx(0.0, abs=1e-9)  # 0.15 from the nearest: still within
    assert got[2] == pytest.approx(((0.5 - 0.2) / 0.1) ** 2, rel=1e-5)
    assert torch.equal(penalty(1, inputs, outputs), torch.zeros(3))  # an unguarded skill


def test_penalty_sums_over_a_steps_inputs_and_keeps_a_gradient():
    training = torch.zeros(1, 2)  # one input: radius 0
    penalty = input_shape_penalty([training], latent_dim=2, softness=1.0)
    inputs = torch.tensor([[[3.0, 4.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0]]], requires_grad=True)
    value = penalty(0, inputs, torch.zeros(1, 1, 5))
    assert value.item() == pytest.approx(25.0 + 1.0)
    value.sum().backward()
    assert torch.allclose(inputs.grad[0, 0, :2], torch.tensor([6.0, 8.0]))
    assert torch.all(inputs.grad[..., 2:] == 0)


def test_bad_shapes_and_softness_are_refused():
    with pytest.raises(ValueError, match="softness"):
        input_shape_penalty([torch.zeros(1, 2)], latent_dim=2, softness=0.0)
    with pytest.raises(ValueError, match=r"\(M, 2\)"):
        input_shape_penalty([torch.zeros(3, 4)], latent_dim=2, softness=0.1)


def test_sum_penalties_adds_and_skips_none():
    def one(skill, inputs, outputs):
        return torch.ones(inputs.shape[0])

    assert sum_penalties([None, None]) is None
    assert sum_penalties([one, None]) is one
    both = sum_penalties([one, one])
    assert torch.equal(both(0, torch.zeros(2, 1, 5), torch.zeros(2, 1, 5)), torch.full((2,), 2.0))


def test_a_bundle_carries_its_input_shapes_and_the_guard_needs_them(tmp_path):
    bundle = untrained(load("CutRearrange", "smoke"), "pasta", PRIOR, model_config=tiny_model_config(), seed=0)
    with pytest.raises(ValueError, match="training input shapes, which this .* plan.input_shape_guard=false"):
        bundle_functions(bundle, input_shape_guard=True)
    with pytest.raises(ValueError, match="input_shapes must hold"):
        dataclasses.replace(bundle, input_shapes=(((0.0, 0.0),),))
    shaped = dataclasses.replace(bundle, input_shapes=(((0.0, 0.0), (0.1, 0.0)), ()))
    loaded = load_trained(save_trained(tmp_path / "models.pt", shaped))
    assert loaded.input_shapes == shaped.input_shapes
    functions = bundle_functions(loaded, input_shape_guard=True, input_shape_softness=0.1)
    flat = torch.tensor([[[0.4, 0.0, 0.5, 0.1, 0.5]]])  # 0.3 from the nearest cut input, 0.2 beyond the radius
    torch.testing.assert_close(functions.step_penalty(0, flat, torch.zeros(1, 2, 5)), torch.tensor([4.0]))
    torch.testing.assert_close(functions.step_penalty(1, flat, torch.zeros(1, 1, 5)), torch.tensor([0.0]))
    both = bundle_functions(dataclasses.replace(loaded, reach=((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))), guard="reach",
                            reach_softness=0.1, input_shape_guard=True, input_shape_softness=0.1)
    moved = flat.expand(1, 2, 5).clone()
    moved[..., 2] += 0.1  # each output 0.1 along x from the input: 1 per output from the reach guard
    torch.testing.assert_close(both.step_penalty(0, flat, moved), torch.tensor([4.0 + 2.0]))
    settings = PlanSettings.from_config(load("CRS", "smoke", ["plan.input_shape_guard=true"]))
    assert settings.input_shape_guard and settings.input_shape_softness == 0.05
