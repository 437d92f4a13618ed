"""Datasets from a tiny synthetic dataset written with write_trajectory (no simulator)."""

import numpy as np
import pytest
import torch

from pasta.data.storage import DatasetError
from pasta.geometry.distances import chamfer_distance
from pasta.train.datasets import DecodedGoals, TransitionSampler, pad_sets, split_trajectories, vae_clouds
from pasta.train.demos import load_demonstrations
from pasta.train.entities import PairChamfer, state_cloud
from tests.train.conftest import ENTITY_POINTS
from tests.train.synthetic_demos import POINTS, STEPS


def test_demonstrations_hold_states_targets_and_skill_tools(training_data):
    demos = training_data.demos
    assert len(demos) == 10 and demos.skills[:2] == ("cut", "rearrange")
    assert demos.points.shape == (10 * (STEPS + 1), POINTS, 3)
    assert demos.target_state.tolist() == [i * (STEPS + 1) + STEPS for i in range(10)]
    assert demos.tool_points[0].shape == (STEPS, 20, 3) and demos.tool_states[0].shape == (STEPS, 8)
    # the cut tool is the knife (first 20 tool points), the rearrange tool the gripper (last 20, 0.1 higher)
    assert demos.tool_points[1][:, :, 1].mean() > demos.tool_points[0][:, :, 1].mean() + 0.05
    assert [len(np.unique(demos.labels[s])) for s in demos.target_state] == [2] * 10  # DBSCAN on targets


def test_entity_tables_split_states_or_keep_whole_scenes(training_data, scene_data):
    table = training_data.table
    assert table.clouds.shape[1:] == (ENTITY_POINTS, 3)
    assert [len(table.state_entities[s]) for s in range(3)] == [1, 1, 2]  # the cut splits at step 2
    assert all(len(ids) == 1 for ids in scene_data.table.state_entities)
    assert len(scene_data.table) == len(training_data.demos.points)


def test_splits_are_by_trajectory_and_seeded(training_data):
    demos = training_data.demos
    train, test = split_trajectories(demos, 0.2, seed=42)
    assert sorted(np.concatenate([train, test]).tolist()) == list(range(10)) and len(test) == 2
    assert np.array_equal(split_trajectories(demos, 0.2, seed=42)[1], test)
    clouds = vae_clouds(demos, training_data.table, test)
    assert len(clouds) == sum(len(training_data.table.of_states(np.arange(demos.first_state[i],
                                                                          demos.target_state[i] + 1)))
                              for i in test)


def test_feasibility_positives_are_filtered_to_the_skill_shape(cfg, training_data):
    demos, table = training_data.demos, training_data.table
    chamfer = PairChamfer(table)
    sampler = TransitionSampler(demos, table, cfg.skills, np.arange(10), 5e-4, chamfer)
    rng = np.random.default_rng(0)
    assert sampler.count(0) == 5 * (STEPS - 1) and sampler.count(1) == 5 * (STEPS - 1)
    cut = sampler.feasibility_positives(0, sampler.transitions[0], rng)
    assert cut.obs and all(len(o) == 1 and len(g) == 2 for o, g in zip(cut.obs, cut.goal, strict=True))
    rearrange = sampler.feasibility_positives(1, sampler.transitions[1], rng)
    assert rearrange.obs and all(len(o) == 1 and len(g) == 1 for o, g in zip(rearrange.obs, rearrange.goal,
                                                                              strict=True))
    # the static slab is filtered out: the kept observation entity is always the moving one (label 0)
    assert set(table.label[np.concatenate(rearrange.obs)].tolist()) == {0}
    unfiltered = TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, chamfer)
    found = unfiltered.feasibility_positives(1, unfiltered.transitions[1], rng)
    assert all(len(o) == 2 and len(g) == 2 for o, g in zip(found.obs, found.goal, strict=True))


