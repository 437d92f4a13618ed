"""Tool surface point clouds (env_spec section 3.1) and NumPy twins of the tool SDFs.

Every tool gets a fixed set of ``n_points`` (100) surface points in its local frame, sampled
once with Open3D (Poisson-disk sampling with a fixed seed) from a triangle mesh of the tool and
cached per tool geometry. :func:`tool_points_world` moves them to the world by the tool's pose.

Meshes, in the local frames of :mod:`pasta.sim.tool_geometry`:

* box: ``TriangleMesh.create_box`` centred on the origin.
* knife: a pentagonal prism built from its vertices: the cross-section in x-y runs from the
  top (``half.y``) down the sides to where the V faces ``y = slope |x| - blade_depth`` meet them,
  and to the edge at ``(0, -blade_depth)``; it is extruded over ``|z| <= half.z``.
* rolling_pin: a capsule along local z: the side of ``create_cylinder`` (caps removed) plus the
  outer halves of two ``create_sphere`` at ``z = +-half_length``.
* gripper: one finger box. Half of the points lie on finger + (centred at ``x = +gap/2``), the
  other half are their mirror images (x -> -x) on finger - (at ``x = -gap/2``).

The original sampled fixed grids on single faces (env_spec 3.1); here the whole surface is
sampled, so a point cloud sees every side of a tool.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from pasta.config.schema import ToolConfig
from pasta.sim.quaternion import quat_to_matrix_np

DEFAULT_SEED = 0


@dataclass(frozen=True, eq=False)
class ToolPointSet:
    """Local surface points of one tool.

    ``points`` (n, 3) are in the tool's local frame at gap 0; ``finger_sign`` (n,) is +1 / -1
    for points on the gripper's finger + / - (shifted by +-gap/2 along local x) and 0 otherwise.
    Both arrays are read-only.
    """

    points: np.ndarray
    finger_sign: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def _geometry_key(tool: ToolConfig) -> tuple:
    return (tool.kind, tuple(tool.half_extents), tool.radius, tool.half_length, tool.blade_depth,
            tool.blade_angle_deg)


def blade_slope(blade_angle_deg: float) -> float:
    """Slope of the knife's V faces: cot(blade angle / 2)."""
    return 1.0 / math.tan(math.radians(blade_angle_deg) / 2.0)


# ------------------------------------------------------------------ meshes
def _box_mesh(half):
    import open3d as o3d

    hx, hy, hz = (float(h) for h in half)
    if min(hx, hy, hz) <= 0:
        raise ValueError(f"box half extents must be positive, got {half}")
    mesh = o3d.geometry.TriangleMesh.create_box(2 * hx, 2 * hy, 2 * hz)
    mesh.translate((-hx, -hy, -hz))
    return mesh


def knife_cross_section(half, blade_depth: float, blade_angle_deg: float) -> np.ndarray:
    """The knife's (x, y) cross-section polygon, counter-clockwise: (5, 2)."""
    t, top = float(half[0]), float(half[1])
    side_y = blade_slope(blade_angle_deg) * t - blade_depth
    if t <= 0 or half[2] <= 0 or side_y >= top:
        raise ValueError(
            f"knife geometry half={tuple(half)}, blade_depth={blade_depth}, angle={blade_angle_deg} "
            "has no V edge below its top"
        )
    return np.array([[0.0, -blade_depth], [t, side_y], [t, top], [-t, top], [-t, side_y]])


def _knife_mesh(half, blade_depth: float, blade_angle_deg: float):
    import open3d as o3d

    polygon = knife_cross_section(half, blade_depth, blade_angle_deg)
    hz = float(half[2])
    m = len(polygon)
    front = np.column_stack([polygon, np.full(m, hz)])
    back = np.column_stack([polygon, np.full(m, -hz)])
    vertices = np.vstack([front, back])
    triangles = []
    for i in range(1, m - 1):  # caps: fans from vertex 0 (the polygon is convex)
        triangles.append([0, i, i + 1])
        triangles.append([m, m + i + 1, m + i])
    for i in range(m):  # sides
        j = (i + 1) % m
        triangles.append([i, m + i, j])
        triangles.append([j, m + i, m + j])
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)
    )
    mesh.compute_triangle_normals()
    return mesh


