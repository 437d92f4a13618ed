"""The demonstration key: what decides a demonstration, and so when a rerun may reuse its file."""

import pytest

from pasta.config import load
from pasta.data.demos import demonstration_key


def key(overrides=(), method="scripted", seed=0):
    return demonstration_key(load("CRS", "small", list(overrides)), method, seed)


def test_equal_configs_give_equal_keys():
    assert key() == key()


@pytest.mark.parametrize("override", ["train.policy_lr=0.002", "policy.encoder=pointnet", "plan.samples=7",
                                      "eval.success_threshold=0.5"])
def test_training_planning_and_evaluation_settings_keep_the_key(override):
    assert key([override]) == key()


@pytest.mark.parametrize("override", ["sim.tool_expel_rate=0.1", "data.knife_start=centre", "data.dbscan_eps=0.04",
                                      "distractors=2"])
def test_what_a_demonstration_reads_changes_the_key(override):
    assert key([override]) != key()


def test_method_and_seed_change_the_key():
    assert key(method="gbto") != key()
    assert key(seed=1) != key()
