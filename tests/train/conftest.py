"""Training tests: one thread, and one tiny synthetic CutRearrange dataset per session."""

from __future__ import annotations

import pytest
import torch

from pasta.config import load
from pasta.train.stages import load_training_data
from tests.train.synthetic_demos import write_dataset

ENTITY_POINTS = 64  # the tiny VAE's decoded size (tests/models/synthetic.tiny_model_config)


@pytest.fixture(autouse=True)
def _single_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


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
