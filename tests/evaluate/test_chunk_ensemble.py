"""Temporal ensembling of action chunks against a plain recount of the weighted mean."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.evaluate.chunk_ensemble import ChunkEnsemble


def recount(chunks: list[np.ndarray], step: int, decay: float) -> np.ndarray:
    """Weighted mean of every prediction for ``step``: chunk ``s`` predicts steps ``s ..``, weight exp(-decay age)."""
    total, weight = 0.0, 0.0
    for start, chunk in enumerate(chunks[: step + 1]):
        age = step - start
        if age < len(chunk):
            total = total + np.exp(-decay * age) * chunk[age]
            weight += np.exp(-decay * age)
    return total / weight


@pytest.mark.parametrize("decay", [-3.0, 0.0, 0.7])
def test_each_step_acts_the_weighted_mean_of_every_prediction_for_it(decay):
    rng = np.random.default_rng(0)
    n_steps, horizon, action_dim = 12, 4, 3
    chunks = [rng.normal(size=(horizon, action_dim)) for _ in range(n_steps)]
    ensemble = ChunkEnsemble(n_steps, action_dim, decay)
    for k, chunk in enumerate(chunks):
        ensemble.add(k, chunk)  # chunks reaching past the last step are cut
        np.testing.assert_allclose(ensemble.action(k), recount(chunks, k, decay), rtol=1e-12)


def test_a_strongly_negative_decay_acts_the_oldest_prediction_and_a_positive_one_the_newest():
    ensemble = ChunkEnsemble(3, 1, -50.0)
    ensemble.add(0, np.array([[1.0], [2.0], [3.0]]))
    ensemble.add(1, np.array([[20.0], [30.0]]))
    assert ensemble.action(1) == pytest.approx([2.0])
    newest = ChunkEnsemble(3, 1, 50.0)
    newest.add(0, np.array([[1.0], [2.0], [3.0]]))
    newest.add(1, np.array([[20.0], [30.0]]))
    assert newest.action(1) == pytest.approx([20.0])


def test_a_step_no_chunk_has_reached_is_refused_by_number():
    ensemble = ChunkEnsemble(5, 2, 0.0)
    ensemble.add(0, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="step 3"):
        ensemble.action(3)
