"""The reach guard: distances against a double loop, the reach of transitions, the guarded feasibility, a
planner it keeps from a transition no demonstration spans, and the bundle that carries the reach."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.plan import PlanningFunctions, PlanSettings, SkillSpec, bundle_functions, plan_with
from pasta.plan.reach import output_displacements, planar_skills, reach_penalty, skill_reach, skill_vertical_range
from pasta.train.bundle import load_trained, save_trained, untrained
from tests.models.synthetic import tiny_model_config

PRIOR = LatentPrior(2, (0.0, 0.0, 0.0), (1.0, 0.2, 1.0))


def test_output_displacements_are_from_the_nearest_input_centre():
    gen = torch.Generator().manual_seed(0)
    inputs, outputs = torch.rand(4, 3, 3, generator=gen), torch.rand(4, 2, 3, generator=gen)
    expected = torch.zeros(4, 2, 3)
    for b in range(4):
        for j in range(2):
            nearest = min(range(3), key=lambda i: float((outputs[b, j] - inputs[b, i]).norm()))
            expected[b, j] = (outputs[b, j] - inputs[b, nearest]).abs()
    torch.testing.assert_close(output_displacements(inputs, outputs), expected)


def test_skill_reach_is_the_largest_displacement_per_axis():
    split = (torch.tensor([[0.5, 0.1, 0.5]]), torch.tensor([[0.4, 0.1, 0.5], [0.6, 0.09, 0.52]]))
    moved = (torch.tensor([[0.5, 0.1, 0.5], [0.2, 0.1, 0.2]]), torch.tensor([[0.2, 0.1, 0.45]]))
    # moved: nearest input (0.2, 0.1, 0.2) at 0.25, not (0.5, 0.1, 0.5) at 0.30
    assert skill_reach([split, moved]) == pytest.approx((0.1, 0.01, 0.25))
    assert skill_reach([split]) == pytest.approx((0.1, 0.01, 0.02))
    assert all(math.isnan(r) for r in skill_reach([]))


def test_the_penalty_is_zero_within_the_reach_and_grows_beyond_it():
    penalty = reach_penalty([(0.1, 0.01, 0.02), (math.nan,) * 3], latent_dim=2, softness=0.05)
    inputs = torch.tensor([[[0.0, 0.0, 0.5, 0.1, 0.5]]]).expand(3, 1, 5)
    outputs = torch.tensor([[[1.0, 1.0, 0.55, 0.1, 0.5]], [[0.0, 0.0, 0.65, 0.1, 0.5]], [[0.0, 0.0, 0.5, 0.1, 0.62]]])
    # displacements 0.05 in x (within), 0.15 in x (0.05 beyond: 1) and 0.12 in z (0.1 beyond: 4); z plays no part
    torch.testing.assert_close(penalty(0, inputs, outputs), torch.tensor([0.0, 1.0, 4.0]))
    torch.testing.assert_close(penalty(1, inputs, outputs), torch.zeros(3))  # nan: unguarded
    with pytest.raises(ValueError, match="softness must be > 0, got 0"):
        reach_penalty([(0.1, 0.1, 0.1)], latent_dim=2, softness=0.0)


def test_a_planar_skill_is_limited_in_horizontal_distance_by_its_larger_horizontal_reach():
    """CRS's push at small reached x 0.385 and z 0.202 in its demonstrations; a test problem needs (-0.252, -0.308).
    Per axis that is 0.106 beyond z's reach; in the plane it is 0.398 against 0.385."""
    reach = [(0.385, 0.004, 0.202)]
    inputs = torch.tensor([[[0.0, 0.0, 0.5, 0.1, 0.5]]]).expand(3, 1, 5)
    outputs = torch.tensor([[[0.0, 0.0, 0.248, 0.1, 0.192]],  # the test problem's push
                            [[0.0, 0.0, 0.0, 0.1, 0.5]],  # 0.5 along x: beyond either way
                            [[0.0, 0.0, 0.5, 0.12, 0.5]]])  # 0.02 up: y keeps its own reach
    per_axis = reach_penalty(reach, latent_dim=2, softness=0.02)(0, inputs, outputs)
    planar = reach_penalty(reach, latent_dim=2, softness=0.02, planar=[True])(0, inputs, outputs)
    horizontal = math.hypot(0.252, 0.308)
    torch.testing.assert_close(per_axis, torch.tensor([(0.106 / 0.02) ** 2, (0.115 / 0.02) ** 2, 0.8 ** 2]),
                               rtol=1e-3, atol=1e-3)
    torch.testing.assert_close(planar, torch.tensor([((horizontal - 0.385) / 0.02) ** 2, (0.115 / 0.02) ** 2,
                                                     0.8 ** 2]), rtol=1e-3, atol=1e-3)
    with pytest.raises(ValueError, match="planar has 2 values for 1 skills"):
        reach_penalty(reach, latent_dim=2, softness=0.02, planar=[True, False])


