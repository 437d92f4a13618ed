"""Quaternion helpers for Taichi kernels (unit quaternions, w first)."""

from __future__ import annotations

import numpy as np
import taichi as ti


@ti.func
def quat_mul(a, b):
    """Hamilton product a * b of two (4,) quaternions (w, x, y, z)."""
    return ti.Vector(
        [
            a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
        ]
    )


@ti.func
def quat_normalised(q):
    return q / ti.sqrt(q.dot(q) + 1e-12)


@ti.func
def quat_to_matrix(q):
    """(3, 3) rotation matrix of a (4,) unit quaternion."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ti.Matrix(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@ti.func
def axis_angle_to_quat(w):
    """Unit quaternion of the rotation by the (3,) axis-angle vector ``w`` (radians).

    Smooth at w = 0: the norm carries a tiny epsilon so gradients stay finite.
    """
    theta = ti.sqrt(w.dot(w) + 1e-16)
    half = 0.5 * theta
    s = ti.sin(half) / theta
    return ti.Vector([ti.cos(half), w[0] * s, w[1] * s, w[2] * s])


def quat_to_matrix_np(q: np.ndarray) -> np.ndarray:
    """NumPy twin of :func:`quat_to_matrix` for (4,) quaternions."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
