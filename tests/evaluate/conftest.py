"""Evaluation tests: CutRearrange at the smoke profile's simulator size, tiny skill budgets, untrained models."""

from __future__ import annotations

import pytest
import torch

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.train.bundle import untrained

# Short skills and a tiny planner; the layout (grid 32, 2000 particles) stays the smoke profile's.
FAST = ("sim.steps_per_skill=2", "sim.settle_steps=1", "plan.samples=8", "plan.iterations=2")
PRIOR = LatentPrior(2, (0.2, 0.1, 0.2), (0.8, 0.2, 0.8))


@pytest.fixture(autouse=True)
def _single_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="session")
def cfg():
    return load("CutRearrange", "smoke", list(FAST))


@pytest.fixture(scope="session")
def bundle(cfg):
    return untrained(cfg, "pasta", PRIOR).eval()
