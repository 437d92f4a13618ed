"""Set policy: input tagging, shapes, noise, entity filtering, behaviour-cloning on a synthetic task."""

from __future__ import annotations

import pytest
import torch

from pasta.geometry.entities import PIECE_GAP
from pasta.models import PolicyConfig, SetPolicy, filter_entities, uniform_point_noise
from pasta.models.policy import (
    CENTRE_OFFSET_SCALE,
    GAP_SCALE,
    cloud_gaps,
    cloud_quantiles,
    dough_frame,
    goal_heading,
    tag_point_roles,
    turn_actions,
    turn_clouds,
)
from tests.models.synthetic import box_clouds, goal_offset_problem, tiny_encoder, train


def test_tag_point_roles():
    a, b, c = torch.zeros(2, 4, 3), torch.ones(2, 1, 3), torch.full((2, 3, 3), 2.0)
    points, roles = tag_point_roles(a, b, c)
    assert points.shape == (2, 8, 3) and roles.shape == (2, 8, 3)
    assert roles[0].argmax(-1).tolist() == [0, 0, 0, 0, 1, 2, 2, 2]
    assert torch.equal(roles.sum(-1), torch.ones(2, 8))
    with pytest.raises(ValueError):
        tag_point_roles(a, torch.zeros(3, 1, 3))


def test_default_policy_shapes():
    torch.manual_seed(0)
    policy = SetPolicy(10)
    assert [(m.in_features, m.out_features) for m in policy.head[::2]] == [(1024, 512), (512, 256), (256, 10)]
    gen = torch.Generator().manual_seed(0)
    obs, tool, goal = box_clouds(2, 64, gen), box_clouds(2, 16, gen), box_clouds(2, 64, gen)
    assert policy(obs, tool, goal).shape == (2, 10)


def test_uniform_point_noise_is_bounded_and_seeded():
    points = torch.zeros(1000, 3)
    noisy = uniform_point_noise(points, 0.005, torch.Generator().manual_seed(1))
    assert float(noisy.abs().max()) <= 0.005 and float(noisy.abs().max()) > 0.004
    assert abs(float(noisy.mean())) < 3e-4
    assert torch.equal(noisy, uniform_point_noise(points, 0.005, torch.Generator().manual_seed(1)))


def test_filter_entities_removes_pairs_already_matched():
    gen = torch.Generator().manual_seed(2)
    a, b, c = box_clouds(3, 100, gen)
    obs = torch.stack([a, b])
    goal = torch.stack([c, a + 0.001, b + 0.3])  # a is (almost) at its goal
    out = filter_entities(obs, goal, 5e-4)
    assert out.obs_keep.tolist() == [False, True] and out.goal_keep.tolist() == [True, False, True]
    assert torch.equal(out.obs, obs[1:]) and torch.equal(out.goal, goal[[0, 2]])
    none = filter_entities(obs, goal, 0.0)
    assert bool(none.obs_keep.all()) and bool(none.goal_keep.all())


def test_behaviour_cloning_on_goal_offset():
    torch.manual_seed(0)
    policy = SetPolicy(3, PolicyConfig(encoder=tiny_encoder(3), head_channels=(32,)))
    noisy, action = goal_offset_problem(torch.Generator().manual_seed(3))

    def loss():
        return (policy(*noisy) - action).square().sum(-1).mean()

    first, last = train(loss, policy.parameters(), steps=40, lr=1e-2)
    assert last < 0.6 * first  # the initial loss is about that of predicting the mean action


@pytest.mark.parametrize("encoder", ["pointnet2", "pointnet"])
def test_bf16_autocast_changes_the_default_policys_actions_by_under_two_percent(encoder):
    """Mixed precision (``train.precision: bf16``) computes the same function: measured 0.5-0.6 % apart."""
    torch.manual_seed(0)
    policy = SetPolicy(10, PolicyConfig(point_encoder=encoder))
    gen = torch.Generator().manual_seed(0)
    clouds = [0.4 + 0.2 * torch.rand(4, n, 3, generator=gen) for n in (300, 50, 300)]
    with torch.no_grad():
        exact = policy(*clouds)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            mixed = policy(*clouds)
    assert mixed.dtype == torch.bfloat16
    gap = float((mixed.float() - exact).norm() / exact.norm())
    assert 0 < gap < 0.02, gap