def _capsule_mesh(radius: float, half_length: float):
    import open3d as o3d

    if radius <= 0:
        raise ValueError(f"rolling pin radius must be positive, got {radius}")
    mesh = o3d.geometry.TriangleMesh()
    if half_length > 0:
        cylinder = o3d.geometry.TriangleMesh.create_cylinder(radius, 2 * half_length, resolution=48, split=8)
        v = np.asarray(cylinder.vertices)
        tri = np.asarray(cylinder.triangles)
        z = v[tri][:, :, 2]
        cylinder.remove_triangles_by_mask(np.ptp(z, axis=1) < 1e-9)  # the flat caps lie inside the capsule
        cylinder.remove_unreferenced_vertices()
        mesh += cylinder
    for sign in (1.0, -1.0):
        sphere = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=24)
        v = np.asarray(sphere.vertices)
        centroid_z = v[np.asarray(sphere.triangles)][:, :, 2].mean(axis=1)
        sphere.remove_triangles_by_mask(sign * centroid_z < 0)  # keep the outer half only
        sphere.remove_unreferenced_vertices()
        sphere.translate((0.0, 0.0, sign * half_length))
        mesh += sphere
    return mesh


def tool_mesh(tool: ToolConfig):
    """An ``open3d.geometry.TriangleMesh`` of the tool in its local frame (gripper: one finger at x = 0)."""
    if tool.kind in ("box", "gripper"):
        return _box_mesh(tool.half_extents)
    if tool.kind == "knife":
        return _knife_mesh(tool.half_extents, tool.blade_depth, tool.blade_angle_deg)
    if tool.kind == "rolling_pin":
        return _capsule_mesh(tool.radius, tool.half_length)
    raise ValueError(f"unknown tool kind {tool.kind!r}")


def _sample_mesh(mesh, n: int, seed: int) -> np.ndarray:
    import open3d as o3d

    if n < 1:
        raise ValueError(f"need at least one point, got {n}")
    o3d.utility.random.seed(seed)
    cloud = mesh.sample_points_poisson_disk(number_of_points=n, init_factor=5)
    points = np.asarray(cloud.points, dtype=np.float64)
    if len(points) != n:  # Poisson-disk elimination can fall short on tiny meshes; top up uniformly
        o3d.utility.random.seed(seed + 1)
        extra = np.asarray(mesh.sample_points_uniformly(number_of_points=n - len(points)).points)
        points = np.vstack([points, extra])
    return points


@lru_cache(maxsize=64)
def _cached_points(key: tuple, n_points: int, seed: int) -> ToolPointSet:
    kind, half, radius, half_length, blade_depth, blade_angle = key
    tool = ToolConfig(
        name="_", kind=kind, position=(0.0, 0.0, 0.0), half_extents=half, radius=radius,
        half_length=half_length, blade_depth=blade_depth, blade_angle_deg=blade_angle, static=True,
    )
    mesh = tool_mesh(tool)
    if kind == "gripper":
        n_plus = (n_points + 1) // 2
        plus = _sample_mesh(mesh, n_plus, seed)
        minus = plus[: n_points - n_plus] * np.array([-1.0, 1.0, 1.0])
        points = np.vstack([plus, minus])
        sign = np.concatenate([np.ones(n_plus), -np.ones(n_points - n_plus)])
    else:
        points = _sample_mesh(mesh, n_points, seed)
        sign = np.zeros(n_points)
    points = points.astype(np.float32)
    sign = sign.astype(np.float32)
    points.flags.writeable = False
    sign.flags.writeable = False
    return ToolPointSet(points=points, finger_sign=sign)


def local_tool_points(tool: ToolConfig, n_points: int = 100, seed: int = DEFAULT_SEED) -> ToolPointSet:
    """``n_points`` surface points of ``tool`` in its local frame, cached per geometry (read-only)."""
    return _cached_points(_geometry_key(tool), int(n_points), int(seed))


