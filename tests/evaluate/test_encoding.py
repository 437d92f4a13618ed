"""Clouds to entity latents: one latent per DBSCAN entity (or one for the whole scene with Flat3D)."""

from __future__ import annotations

import numpy as np
import torch

from pasta.evaluate.encoding import ENTITY_POINTS, encode_scene
from pasta.train.bundle import untrained
from tests.evaluate.conftest import PRIOR


def two_boxes(rng: np.random.Generator, n: tuple[int, int] = (700, 300)) -> np.ndarray:
    a = rng.uniform((0.2, 0.1, 0.4), (0.3, 0.15, 0.5), size=(n[0], 3))
    b = rng.uniform((0.6, 0.1, 0.4), (0.65, 0.15, 0.45), size=(n[1], 3))
    return np.concatenate([a, b]).astype(np.float32)


def test_each_entity_becomes_one_latent_centred_on_it(cfg, bundle):
    points = two_boxes(np.random.default_rng(0))
    scene = encode_scene(cfg, bundle, points, np.random.default_rng(1))
    assert scene.latents.shape == (2, bundle.vae.config.latent_dim + 3)
    assert scene.entities.shape == (2, ENTITY_POINTS, 3)
    assert scene.labels.shape == (1000,) and set(np.unique(scene.labels)) == {0, 1}
    assert (scene.labels[:700] == scene.labels[0]).all() and (scene.labels[700:] != scene.labels[0]).all()
    # t is the mean of the resampled entity that was encoded, z the VAE's posterior mean of it.
    np.testing.assert_allclose(scene.latents[:, 2:].numpy(), scene.entities.mean(axis=1), atol=1e-5)
    with torch.no_grad():
        expected = bundle.vae.encode_entities(torch.from_numpy(scene.entities))
    torch.testing.assert_close(scene.latents, expected)
    small = points[scene.labels == 1]
    assert set(map(tuple, scene.entities[1])) == set(map(tuple, small)), "padding draws only the entity's points"


def test_flat3d_encodes_the_whole_scene_as_one_entity(cfg):
    flat = untrained(cfg, "flat3d", PRIOR).eval()
    points = two_boxes(np.random.default_rng(0))
    scene = encode_scene(cfg, flat, points, np.random.default_rng(1))
    assert scene.latents.shape == (1, 5)
    assert (scene.labels == 0).all()
    np.testing.assert_allclose(scene.latents[0, 2:].numpy(), points.mean(axis=0), atol=1e-5)


def test_encoding_is_reproducible_with_the_same_generator(cfg, bundle):
    points = two_boxes(np.random.default_rng(3), n=(1500, 500))  # more points than ENTITY_POINTS: subsampled
    a = encode_scene(cfg, bundle, points, np.random.default_rng(7))
    b = encode_scene(cfg, bundle, points, np.random.default_rng(7))
    torch.testing.assert_close(a.latents, b.latents, rtol=0, atol=0)
    np.testing.assert_array_equal(a.entities, b.entities)
    other = encode_scene(cfg, bundle, points, np.random.default_rng(8))
    np.testing.assert_array_equal(other.labels, a.labels)  # the same entities ...
    for k in range(2):  # ... each resampled differently, so encoded differently
        assert not np.array_equal(other.entities[k], a.entities[k]), k
        assert not torch.equal(other.latents[k], a.latents[k]), k
