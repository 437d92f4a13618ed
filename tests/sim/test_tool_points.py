"""Tool surface points (Open3D meshes) and the NumPy tool SDFs."""

from __future__ import annotations

import numpy as np
import pytest

from pasta.config import load
from pasta.config.schema import TASK_NAMES, ToolConfig
from pasta.sim.tool_points import (
    local_sdf,
    local_tool_points,
    tool_mesh,
    tool_points_world,
    tool_world_bounds,
    world_sdf,
)

ALL_TOOLS = {t.name + "@" + task: t for task in TASK_NAMES for t in load(task, "smoke").tools}


@pytest.mark.parametrize("key", sorted(ALL_TOOLS))
def test_local_points_lie_on_the_surface_and_are_cached(key):
    tool = ALL_TOOLS[key]
    pts = local_tool_points(tool)
    assert pts.points.shape == (100, 3) and pts.points.dtype == np.float32
    assert local_tool_points(tool) is pts  # cached per geometry
    gap = 0.1 if tool.kind == "gripper" else 0.0
    world = tool_points_world(pts, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), gap)
    assert np.abs(local_sdf(tool, world, gap)).max() < 5e-4
    spread = world.max(axis=0) - world.min(axis=0)
    assert (spread > 0.02).all()  # the points cover the whole tool, not one spot
    with pytest.raises(ValueError):
        pts.points[0, 0] = 1.0


def test_mesh_vertices_have_zero_sdf():
    for tool in ALL_TOOLS.values():
        vertices = np.asarray(tool_mesh(tool).vertices)
        assert np.abs(local_sdf(tool, vertices) if tool.kind != "gripper" else
                      local_sdf(tool, vertices + [0.5, 0, 0], gap=1.0)).max() < 1e-6, tool.name


def test_gripper_points_split_between_the_fingers_and_follow_the_gap():
    tool = load("CutRearrange", "smoke").tools[1]
    pts = local_tool_points(tool)
    assert (pts.finger_sign == 1).sum() == 50 and (pts.finger_sign == -1).sum() == 50
    narrow = tool_points_world(pts, (0, 0, 0), (1, 0, 0, 0), 0.08)
    wide = tool_points_world(pts, (0, 0, 0), (1, 0, 0, 0), 0.2)
    np.testing.assert_allclose(wide[:50, 0] - narrow[:50, 0], 0.06, atol=1e-6)
    np.testing.assert_allclose(wide[50:, 0] - narrow[50:, 0], -0.06, atol=1e-6)


def test_world_transform_matches_the_rotation_and_batches():
    tool = ToolConfig(name="b", kind="box", position=(0, 0, 0), half_extents=(0.1, 0.02, 0.05), static=True)
    pts = local_tool_points(tool)
    q = (np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0)  # 90 degrees about y: local x -> world -z
    world = tool_points_world(pts, (0.5, 0.5, 0.5), q)
    np.testing.assert_allclose(world[:, 2] - 0.5, -pts.points[:, 0], atol=1e-6)
    assert np.abs(world_sdf(tool, world, (0.5, 0.5, 0.5), q)).max() < 1e-5
    batch = tool_points_world(pts, np.array([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0]]), np.array([q, (1, 0, 0, 0)]))
    assert batch.shape == (2, 100, 3)
    np.testing.assert_allclose(batch[0], world, atol=1e-7)
    lo, hi = tool_world_bounds(tool, (0.5, 0.5, 0.5), q)
    np.testing.assert_allclose(lo, (0.45, 0.48, 0.4), atol=1e-6)
    np.testing.assert_allclose(hi, (0.55, 0.52, 0.6), atol=1e-6)


def test_numpy_sdfs_have_the_right_sign():
    knife = load("CutRearrange", "smoke").tools[0]
    inside = np.array([[0.0, 0.0, 0.0], [0.0, -0.14, 0.0]])
    outside = np.array([[0.02, -0.14, 0.0], [0.0, 0.1, 0.0], [0.03, 0.0, 0.0]])
    assert (local_sdf(knife, inside) < 0).all() and (local_sdf(knife, outside) > 0).all()
    pin = load("CRS", "smoke").tools[2]
    tip = pin.half_length + pin.radius
    assert local_sdf(pin, np.array([[0.0, 0.0, tip]]))[0] == pytest.approx(0.0, abs=1e-9)  # cap end