def test_the_tools_that_move_along_x_and_z_make_their_skills_planar():
    assert planar_skills(load("CRS", "small")) == {"push", "spread"}  # the knife moves along x only
    assert planar_skills(load("CutRearrange", "small")) == {"rearrange"}
    assert PlanSettings.from_config(load("CRS", "small")).planar_skills == {"push", "spread"}
    assert PlanSettings.from_config(load("CRS", "small", ["plan.reach_frame=axes"])).planar_skills == frozenset()


def _exploitable_problem() -> tuple[PlanningFunctions, torch.Tensor, torch.Tensor]:
    """``split`` (1 -> 2) keeps the shape code and is scored 1 wherever it puts its pieces, as a network that saw
    only in-place splits may do; ``move`` (1 -> 1) carries one piece anywhere. The goal wants the two pieces
    0.3 from the dough, so split-then-nothing reaches it by teleporting, while a split in place must be followed
    by moves."""
    skills = (SkillSpec("split", 1, 2), SkillSpec("move", 1, 1))

    def feasibility(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        shape = ((outputs[..., :2] - inputs[:, :1, :2]) ** 2).sum(dim=(-1, -2))
        return torch.exp(-shape / 0.1)

    def pair_cost(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return ((a - b) ** 2).sum(-1)

    obs = torch.tensor([[0.0, 0.0, 0.5, 0.1, 0.5]])
    goal = torch.tensor([[0.0, 0.0, 0.2, 0.1, 0.5], [0.0, 0.0, 0.8, 0.1, 0.5]])
    return PlanningFunctions(skills, PRIOR, feasibility, pair_cost), obs, goal


def test_the_reach_guard_keeps_a_split_in_place_where_the_unguarded_planner_teleports():
    functions, obs, goal = _exploitable_problem()
    settings = PlanSettings(lr=0.05, iterations=120, samples=128, alpha=100.0, seed=0, halving=())
    sequences = [("split", "move", "move")]
    free = plan_with(functions, obs, goal, 3, settings, skill_sequences=sequences)
    reach = [(0.05, 0.05, 0.05), (1.0, 1.0, 1.0)]
    guarded = dataclasses.replace(functions, penalty=reach_penalty(reach, latent_dim=2, softness=0.01))
    kept = plan_with(guarded, obs, goal, 3, settings, skill_sequences=sequences)

    def split_distance(plan) -> float:
        return float(output_displacements(obs[None, :, 2:], plan.latent_sets[1][None, :2, 2:]).max())

    assert split_distance(free) > 0.15  # the unguarded split leaves its pieces where they started, far off
    assert split_distance(kept) < 0.07  # the guarded one splits in place (reach 0.05 per axis) ...
    assert kept.cost < 1e-3  # ... and the moves still reach the goal
    assert kept.penalties[0] < 1.0 and kept.score == pytest.approx(
        sum(math.log(max(f, settings.feasibility_floor)) for f in kept.feasibilities) - sum(kept.penalties)
        - settings.alpha * kept.cost, abs=1e-5)


def test_a_bundle_carries_its_reach_and_the_guard_needs_it(tmp_path):
    cfg = load("CutRearrange", "smoke")
    bundle = untrained(cfg, "pasta", PRIOR, model_config=tiny_model_config(), seed=0)
    with pytest.raises(ValueError, match="trained without; train it again .* or plan with plan.guard=none"):
        bundle_functions(bundle, guard="reach")
    with pytest.raises(ValueError, match="reach has 1 values for 2 skills"):
        dataclasses.replace(bundle, reach=((0.1, 0.1, 0.1),))
    with pytest.raises(ValueError, match=r"each skill's reach must be \(x, y, z\)"):
        dataclasses.replace(bundle, reach=((0.1,), (0.1,)))
    reached = dataclasses.replace(bundle, reach=((0.2, 0.01, 0.02), (math.nan,) * 3))
    loaded = load_trained(save_trained(tmp_path / "models.pt", reached))
    assert loaded.reach[0] == pytest.approx((0.2, 0.01, 0.02)) and math.isnan(loaded.reach[1][0])
    functions = bundle_functions(loaded, guard="reach", reach_softness=0.05)
    u = torch.zeros(1, 1, 5)
    far = torch.zeros(1, 2, 5)
    far[..., 2] = 0.3  # 0.3 along x from the input: 0.1 beyond the cut's reach, for each of the two outputs
    torch.testing.assert_close(functions.step_penalty(0, u, far), torch.tensor([8.0]))
    torch.testing.assert_close(functions.step_penalty(1, u, far[:, :1]), torch.tensor([0.0]))  # rearrange: nan
    assert bundle_functions(loaded).penalty is None
    with pytest.raises(ValueError, match="guard must be one of"):
        bundle_functions(loaded, guard="box")
    assert PlanSettings.from_config(load("CutRearrange", "smoke", ["plan.guard=reach"])).guard == "reach"


def test_the_vertical_range_is_the_lowest_and_highest_signed_drop():
    spread = (torch.tensor([[0.5, 0.10, 0.5]]), torch.tensor([[0.5, 0.08, 0.5]]))
    deeper = (torch.tensor([[0.5, 0.10, 0.5]]), torch.tensor([[0.52, 0.079, 0.5]]))
    assert skill_vertical_range([spread, deeper]) == pytest.approx((-0.021, -0.02))
    assert all(math.isnan(v) for v in skill_vertical_range([]))


def test_the_signed_guard_penalises_a_spread_that_does_not_lower_its_piece():
    """CRS's spreads lowered their pieces' centres by 0.0186-0.0215 at small; the planner put a spread that left
    the dough as it was first and made the flat piece elsewhere. Absolute, |d_y| = 0 is within the reach; signed,
    it is 0.0186 above the range."""
    reach, vertical = [(0.003, 0.0215, 0.002)], [(-0.0215, -0.0186)]
    inputs = torch.tensor([[[0.0, 0.0, 0.5, 0.10, 0.5]]]).expand(3, 1, 5)
    outputs = torch.tensor([[[0.0, 0.0, 0.5, 0.10, 0.5]],  # a spread that does nothing
                            [[0.0, 0.0, 0.5, 0.080, 0.5]],  # a spread as the demonstrations spread
                            [[0.0, 0.0, 0.5, 0.06, 0.5]]])  # one that goes 0.0185 deeper than any
    absolute = reach_penalty(reach, latent_dim=2, softness=0.01)(0, inputs, outputs)
    signed = reach_penalty(reach, latent_dim=2, softness=0.01, vertical=vertical)(0, inputs, outputs)
    torch.testing.assert_close(absolute, torch.tensor([0.0, 0.0, 1.85 ** 2]), rtol=1e-3, atol=1e-3)
    torch.testing.assert_close(signed, torch.tensor([1.86 ** 2, 0.0, 1.85 ** 2]), rtol=1e-3, atol=1e-3)
    with pytest.raises(ValueError, match="a \\(lowest, highest\\) pair for each of 1 skills"):
        reach_penalty(reach, latent_dim=2, softness=0.01, vertical=[(-0.01, -0.02)])


def test_a_bundle_carries_its_vertical_range_and_the_signed_guard_needs_it(tmp_path):
    cfg = load("CutRearrange", "smoke")
    bundle = dataclasses.replace(untrained(cfg, "pasta", PRIOR, model_config=tiny_model_config(), seed=0),
                                 reach=((0.2, 0.01, 0.02), (0.3, 0.01, 0.3)))
    with pytest.raises(ValueError, match="vertical range, which this CutRearrange bundle was trained without"):
        bundle_functions(bundle, guard="reach", reach_vertical="signed")
    ranged = dataclasses.replace(bundle, vertical_range=((-0.008, -0.001), (-0.002, 0.004)))
    loaded = load_trained(save_trained(tmp_path / "models.pt", ranged))
    assert [list(r) for r in loaded.vertical_range] == [pytest.approx([-0.008, -0.001]), pytest.approx([-0.002, 0.004])]
    functions = bundle_functions(loaded, guard="reach", reach_softness=0.01, reach_vertical="signed")
    u, same = torch.zeros(1, 1, 5), torch.zeros(1, 2, 5)
    torch.testing.assert_close(functions.step_penalty(0, u, same), torch.tensor([2 * 0.1 ** 2]))  # 0.001 above
    with pytest.raises(ValueError, match="reach_vertical must be one of"):
        bundle_functions(loaded, guard="reach", reach_vertical="up")
    assert PlanSettings.from_config(load("CRS", "smoke", ["plan.reach_vertical=signed"])).reach_vertical == "signed"
