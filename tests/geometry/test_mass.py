"""Merging entity clouds by hull volume, against exact volumes and a slow apportionment."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from pasta.geometry.mass import apportion, hull_volume, merge_by_shares, merge_by_volume


def _box(rng: np.random.Generator, low, size, n: int) -> np.ndarray:
    """``n`` points in the box, its 8 corners among them (so the hull is the box)."""
    low, size = np.asarray(low, float), np.asarray(size, float)
    corners = low + np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)]) * size
    return np.concatenate([corners, low + rng.uniform(size=(n - 8, 3)) * size])


def test_the_hull_volume_of_a_box_is_its_volume():
    rng = np.random.default_rng(0)
    assert hull_volume(_box(rng, (1.0, 2.0, 3.0), (0.2, 0.05, 0.3), 200)) == pytest.approx(0.003, rel=1e-9)


def test_flat_or_tiny_clouds_have_no_volume_and_bad_ones_are_named():
    assert hull_volume(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)) == 0.0  # coplanar
    assert hull_volume(np.zeros((3, 3))) == 0.0
    with pytest.raises(ValueError, match="finite"):
        hull_volume(np.full((5, 3), np.nan))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        hull_volume(np.zeros((5, 2)))


@pytest.mark.parametrize("weights, total", [([1, 1, 1], 10), ([0.5, 0.3, 0.2], 7), ([3, 0, 1], 1000), ([0, 0], 5),
                                            ([2, 7, 1, 5], 13)])
def test_apportion_matches_largest_remainders_by_hand(weights, total):
    # The slow obvious reference: exact fractions, floors, then one more to the largest remainders (first wins).
    w = [Fraction(x).limit_denominator(10**6) for x in weights]
    shares = [x / sum(w) for x in w] if sum(w) > 0 else [Fraction(1, len(w))] * len(w)
    exact = [s * total for s in shares]
    counts = [int(e) for e in exact]
    by_remainder = sorted(range(len(w)), key=lambda k: (-(exact[k] - counts[k]), k))
    for k in by_remainder[: total - sum(counts)]:
        counts[k] += 1
    assert apportion(np.array(weights, float), total).tolist() == counts


def test_apportion_names_bad_weights():
    with pytest.raises(ValueError, match="-1"):
        apportion(np.array([1.0, -1.0]), 3)


def test_merge_by_volume_gives_each_entity_its_share_of_the_points():
    rng = np.random.default_rng(1)
    big = _box(rng, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 100)
    small = _box(rng, (5.0, 0.0, 0.0), (0.5, 0.5, 0.5), 100)  # an eighth of the volume
    merged = merge_by_volume(np.stack([big, small]), 90, rng=0)
    assert merged.shape == (90, 3)
    from_small = merged[:, 0] >= 5.0
    assert int(from_small.sum()) == 10
    assert len(np.unique(merged[~from_small], axis=0)) == 80  # drawn without replacement
    assert merge_by_volume(np.stack([big, small]), 90, rng=0) == pytest.approx(merged)  # seeded


def test_merge_by_shares_follows_the_given_shares_not_the_volumes():
    rng = np.random.default_rng(2)
    big = _box(rng, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 100)
    small = _box(rng, (5.0, 0.0, 0.0), (0.5, 0.5, 0.5), 100)
    merged = merge_by_shares(np.stack([big, small]), np.array([1.0, 3.0]), 80, rng=0)
    assert int((merged[:, 0] >= 5.0).sum()) == 60
    with pytest.raises(ValueError, match=r"\(2,\)"):
        merge_by_shares(np.stack([big, small]), np.array([1.0, 1.0, 1.0]), 80, rng=0)