def test_policy_samples_and_cost_pairs(cfg, training_data):
    demos, table = training_data.demos, training_data.table
    chamfer = PairChamfer(table)
    sampler = TransitionSampler(demos, table, cfg.skills, np.arange(10), 5e-4, chamfer)
    rng = np.random.default_rng(1)
    samples = sampler.policy_samples(1, sampler.transitions[1], rng, limit=4)
    assert samples is not None and len(samples) == 4
    assert samples.obs_points.shape == (4, POINTS, 3) and samples.tool_points.shape == (4, 20, 3)
    assert samples.actions.shape == (4, 10) and torch.all(samples.actions[:, :3] == 0)
    for phase, action in zip(samples.phases.tolist(), samples.actions, strict=True):  # phase = t / actions
        assert 0.0 <= phase < 1.0
        assert any(np.array_equal(demos.actions[i][round(phase * len(demos.actions[i]))], action.numpy())
                   for i in range(10) if demos.skill_index[i] == 1)
    pairs = sampler.cost_pairs(sampler.transitions[0][:6], rng)
    assert len(pairs.a) == 12
    sub = table.clouds[:, :200]
    direct = chamfer_distance(sub[torch.from_numpy(pairs.a)], sub[torch.from_numpy(pairs.b)])
    assert torch.allclose(pairs.chamfer, direct.float())
    latents = torch.randn(len(table), 5)
    u, mask = pad_sets([np.array([0]), np.array([1, 2])], latents)
    assert u.shape == (2, 2, 5) and mask.tolist() == [[True, False], [True, True]]
    cloud = state_cloud(demos, table, table.state_entities[3], 50, np.random.default_rng(0))
    assert cloud.shape == (50, 3)


def test_missing_or_foreign_dataset_is_refused(cfg, tmp_path):
    with pytest.raises(DatasetError, match="index"):
        load_demonstrations(tmp_path, cfg)


def test_policy_samples_carry_the_next_actions_zero_after_the_trajectory_ends_and_the_previous_one(cfg, training_data):
    demos, table = training_data.demos, training_data.table
    sampler = TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table), chunk=3)
    trajectory = int(np.flatnonzero(demos.skill_index[:10] == 1)[0])
    last = len(demos.actions[trajectory]) - 1
    rows = np.array([[trajectory, 0], [trajectory, last - 1], [trajectory, last]])
    samples = sampler.policy_samples(1, rows, np.random.default_rng(0), limit=3)
    assert samples is not None and len(samples) == 3
    chunks = samples.action_chunks.numpy().reshape(3, 3, -1)
    actions = demos.actions[trajectory]
    np.testing.assert_array_equal(chunks[0], actions[:3])
    np.testing.assert_array_equal(chunks[1], np.concatenate([actions[last - 1 :], np.zeros((1, actions.shape[1]))]))
    np.testing.assert_array_equal(chunks[2, 0], actions[last])
    assert not chunks[2, 1:].any()
    np.testing.assert_array_equal(chunks[:, 0], samples.actions.numpy())
    previous = samples.previous_actions.numpy()
    assert previous.shape == (3, actions.shape[1]) and not previous[0].any()  # nothing before the first step
    np.testing.assert_array_equal(previous[1:], actions[[last - 2, last - 1]])
    with pytest.raises(ValueError, match="chunk"):
        TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table), chunk=0)


