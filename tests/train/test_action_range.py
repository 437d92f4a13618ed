"""The demonstrated action range: per skill, per dimension, against a slow loop; the box it clips to; the bundle
that keeps it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pasta.evaluate.policy_action import checked_action, skill_action_range
from pasta.models.latent_prior import LatentPrior
from pasta.train.action_range import bounded, demonstrated_action_ranges
from pasta.train.bundle import load_trained, save_trained, untrained
from tests.models.synthetic import tiny_model_config

PRIOR = LatentPrior(2, (0.2, 0.2, 0.2), (0.8, 0.8, 0.8))


def slow_ranges(demos, trajectories, skill_index, action_dim):
    low, high = [1.0] * action_dim, [-1.0] * action_dim
    for i in trajectories:
        if demos.skill_index[i] != skill_index:
            continue
        for action in demos.actions[i]:
            for d in range(action_dim):
                low[d], high[d] = min(low[d], float(action[d])), max(high[d], float(action[d]))
    return tuple(low), tuple(high)


def test_each_skills_range_is_the_lowest_and_highest_action_of_its_given_trajectories(training_data):
    demos, train = training_data.demos, training_data.heads_train
    ranges = demonstrated_action_ranges(demos, train, 2, 10)
    for k in range(2):
        low, high = slow_ranges(demos, train, k, 10)
        np.testing.assert_allclose(ranges[k][0], low, rtol=0, atol=0)
        np.testing.assert_allclose(ranges[k][1], high, rtol=0, atol=0)
    (cut_low, cut_high), (rearrange_low, rearrange_high) = ranges
    assert 0 < cut_low[0] < cut_high[0] and cut_high[3:] == (0.0,) * 7  # the knife moves along +x; the gripper not
    assert cut_low != rearrange_low and rearrange_low[:3] == (0.0,) * 3
    cuts_only = [i for i in train if demos.skill_index[i] == 0]
    assert demonstrated_action_ranges(demos, cuts_only, 2, 10)[1] == ((-1.0,) * 10, (1.0,) * 10)  # none: [-1, 1]


def test_an_action_is_clipped_to_the_box_and_a_box_of_other_length_is_refused():
    box = ((0.0, -0.5, 0.0), (0.5, 0.5, 0.0))
    np.testing.assert_array_equal(bounded(np.array([0.7, -0.2, 0.3]), box), np.array([0.5, -0.2, 0.0], np.float32))
    with pytest.raises(ValueError, match=r"shape \(2,\) cannot be bounded by a range of 3 dimensions"):
        bounded(np.zeros(2), box)


def test_the_bundle_keeps_its_action_range_and_the_demonstrated_executor_needs_it(cfg, tmp_path):
    bundle = untrained(cfg, "pasta", PRIOR, model_config=tiny_model_config(), seed=0)
    with pytest.raises(ValueError, match="trained before it was kept: run `pasta train` again"):
        skill_action_range(bundle, "rearrange", "demonstrated")
    assert skill_action_range(bundle, "rearrange", "unit") is None
    with pytest.raises(ValueError, match="unknown policy action range 'demo'"):
        skill_action_range(bundle, "rearrange", "demo")
    gripper_up = ((0.0,) * 3 + (-1.0, 0.0, -1.0) + (0.0,) * 3 + (-1.0,), (0.0,) * 3 + (1.0,) * 3 + (0.0,) * 3 + (1.0,))
    ranged = dataclasses.replace(bundle, action_range=(((-1.0,) * 10, (1.0,) * 10), gripper_up))
    loaded = load_trained(save_trained(tmp_path / "models.pt", ranged))
    assert loaded.action_range == ranged.action_range
    box = skill_action_range(loaded, "rearrange", "demonstrated")
    lowered = np.array([0.3, 0, 0, 0.2, -0.2, 1.5, 0.1, 0, 0, -0.4])  # the gripper goes down: no demonstration did
    np.testing.assert_allclose(checked_action(lowered, "rearrange", 1, 3, box), [0, 0, 0, 0.2, 0, 1, 0, 0, 0, -0.4])
    np.testing.assert_allclose(checked_action(lowered, "rearrange", 1, 3), np.clip(lowered, -1, 1))
    with pytest.raises(ValueError, match="action_range must hold a \\(lowest, highest\\) pair of 10 floats"):
        dataclasses.replace(bundle, action_range=(gripper_up,))