def tool_points_world(local_points: ToolPointSet | np.ndarray, pos, rot, gap=0.0) -> np.ndarray:
    """Move local tool points to the world: ``pos + R(rot) @ (p + finger_sign * gap / 2 * e_x)``.

    ``pos`` (3,) or (B, 3), ``rot`` (4,) or (B, 4) quaternions w first (normalised here), ``gap``
    scalar or (B,). A plain (n, 3) array is treated as having no fingers. Returns (n, 3) float32,
    or (B, n, 3) for batched poses.
    """
    if isinstance(local_points, ToolPointSet):
        points, sign = local_points.points, local_points.finger_sign
    else:
        points = np.asarray(local_points, dtype=np.float32)
        sign = np.zeros(len(points), np.float32)
    pos = np.asarray(pos, dtype=np.float64)
    rot = np.asarray(rot, dtype=np.float64)
    batched = pos.ndim == 2
    pos_b = pos.reshape(-1, 3)
    rot_b = rot.reshape(-1, 4)
    gap_b = np.broadcast_to(np.asarray(gap, dtype=np.float64).reshape(-1), (len(pos_b),))
    if len(rot_b) != len(pos_b):
        raise ValueError(f"{len(pos_b)} positions but {len(rot_b)} rotations")
    R = np.stack([quat_to_matrix_np(q) for q in rot_b])  # (B, 3, 3)
    shift = 0.5 * gap_b[:, None] * sign[None]  # (B, n): finger offset along local x
    local = np.repeat(points[None].astype(np.float64), len(pos_b), axis=0)
    local[..., 0] += shift
    world = np.einsum("bij,bnj->bni", R, local) + pos_b[:, None, :]
    world = world.astype(np.float32)
    return world if batched else world[0]


# ---------------------------------------------------------------- NumPy SDFs
def _box_sdf(p: np.ndarray, half) -> np.ndarray:
    q = np.abs(p) - np.asarray(half)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return np.where(q.max(axis=-1) > 0, outside, inside)


def _knife_sdf(p: np.ndarray, half, blade_depth: float, slope: float) -> np.ndarray:
    """Exact where the body or one V face is nearest; like the engine's knife_sdf (max of planes)."""
    centre_y = 0.5 * (half[1] - blade_depth)
    body = _box_sdf(p - np.array([0.0, centre_y, 0.0]), (half[0], 0.5 * (half[1] + blade_depth), half[2]))
    norm = math.sqrt(1.0 + slope * slope)
    face_right = (slope * p[..., 0] - p[..., 1] - blade_depth) / norm
    face_left = (-slope * p[..., 0] - p[..., 1] - blade_depth) / norm
    return np.maximum(body, np.maximum(face_right, face_left))


def _capsule_sdf(p: np.ndarray, radius: float, half_length: float) -> np.ndarray:
    closest = np.zeros_like(p)
    closest[..., 2] = np.clip(p[..., 2], -half_length, half_length)
    return np.linalg.norm(p - closest, axis=-1) - radius


def local_sdf(tool: ToolConfig, points: np.ndarray, gap: float = 0.0) -> np.ndarray:
    """Signed distance (negative inside) of local points (n, 3) to ``tool``: (n,).

    NumPy twin of the engine's SDFs; for a gripper, the minimum over both fingers at ``gap``.
    """
    p = np.asarray(points, dtype=np.float64)
    if tool.kind == "box":
        return _box_sdf(p, tool.half_extents)
    if tool.kind == "knife":
        return _knife_sdf(p, tool.half_extents, tool.blade_depth, blade_slope(tool.blade_angle_deg))
    if tool.kind == "rolling_pin":
        return _capsule_sdf(p, tool.radius, tool.half_length)
    if tool.kind == "gripper":
        shift = np.array([0.5 * gap, 0.0, 0.0])
        return np.minimum(_box_sdf(p - shift, tool.half_extents), _box_sdf(p + shift, tool.half_extents))
    raise ValueError(f"unknown tool kind {tool.kind!r}")


def world_sdf(tool: ToolConfig, points: np.ndarray, pos, rot, gap: float = 0.0) -> np.ndarray:
    """Signed distance of world points (n, 3) to ``tool`` at pose (pos, rot, gap): (n,)."""
    R = quat_to_matrix_np(rot)
    local = (np.asarray(points, dtype=np.float64) - np.asarray(pos, dtype=np.float64)) @ R
    return local_sdf(tool, local, gap)


def tool_world_bounds(tool: ToolConfig, pos, rot, gap: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned world bounds (lo (3,), hi (3,)) of the tool at a pose, from its mesh vertices."""
    vertices = np.asarray(tool_mesh(tool).vertices, dtype=np.float64)
    if tool.kind == "gripper":
        shift = np.array([0.5 * gap, 0.0, 0.0])
        vertices = np.vstack([vertices + shift, vertices - shift])
    world = vertices @ quat_to_matrix_np(rot).T + np.asarray(pos, dtype=np.float64)
    return world.min(axis=0), world.max(axis=0)