def test_policy_samples_have_the_configured_number_of_points_drawn_from_the_same_pieces(cfg, training_data):
    demos, table = training_data.demos, training_data.table
    chamfer = PairChamfer(table)
    full = TransitionSampler(demos, table, cfg.skills, np.arange(10), 5e-4, chamfer)
    half = TransitionSampler(demos, table, cfg.skills, np.arange(10), 5e-4, chamfer, cloud_points=POINTS // 2)
    rows = full.transitions[1][:8]
    a = full.policy_samples(1, rows, np.random.default_rng(3), limit=4)
    b = half.policy_samples(1, rows, np.random.default_rng(3), limit=4)
    assert a.obs_points.shape == (4, POINTS, 3) and b.obs_points.shape == (4, POINTS // 2, 3)
    assert b.goal_points.shape == (4, POINTS // 2, 3)
    assert [ids.tolist() for ids in a.obs_ids] == [ids.tolist() for ids in b.obs_ids]
    for dense, sparse in zip(a.obs_points.numpy(), b.obs_points.numpy(), strict=True):  # a subset of the same piece
        gaps = np.linalg.norm(sparse[:, None] - dense[None], axis=-1).min(axis=1)
        assert gaps.max() < 0.05


def test_the_hindsight_ratio_sets_how_many_policy_goals_are_later_states(cfg, training_data):
    """Ratio 0: every goal is the demonstration's target; ratio 1: every goal is a state of the trajectory
    between the sample's step and its end (for the cut, its first steps' goals are the uncut slab)."""
    demos, table = training_data.demos, training_data.table
    rows = np.array([[i, 0] for i in range(10) if demos.skill_index[i] == 0])
    targets = [table.state_entities[demos.target_state[i]].tolist() for i, _ in rows]
    goals = {}
    for ratio in (0.0, 1.0):
        sampler = TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table),
                                    hindsight_ratio=ratio)
        samples = sampler.policy_samples(0, np.repeat(rows, 8, axis=0), np.random.default_rng(1), limit=8 * len(rows))
        goals[ratio] = [ids.tolist() for ids in samples.goal_ids]
    assert goals[0.0] == [t for t in targets for _ in range(8)]
    assert sum(g == t for g, t in zip(goals[1.0], [t for t in targets for _ in range(8)], strict=True)) < len(rows) * 8
    with pytest.raises(ValueError, match="hindsight_ratio.*1.5"):
        TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table), hindsight_ratio=1.5)


def test_the_target_share_sets_how_many_feasibility_goals_are_the_demonstrations_targets(cfg, training_data):
    """Share 1: every positive's goal is its demonstration's target; share 0 (the official): a state of the
    trajectory, never the target (a demonstration ends short of it); a share outside [0, 1] is refused."""
    demos, table = training_data.demos, training_data.table
    rows = np.repeat(np.array([[i, t] for i in range(10) if demos.skill_index[i] == 0 for t in (0, 5)]), 4, axis=0)
    targets = [table.state_entities[demos.target_state[i]].tolist() for i, _ in rows]
    goals = {}
    for share in (0.0, 0.5, 1.0):
        sampler = TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table),
                                    target_share=share)
        found = sampler.feasibility_positives(0, rows, np.random.default_rng(3))
        assert len(found.goal) == len(rows)
        goals[share] = sum(g.tolist() == t for g, t in zip(found.goal, targets, strict=True))
    assert goals[0.0] == 0 and goals[1.0] == len(rows) and 0 < goals[0.5] < len(rows)
    with pytest.raises(ValueError, match="target_share.*1.5"):
        TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table), target_share=1.5)


def test_decoded_goal_clouds_weigh_every_entity_alike():
    """A decoded goal stacks as many points of each entity as the policy executor stacks a plan's subgoals."""
    clouds = np.zeros((3, 200, 3), np.float32)
    clouds[1] += 1.0
    clouds[2] += 2.0
    cloud = DecodedGoals(clouds, 1.0).cloud(np.array([0, 2]), 100, np.random.default_rng(0))
    assert cloud.shape == (100, 3)
    assert set(np.unique(cloud[:, 0]).tolist()) == {0.0, 2.0}
    assert 30 <= int((cloud[:, 0] == 0.0).sum()) <= 70
    with pytest.raises(ValueError, match="share.*1.5"):
        DecodedGoals(clouds, 1.5)


