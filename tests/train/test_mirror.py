"""Mirror augmentation: the action sign rules against the tools' kinematics, and the batch reflection."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pasta.config import load
from pasta.train.mirror import MIRROR_SIGNS, mirror_action_signs, mirror_batch, reflection_codes

REFLECTIONS = (np.diag([-1.0, 1.0, 1.0]), np.diag([1.0, 1.0, -1.0]))  # in x, in z


def _exp(w: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(w).as_matrix()


@pytest.mark.parametrize("axis", [0, 1])
def test_rotation_rates_flip_as_the_sign_table_says_for_world_and_body_frames(axis):
    """A mirrored tool pose is ``M R M`` (its shape is symmetric in its body axes). The box turns by a
    world-frame rate, ``exp(w) R``; the gripper by a body-frame rate, ``R exp(w)``. Mirroring the turned pose
    must equal turning the mirrored pose by the table's signed rate."""
    mirror = REFLECTIONS[axis]
    rng = np.random.default_rng(axis)
    box_signs = np.asarray(MIRROR_SIGNS["box"][axis][3:6])
    gripper_signs = np.asarray(MIRROR_SIGNS["gripper"][axis][3:6])
    for _ in range(5):
        pose = Rotation.random(random_state=rng).as_matrix()
        rate = rng.normal(size=3) * 0.3
        mirrored = mirror @ pose @ mirror
        assert np.allclose(mirror @ (_exp(rate) @ pose) @ mirror, _exp(box_signs * rate) @ mirrored, atol=1e-9)
        assert np.allclose(mirror @ (pose @ _exp(rate)) @ mirror, mirrored @ _exp(gripper_signs * rate), atol=1e-9)


def _pin_step(pos: np.ndarray, yaw: float, action: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """The engine's rolling-pin kinematics (``advance_tool``) for a pin whose axis is body z, yawed about y:
    it moves along ``y x axis`` by ``roll * radius + slide``, lifts by ``dy`` and turns by ``-yaw_rate``."""
    roll, yaw_rate, lift, slide = action[:4]
    axis = Rotation.from_rotvec([0.0, yaw, 0.0]).apply([0.0, 0.0, 1.0])
    direction = np.cross([0.0, 1.0, 0.0], axis)
    return pos + direction * (roll * radius + slide) + np.array([0.0, lift, 0.0]), yaw - yaw_rate


@pytest.mark.parametrize("axis", [0, 1])
def test_rolling_pin_actions_flip_as_the_sign_table_says(axis):
    mirror = REFLECTIONS[axis]
    signs = np.asarray(MIRROR_SIGNS["rolling_pin"][axis])
    rng = np.random.default_rng(10 + axis)
    for _ in range(5):
        pos, yaw = rng.uniform(0.3, 0.7, size=3), rng.uniform(-1.0, 1.0)
        action = rng.normal(size=6)
        moved, turned = _pin_step(pos, yaw, action, radius=0.03)
        # a cylinder yawed by theta, mirrored, is the cylinder yawed by -theta (its axis may flip end for end)
        moved_m, turned_m = _pin_step(mirror @ pos, -yaw, signs * action, radius=0.03)
        assert np.allclose(moved_m, mirror @ moved, atol=1e-12)
        assert turned_m == pytest.approx(-turned)


def test_translations_flip_the_reflected_coordinate_only():
    for kind in ("knife", "box", "gripper"):
        for axis, mirror in enumerate(REFLECTIONS):
            assert np.array_equal(MIRROR_SIGNS[kind][axis][:3], np.diag(mirror)), kind
    assert MIRROR_SIGNS["gripper"][0][6] == MIRROR_SIGNS["gripper"][1][6] == 1  # the gap


def test_task_signs_follow_the_action_vector():
    cfg = load("CutRearrange", "smoke")
    signs_x, signs_z = mirror_action_signs(cfg)
    assert signs_x == MIRROR_SIGNS["knife"][0] + MIRROR_SIGNS["gripper"][0]
    assert signs_z == MIRROR_SIGNS["knife"][1] + MIRROR_SIGNS["gripper"][1]


def test_mirror_batch_reflects_about_the_dough_centre_and_twice_is_the_identity():
    cfg = load("CutRearrange", "smoke")
    signs = mirror_action_signs(cfg)
    gen = torch.Generator().manual_seed(0)
    obs, tool, goal = (torch.rand(4, n, 3, generator=gen) for n in (50, 10, 50))
    chunks = torch.randn(4, 2 * len(signs[0]), generator=gen)
    choice = torch.tensor([0, 1, 2, 3])
    once = mirror_batch(obs, tool, goal, chunks, signs, choice)
    twice = mirror_batch(*once, signs, choice)
    for before, after in zip((obs, tool, goal, chunks), twice, strict=True):
        assert torch.allclose(before, after, atol=1e-6)
    m_obs, m_tool, _, m_chunks = once
    assert torch.allclose(m_obs.mean(dim=1), obs.mean(dim=1), atol=1e-6)  # the centre stays
    assert torch.equal(m_obs[0], obs[0]) and torch.equal(m_chunks[0], chunks[0])
    centre_x = obs[1, :, 0].mean()
    assert torch.allclose(m_tool[1, :, 0], 2 * centre_x - tool[1, :, 0], atol=1e-6)
    assert torch.equal(m_tool[1, :, 1:], tool[1, :, 1:])
    assert torch.allclose(m_tool[2, :, 2], 2 * obs[2, :, 2].mean() - tool[2, :, 2], atol=1e-6)
    assert torch.equal(m_chunks[1], chunks[1] * torch.tensor(signs[0] * 2))
    assert torch.equal(m_chunks[3], chunks[3] * torch.tensor(signs[0] * 2) * torch.tensor(signs[1] * 2))
    with pytest.raises(ValueError, match="width 9"):
        mirror_batch(obs, tool, goal, chunks[:, :9], signs, choice)


def test_x_planes_reflect_in_x_only_and_xz_planes_use_every_reflection():
    generator = torch.Generator().manual_seed(0)
    x_only = reflection_codes(400, "x", generator)
    assert set(x_only.tolist()) == {0, 1}
    assert set(reflection_codes(400, "xz", generator).tolist()) == {0, 1, 2, 3}
    cfg = load("CutRearrange", "smoke")
    obs = torch.rand(400, 50, 3)
    mirrored, _, _, _ = mirror_batch(obs, obs[:, :5], obs[:, :7], torch.ones(400, 10), mirror_action_signs(cfg), x_only)
    torch.testing.assert_close(mirrored[..., 1:], obs[..., 1:])  # heights and z untouched
    flipped = (mirrored[..., 0] - obs[..., 0]).abs().amax(dim=1) > 1e-6
    assert 100 < int(flipped.sum()) < 300
    with pytest.raises(ValueError, match="'y'"):
        reflection_codes(3, "y", generator)
