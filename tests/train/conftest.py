"""Training tests: one thread, and one tiny synthetic CutRearrange dataset per session."""

from __future__ import annotations

import pytest

from pasta.config import load
from pasta.train.stages import load_training_data
from tests.threads import one_torch_thread
from tests.train.synthetic_demos import write_dataset

ENTITY_POINTS = 64  # the tiny VAE's decoded size (tests/models/synthetic.tiny_model_config)


_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="session")
def cfg():
    return load("CutRearrange", "smoke")


@pytest.fixture(scope="session")
def dataset_folder(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("demos"), n_trajectories=10)


@pytest.fixture(scope="session")
def training_data(cfg, dataset_folder):
    return load_training_data(cfg, dataset_folder, entity_points=ENTITY_POINTS)


@pytest.fixture(scope="session")
def scene_data(cfg, dataset_folder):
    return load_training_data(cfg, dataset_folder, entity_points=ENTITY_POINTS, whole_scene=True)