def test_dough_frame_centres_the_observation_horizontally_and_returns_the_offsets():
    gen = torch.Generator().manual_seed(4)
    obs, tool, goal = box_clouds(2, 40, gen), box_clouds(2, 8, gen), box_clouds(2, 40, gen) + 0.2
    (obs_c, tool_c, goal_c), offsets = dough_frame(obs, tool, goal)
    centre = obs.mean(dim=1)
    assert torch.allclose(obs_c.mean(dim=1)[:, [0, 2]], torch.zeros(2, 2), atol=1e-6)
    assert torch.allclose(obs_c[..., 1], obs[..., 1])  # heights stay absolute
    assert torch.allclose(goal_c - goal, obs_c - obs) and torch.allclose(tool_c[..., 1], tool[..., 1])
    expected = torch.cat([tool.mean(1) - centre, goal.mean(1) - centre], dim=-1) * CENTRE_OFFSET_SCALE
    assert offsets.shape == (2, 6) and torch.allclose(offsets, expected, atol=1e-6)


@pytest.mark.parametrize("encoder", ["pointnet2", "pointnet"])
def test_a_dough_frame_policy_ignores_where_the_scene_is_on_the_floor(encoder):
    """``policy.frame: dough``: moving the whole scene horizontally leaves the action; lifting it does not.
    The world-frame policy (same weights but the head's extra inputs) sees the move."""
    gen = torch.Generator().manual_seed(5)
    clouds = [0.4 + 0.2 * torch.rand(2, n, 3, generator=gen) for n in (64, 16, 64)]
    moved = [c + torch.tensor([0.15, 0.0, -0.1]) for c in clouds]
    lifted = [c + torch.tensor([0.0, 0.05, 0.0]) for c in clouds]
    results = {}
    for frame in ("dough", "world"):
        torch.manual_seed(0)
        policy = SetPolicy(4, PolicyConfig(point_encoder=encoder, frame=frame)).eval()
        with torch.no_grad():
            results[frame] = [policy(*c) for c in (clouds, moved, lifted)]
    def gap(a, b):
        return float((a - b).norm() / a.norm())

    here, there, up = results["dough"]
    assert gap(here, there) < 1e-5
    assert gap(here, up) > 1e-3
    assert gap(results["world"][0], results["world"][1]) > 1e-3


