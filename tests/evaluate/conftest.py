"""Evaluation tests: CutRearrange at the smoke profile's simulator size, tiny skill budgets, untrained models."""

from __future__ import annotations

import pytest

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.train.bundle import untrained
from tests.threads import one_torch_thread

# Short skills and a tiny planner; the layout (grid 32, 2000 particles) stays the smoke profile's.
FAST = ("sim.steps_per_skill=2", "sim.settle_steps=1", "plan.samples=8", "plan.iterations=2")
PRIOR = LatentPrior(2, (0.2, 0.1, 0.2), (0.8, 0.2, 0.8))


_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="session")
def cfg():
    return load("CutRearrange", "smoke", list(FAST))


@pytest.fixture(scope="session")
def bundle(cfg):
    return untrained(cfg, "pasta", PRIOR).eval()
