"""The attended dough: the entity index at step 1, the component nearest the planned centre afterwards."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.evaluate.selection import attended_mask, nearest_components
from pasta.geometry.entities import label_entities

CENTRES = np.array([[0.2, 0.1, 0.5], [0.5, 0.1, 0.5], [0.8, 0.1, 0.3]])


def blobs(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    points = np.concatenate([c + rng.uniform(-0.03, 0.03, size=(200, 3)) for c in CENTRES])
    return points, label_entities(points)


def label_at(labels: np.ndarray, blob: int) -> int:
    return int(labels[blob * 200])


def test_first_step_takes_the_attended_entity_index():
    points, labels = blobs(np.random.default_rng(0))
    for k in range(3):
        assert np.array_equal(attended_mask(points, labels, (k,)), labels == k)


def test_later_steps_take_the_component_nearest_the_planned_centre():
    points, labels = blobs(np.random.default_rng(1))
    planned = CENTRES[2] + np.array([0.05, 0.0, -0.04])  # off the blob, but nearest to it
    mask = attended_mask(points, labels, (0,), planned_centres=planned[None])
    assert np.array_equal(mask, labels == label_at(labels, 2))
    assert mask[400:].all() and not mask[:400].any()


def test_two_attended_entities_near_one_component_take_distinct_components():
    points, labels = blobs(np.random.default_rng(2))
    planned = np.stack([CENTRES[0], CENTRES[0] + 0.01])  # both nearest blob 0; the second gets blob 1
    chosen = nearest_components(points, labels, planned)
    assert chosen == (label_at(labels, 0), label_at(labels, 1))
    mask = attended_mask(points, labels, (0, 1), planned_centres=planned)
    assert mask[:400].all() and not mask[400:].any()


def test_bad_attention_is_refused_by_name():
    points, labels = blobs(np.random.default_rng(3))
    with pytest.raises(ValueError, match=r"\[3\].*3 components"):
        attended_mask(points, labels, (3,))
    with pytest.raises(ValueError, match="2 attended entities but 1 planned centres"):
        attended_mask(points, labels, (0, 1), planned_centres=CENTRES[:1])