def _turned_about_y(cloud: torch.Tensor, angle: float, pivot: torch.Tensor) -> torch.Tensor:
    """A slow reference: rotation matrix about the vertical axis through ``pivot`` (x towards z by ``angle``)."""
    c, s = torch.cos(torch.tensor(angle)), torch.sin(torch.tensor(angle))
    rotation = torch.tensor([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    return (cloud - pivot) @ rotation.T + pivot


def test_turn_clouds_puts_the_heading_on_plus_x_and_turn_actions_undoes_it():
    gen = torch.Generator().manual_seed(11)
    obs = box_clouds(3, 32, gen)
    goal = box_clouds(3, 32, gen)
    heading = goal_heading(obs, goal)
    assert torch.allclose(heading.norm(dim=1), torch.ones(3), atol=1e-6)
    obs_t, goal_t = turn_clouds(heading, obs.mean(dim=1), obs, goal)
    offset = goal_t.mean(dim=1) - obs_t.mean(dim=1)
    assert torch.allclose(offset[:, 2], torch.zeros(3), atol=1e-6) and bool((offset[:, 0] > 0).all())
    assert torch.allclose(obs_t[..., 1], obs[..., 1])  # heights kept
    # Distances within a cloud are kept (a rotation), and turn_actions maps the turned offset back to the world's.
    def distances(cloud):
        return (cloud[:, :, None] - cloud[:, None]).norm(dim=-1)

    assert torch.allclose(distances(obs_t), distances(obs), atol=1e-6)
    actions = torch.zeros(3, 2 * 4)  # two steps of a 4-value action whose (x, z) pair is (1, 3)
    actions[:, [1, 5]] = offset[:, [0]]
    back = turn_actions(actions, heading, (1, 3), 4)
    world = goal.mean(dim=1) - obs.mean(dim=1)
    for step in (0, 4):
        assert torch.allclose(back[:, [step + 1, step + 3]], world[:, [0, 2]], atol=1e-6)
    assert torch.equal(back[:, [0, 2, 4, 6]], actions[:, [0, 2, 4, 6]])
    assert torch.equal(goal_heading(obs, obs.clone()), torch.tensor([[1.0, 0.0]]).expand(3, 2))


@pytest.mark.parametrize("encoder", ["pointnet2", "pointnet"])
def test_a_heading_policy_turns_its_push_with_the_scene(encoder):
    """``policy.heading_skills``: turning the whole scene about a vertical axis turns the predicted horizontal
    vectors (the named pairs) with it and leaves the other action values; a policy without heading pairs (same
    weights) does not follow the turn."""
    gen = torch.Generator().manual_seed(12)
    obs, tool = box_clouds(2, 64, gen), box_clouds(2, 16, gen)
    goal = obs + torch.tensor([0.15, 0.0, 0.05])
    pivot = torch.tensor([0.5, 0.0, 0.45])
    angle = 1.1
    turned = [_turned_about_y(c, angle, pivot) for c in (obs, tool, goal)]
    config = PolicyConfig(point_encoder=encoder, encoder=tiny_encoder(3), frame="dough", chunk=2, shape_quantiles=3)
    results = {}
    for pairs in ((0, 2, 3, 5), ()):
        torch.manual_seed(0)
        policy = SetPolicy(6, config, heading_pairs=pairs).eval()
        with torch.no_grad():
            results[pairs] = (policy(obs, tool, goal).reshape(2, 2, 6), policy(*turned).reshape(2, 2, 6))
    here, there = results[(0, 2, 3, 5)]
    c, s = torch.cos(torch.tensor(angle)), torch.sin(torch.tensor(angle))
    for ix, iz in ((0, 2), (3, 5)):
        expected_x = c * here[..., ix] - s * here[..., iz]
        expected_z = s * here[..., ix] + c * here[..., iz]
        assert torch.allclose(there[..., ix], expected_x, atol=2e-4)
        assert torch.allclose(there[..., iz], expected_z, atol=2e-4)
    assert float((there[..., [1, 4]] - here[..., [1, 4]]).abs().max()) < 2e-4
    plain_here, plain_there = results[()]
    assert not torch.allclose(plain_there[..., 0], c * plain_here[..., 0] - s * plain_here[..., 2], atol=2e-3)


def test_heading_pairs_must_be_pairs_within_the_action():
    with pytest.raises(ValueError, match="heading pairs"):
        SetPolicy(6, PolicyConfig(point_encoder="pointnet"), heading_pairs=(0, 2, 3))
    with pytest.raises(ValueError, match="heading pairs"):
        SetPolicy(6, PolicyConfig(point_encoder="pointnet"), heading_pairs=(0, 7))


def test_a_phase_policy_reads_the_phase_and_refuses_to_go_without_it():
    torch.manual_seed(0)
    policy = SetPolicy(4, PolicyConfig(point_encoder="pointnet", phase_input=True)).eval()
    assert policy.head[0].in_features == policy.encoder.out_dim + 1
    gen = torch.Generator().manual_seed(6)
    clouds = [0.4 + 0.2 * torch.rand(2, n, 3, generator=gen) for n in (64, 16, 64)]
    with torch.no_grad():
        early, late = policy(*clouds, torch.zeros(2)), policy(*clouds, torch.full((2,), 0.9))
    assert not torch.allclose(early, late, atol=1e-4)
    with pytest.raises(ValueError, match="phase"):
        policy(*clouds)
    with pytest.raises(ValueError, match="frame"):
        PolicyConfig(frame="tool")


def test_a_previous_action_policy_reads_it_and_refuses_to_go_without_it():
    torch.manual_seed(0)
    policy = SetPolicy(6, PolicyConfig(point_encoder="pointnet", previous_action_input=True)).eval()
    assert policy.head[0].in_features == policy.encoder.out_dim + 6
    gen = torch.Generator().manual_seed(7)
    clouds = [0.4 + 0.2 * torch.rand(2, n, 3, generator=gen) for n in (64, 16, 64)]
    with torch.no_grad():
        still, moving = policy(*clouds, None, torch.zeros(2, 6)), policy(*clouds, None, torch.full((2, 6), 0.8))
    assert not torch.allclose(still, moving, atol=1e-4)
    for wrong in (None, torch.zeros(2, 5)):
        with pytest.raises(ValueError, match="previous action"):
            policy(*clouds, None, wrong)


@pytest.mark.parametrize("encoder", ["pointnet2", "pointnet"])
def test_a_heading_policy_turns_the_previous_action_into_its_frame(encoder):
    """With ``heading_pairs`` the previous action is given in the world frame: turning the scene and the previous
    action's horizontal vectors together turns the predicted vectors with them (the equivariance of
    ``test_a_heading_policy_turns_its_push_with_the_scene``); turning the scene alone does not."""
    gen = torch.Generator().manual_seed(13)
    obs, tool = box_clouds(2, 64, gen), box_clouds(2, 16, gen)
    goal = obs + torch.tensor([0.1, 0.0, -0.12])
    previous = torch.tensor([[0.6, 0.1, -0.3, 0.2, 0.5, -0.4], [-0.2, 0.0, 0.7, 0.1, -0.6, 0.3]])
    pivot, angle = torch.tensor([0.45, 0.0, 0.5]), -0.8
    c, s = torch.cos(torch.tensor(angle)), torch.sin(torch.tensor(angle))

    def turned_vectors(values: torch.Tensor) -> torch.Tensor:
        out = values.clone()
        for ix, iz in ((0, 2), (3, 5)):
            out[..., ix] = c * values[..., ix] - s * values[..., iz]
            out[..., iz] = s * values[..., ix] + c * values[..., iz]
        return out

    turned = [_turned_about_y(cloud, angle, pivot) for cloud in (obs, tool, goal)]
    config = PolicyConfig(point_encoder=encoder, encoder=tiny_encoder(3), frame="dough", chunk=2,
                          previous_action_input=True)
    torch.manual_seed(0)
    policy = SetPolicy(6, config, heading_pairs=(0, 2, 3, 5)).eval()
    # a head that leans on the previous action, so that a wrong turn of it shows
    with torch.no_grad():
        policy.head[0].weight[:, -6:] *= 20.0
        here = policy(obs, tool, goal, None, previous).reshape(2, 2, 6)
        there = policy(*turned, None, turned_vectors(previous)).reshape(2, 2, 6)
        unturned = policy(*turned, None, previous).reshape(2, 2, 6)
    assert torch.allclose(there, turned_vectors(here), atol=3e-4)
    assert not torch.allclose(unturned, turned_vectors(here), atol=3e-3)


def test_cloud_quantiles_match_sorted_coordinates():
    gen = torch.Generator().manual_seed(3)
    cloud = torch.rand(2, 101, 3, generator=gen)
    got = cloud_quantiles(cloud, 5).view(2, 3, 5) / CENTRE_OFFSET_SCALE
    ordered = cloud.sort(dim=1).values  # (2, 101, 3): with 101 points, level q sits exactly at index 100 q
    for b in range(2):
        for axis in range(3):
            expected = ordered[b, [0, 25, 50, 75, 100], axis]
            assert torch.allclose(got[b, axis], expected, atol=1e-6)
    with pytest.raises(ValueError, match="got 1"):
        cloud_quantiles(cloud, 1)


def test_a_quantile_policy_sees_where_the_goal_splits():
    """Two goals with the same centre and pooled extent but the gap at different x: the quantile features
    differ, so a quantile policy can act on where the cut is."""
    torch.manual_seed(0)
    policy = SetPolicy(4, PolicyConfig(point_encoder="pointnet", frame="dough", shape_quantiles=9)).eval()
    assert policy.head[0].in_features == policy.encoder.out_dim + 6 + 6 * 9
    gen = torch.Generator().manual_seed(4)
    obs, tool = torch.rand(1, 64, 3, generator=gen), torch.rand(1, 16, 3, generator=gen)
    unit = torch.rand(1, 64, 3, generator=gen)

    def goal(split: float) -> torch.Tensor:
        left = unit[:, :32] * torch.tensor([split - 0.05, 1.0, 1.0])
        right = unit[:, 32:] * torch.tensor([0.95 - split, 1.0, 1.0]) + torch.tensor([split + 0.05, 0.0, 0.0])
        return torch.cat([left, right], dim=1)

    features = [cloud_quantiles(goal(s), 9) for s in (0.3, 0.6)]
    assert (features[0] - features[1]).abs().max() > 0.5
    with torch.no_grad():
        assert not torch.allclose(policy(obs, tool, goal(0.3)), policy(obs, tool, goal(0.6)), atol=1e-5)
    with pytest.raises(ValueError, match="shape_quantiles"):
        PolicyConfig(shape_quantiles=1)


def _slow_cloud_gaps(cloud: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """``cloud_gaps`` by hand: per batch and axis, a loop over the sorted coordinates."""
    rows = []
    for points, centre in zip(cloud.tolist(), origin.tolist(), strict=True):
        row = []
        for axis in range(3):
            values = sorted(p[axis] for p in points)
            widest, lower, upper = -1.0, 0.0, 0.0
            for a, b in zip(values[:-1], values[1:], strict=True):
                if b - a > widest:
                    widest, lower, upper = b - a, a, b
            if widest < PIECE_GAP:
                lower = upper = values[(len(values) - 1) // 2]
            row += [(lower - centre[axis]) * GAP_SCALE, (upper - centre[axis]) * GAP_SCALE, float(widest >= PIECE_GAP)]
        rows.append(row)
    return torch.tensor(rows)


def test_cloud_gaps_match_a_slow_reference_and_find_a_cuts_faces():
    gen = torch.Generator().manual_seed(2)
    piece = torch.rand(3, 200, 3, generator=gen) * torch.tensor([0.3, 0.04, 0.06])
    cut = piece.clone()
    cut[..., 0] += 0.11 * (piece[..., 0] > 0.1)  # the part beyond x = 0.1 slid 0.11 along x
    tool = torch.rand(3, 3, generator=gen)
    for cloud in (piece, cut):
        assert torch.allclose(cloud_gaps(cloud, tool), _slow_cloud_gaps(cloud, tool), atol=1e-5)
    assert cloud_gaps(piece, tool)[:, [2, 5, 8]].sum() == 0  # a whole piece has no gap on any axis
    features = cloud_gaps(cut, tool)
    assert features[:, 2].tolist() == [1.0, 1.0, 1.0] and features[:, [5, 8]].sum() == 0
    faces = torch.stack([piece[..., 0].masked_fill(piece[..., 0] > 0.1, -1).amax(1),
                         piece[..., 0].masked_fill(piece[..., 0] <= 0.1, 9).amin(1) + 0.11], dim=1)
    assert torch.allclose(features[:, :2], (faces - tool[:, :1]) * GAP_SCALE, atol=1e-5)
    with pytest.raises(ValueError, match=r"\(B, N >= 2, 3\)"):
        cloud_gaps(piece[:, :1], tool)
    with pytest.raises(ValueError, match="origin"):
        cloud_gaps(piece, tool[:2])


def test_a_gap_policy_reads_the_goals_gap():
    """The head reads the pooled features, the dough-frame offsets and the gaps of the observation and goal
    relative to the tool's centre, in that order: the output is that head applied by hand."""
    policy = SetPolicy(4, PolicyConfig(point_encoder="pointnet", frame="dough", gap_features=True)).eval()
    assert policy.head[0].in_features == policy.encoder.out_dim + 6 + 18
    gen = torch.Generator().manual_seed(5)
    obs, tool = torch.rand(1, 64, 3, generator=gen), torch.rand(1, 16, 3, generator=gen)
    piece = torch.rand(1, 64, 3, generator=gen)
    goals = [piece + 0.2 * (piece[..., :1] > split) * torch.tensor([1.0, 0.0, 0.0]) for split in (0.3, 0.6)]
    with torch.no_grad():
        for goal in goals:
            clouds, offsets = dough_frame(obs, tool, goal)
            centre = clouds[1].mean(dim=1)
            inputs = torch.cat([policy.encoder(*clouds), offsets, cloud_gaps(clouds[0], centre),
                                cloud_gaps(clouds[2], centre)], dim=-1)
            expected = policy.head(inputs) * policy.config.output_scale
            assert torch.allclose(policy(obs, tool, goal), expected, atol=1e-6)
        assert not torch.allclose(policy(obs, tool, goals[0]), policy(obs, tool, goals[1]), atol=1e-5)