def test_the_decoded_goal_share_sets_how_many_policy_goals_come_from_the_decoder(cfg, training_data):
    """Share 1: every goal cloud is drawn from the decoded entities (here the entities lifted by 10), the
    observations never; share 0: none; a table of another size is refused."""
    demos, table = training_data.demos, training_data.table
    lifted = table.clouds.numpy() + np.array([0.0, 10.0, 0.0], np.float32)
    rows = np.repeat(np.array([[i, 0] for i in range(10) if demos.skill_index[i] == 0]), 4, axis=0)
    lifted_goals = {}
    for share in (0.0, 0.5, 1.0):
        sampler = TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table),
                                    decoded_goals=DecodedGoals(lifted, share))
        samples = sampler.policy_samples(0, rows, np.random.default_rng(2), limit=len(rows))
        assert (samples.obs_points[..., 1] < 5).all()
        goal_heights = samples.goal_points[..., 1]
        assert ((goal_heights > 5).all(dim=1) | (goal_heights < 5).all(dim=1)).all()
        lifted_goals[share] = int((goal_heights > 5).all(dim=1).sum())
    assert lifted_goals[0.0] == 0 and lifted_goals[1.0] == len(rows) and 0 < lifted_goals[0.5] < len(rows)
    with pytest.raises(ValueError, match="decoded_goals holds 2 entity clouds"):
        TransitionSampler(demos, table, cfg.skills, np.arange(10), 0.0, PairChamfer(table),
                          decoded_goals=DecodedGoals(lifted[:2], 1.0))


def test_the_heads_split_holds_out_a_trajectory_of_every_skill(training_data):
    """A split that left a skill without a held-out trajectory gets one of that skill's moved over (seeded); a
    split that held out every skill stays as it is."""
    demos = training_data.demos
    branches = set()
    for seed, fraction in [(seed, fraction) for seed in range(10) for fraction in (0.1, 0.3)]:
        train, test = split_trajectories(demos, fraction, seed=seed)
        fair_train, fair_test = split_trajectories(demos, fraction, seed=seed, every_skill=True)
        assert sorted(np.concatenate([fair_train, fair_test]).tolist()) == list(range(len(demos)))
        assert set(test) <= set(fair_test)
        assert set(demos.skill_index[fair_test]) == set(demos.skill_index)
        if set(demos.skill_index[test]) == set(demos.skill_index):
            assert np.array_equal(fair_test, test) and np.array_equal(fair_train, train)
            branches.add("kept")
        else:
            assert len(fair_test) > len(test)
            branches.add("moved")
    assert branches == {"kept", "moved"}
    assert np.array_equal(split_trajectories(demos, 0.1, seed=3, every_skill=True)[1],
                          split_trajectories(demos, 0.1, seed=3, every_skill=True)[1])


def test_filtering_that_keeps_the_acted_entity_leaves_a_pair_where_every_entity_matched(cfg, training_data):
    """A goal within the filter's Chamfer of every observed entity: the official filtering leaves nothing,
    ``keep_acted`` keeps the observed entity farthest from its nearest goal entity, and that goal entity."""
    demos, table = training_data.demos, training_data.table
    chamfer = PairChamfer(table)
    state = int(demos.first_state[0])
    entities = table.state_entities[state]
    pairs = [(entities, entities.copy())]  # the state against itself: every distance 0
    official = TransitionSampler(demos, table, cfg.skills, np.arange(10), 5e-4, chamfer)
    keeping = TransitionSampler(demos, table, cfg.skills, np.arange(10), 5e-4, chamfer, keep_acted=True)
    (o, g), = official._filter_all(pairs, 5e-4)
    assert len(o) == 0 and len(g) == 0
    (o, g), = keeping._filter_all(pairs, 5e-4)
    assert len(o) == 1 and len(g) == 1 and int(o[0]) in entities.tolist()
    # With a goal that moved one entity far, both filterings agree (that entity is the acted one).
    later = table.state_entities[int(demos.target_state[0])]
    assert [tuple(map(len, p)) for p in official._filter_all([(entities, later)], 5e-4)] == \
        [tuple(map(len, p)) for p in keeping._filter_all([(entities, later)], 5e-4)]
