"""Seeded particle samplers and the particle budget split."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.sim.shapes import (
    BoxPiece,
    SpherePiece,
    place_distractors,
    sample_box,
    sample_pieces,
    sample_scattered,
    sample_sphere,
    split_budget,
)


def test_box_and_sphere_are_seeded_float32_and_inside():
    box = sample_box(np.random.default_rng(0), 1000, (0.5, 0.1, 0.5), (0.1, 0.04, 0.03))
    assert box.shape == (1000, 3) and box.dtype == np.float32
    assert (np.abs(box - [0.5, 0.1, 0.5]) <= np.array([0.1, 0.04, 0.03]) + 1e-6).all()
    again = sample_box(np.random.default_rng(0), 1000, (0.5, 0.1, 0.5), (0.1, 0.04, 0.03))
    np.testing.assert_array_equal(box, again)
    ball = sample_sphere(np.random.default_rng(1), 4000, (0.3, 0.3, 0.3), 0.05)
    r = np.linalg.norm(ball - 0.3, axis=1)
    assert ball.dtype == np.float32 and r.max() <= 0.05 + 1e-6
    assert np.mean(r < 0.05 * 0.5 ** (1 / 3)) == pytest.approx(0.5, abs=0.03)  # uniform in volume


def test_scattered_shape_matches_the_original_generator():
    x = sample_scattered(np.random.default_rng(0))
    assert x.shape == (2000, 3) and x.dtype == np.float32
    blobs = x.reshape(40, 50, 3)  # 40 seeds x 50 copies
    assert np.all(blobs.std(axis=1)[:, [0, 2]] < 0.007)
    assert np.all(blobs.std(axis=1)[:, 1] < 0.002)
    assert x[:, 1].min() > 0.1  # lifted by 0.1
    assert x[:, 0].min() > 0.62 and x[:, 0].max() < 0.78


def test_split_budget_is_proportional_and_exact():
    assert split_budget(2000, [1.0]) == [2000]
    counts = split_budget(2000, [3.0, 1.0, 1.0])
    assert sum(counts) == 2000 and counts == [1200, 400, 400]
    counts = split_budget(1001, [1.0, 1.0, 1.0])
    assert sum(counts) == 1001 and max(counts) - min(counts) == 1
    assert split_budget(10, [1e6, 1e-9]) == [9, 1]  # every piece keeps a particle
    with pytest.raises(ValueError):
        split_budget(2, [1.0, 1.0, 1.0])
    with pytest.raises(ValueError):
        split_budget(10, [1.0, 0.0])


def test_sample_pieces_shuffles_and_labels():
    pieces = [BoxPiece((0.3, 0.1, 0.5), (0.05, 0.05, 0.05)), SpherePiece((0.7, 0.1, 0.5), 0.05)]
    x, labels = sample_pieces(np.random.default_rng(0), pieces, 1000)
    assert x.shape == (1000, 3) and labels.shape == (1000,)
    assert np.bincount(labels).tolist() == split_budget(1000, [p.volume for p in pieces])
    assert (x[labels == 0, 0] < 0.36).all() and (x[labels == 1, 0] > 0.64).all()
    assert 0 < labels[:100].mean() < 1  # shuffled: a prefix holds both pieces


def test_distractors_keep_their_distance():
    rng = np.random.default_rng(0)
    occupied = [((0.4, 0.4), (0.6, 0.6))]
    pieces = place_distractors(rng, 3, occupied, floor_y=0.09, main_volume=1e-3, margin=0.05)
    assert len(pieces) == 3
    rects = [np.array(r) for r in occupied] + [np.array(p.bounds())[:, [0, 2]] for p in pieces]
    for i in range(len(rects)):
        for j in range(i + 1, len(rects)):
            lo_i, hi_i = rects[i]
            lo_j, hi_j = rects[j]
            separated = np.any(lo_i >= hi_j + 0.05 - 1e-9) or np.any(lo_j >= hi_i + 0.05 - 1e-9)
            assert separated, (i, j)
    for p in pieces:
        assert p.bounds()[0][1] == pytest.approx(0.09)
        assert 0.1e-3 <= p.volume <= 0.2e-3 + 1e-12
    with pytest.raises(RuntimeError, match="no room"):
        place_distractors(rng, 1, [((0.0, 0.0), (1.0, 1.0))], 0.09, 1e-3, max_tries=50)
