"""Signed distance functions of the rigid tools, in the tool's local frame.

Each function takes a local point ``p`` (3,) and the tool's runtime geometry and
returns the signed distance (negative inside). The kind of a tool is a
compile-time choice; its sizes are runtime values, so one compiled kernel
serves every size of the same tool.

Local frames:
  * box: centred, half extents ``half``.
  * knife: a box of half thickness ``half.x`` and half width ``half.z``, from
    ``-blade_depth`` to ``half.y`` in y, cut at the bottom by a V edge whose faces
    satisfy y >= slope * |x| - blade_depth (slope = cot(blade angle / 2)).
  * rolling_pin: a capsule of ``radius`` around the segment |z| <= ``half_length``.
  * gripper: two box fingers of half extents ``half`` centred at x = +-gap / 2.
"""

from __future__ import annotations

import taichi as ti


@ti.func
def box_sdf(p, half):
    q = ti.abs(p) - half
    outside = ti.sqrt(ti.max(q, 0.0).dot(ti.max(q, 0.0)) + 1e-14)
    inside = ti.min(ti.max(q[0], ti.max(q[1], q[2])), 0.0)
    return ti.select(ti.max(q[0], ti.max(q[1], q[2])) > 0.0, outside, inside)


@ti.func
def knife_sdf(p, half, blade_depth, slope):
    centre_y = 0.5 * (half[1] - blade_depth)
    box_half = ti.Vector([half[0], 0.5 * (half[1] + blade_depth), half[2]])
    body = box_sdf(p - ti.Vector([0.0, centre_y, 0.0]), box_half)
    norm = ti.sqrt(1.0 + slope * slope)
    face_right = (slope * p[0] - p[1] - blade_depth) / norm
    face_left = (-slope * p[0] - p[1] - blade_depth) / norm
    return ti.max(body, ti.max(face_right, face_left))


@ti.func
def capsule_sdf(p, radius, half_length):
    closest = ti.Vector([0.0, 0.0, ti.min(ti.max(p[2], -half_length), half_length)])
    d = p - closest
    return ti.sqrt(d.dot(d) + 1e-14) - radius
