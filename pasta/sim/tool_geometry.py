"""Signed distance functions of the rigid tools and their outward normals, in the tool's local frame.

Each function takes a local point ``p`` (3,) and the tool's runtime geometry and
returns ``(sdf, normal)``: the signed distance (negative inside) and the unit
outward normal of the nearest surface, both analytic. Ties (a point exactly on a
tool's mid-plane) resolve to the positive axis, so every node inside a tool has a
direction to leave by. The kind of a tool is a compile-time choice; its sizes are
runtime values, so one compiled kernel serves every size of the same tool.

Local frames:
  * box: centred, half extents ``half``.
  * knife: a box of half thickness ``half.x`` and half width ``half.z``, from
    ``-blade_depth`` to ``half.y`` in y, cut at the bottom by a V edge whose faces
    satisfy y >= slope * |x| - blade_depth (slope = cot(blade angle / 2)).
  * rolling_pin: a capsule of ``radius`` around the segment |z| <= ``half_length``.
  * gripper: two box fingers of half extents ``half`` centred at x = +-gap / 2.
"""

import taichi as ti


@ti.func
def _sign(x):
    return ti.select(x >= 0.0, 1.0, -1.0)


@ti.func
def box_sdf_normal(p, half):
    q = ti.abs(p) - half
    s = ti.Vector([_sign(p[0]), _sign(p[1]), _sign(p[2])])
    outside = ti.max(q, 0.0)
    outside_len = ti.sqrt(outside.dot(outside) + 1e-14)
    # The axis of the nearest face, without dynamic indexing (Taichi's adjoints need constant indices).
    q_max = ti.max(q[0], ti.max(q[1], q[2]))
    along_x = q[0] >= q_max
    along_y = (not along_x) and q[1] >= q_max
    not_x = ti.select(along_y, ti.Vector([0.0, s[1], 0.0]), ti.Vector([0.0, 0.0, s[2]]))
    inside_normal = ti.select(along_x, ti.Vector([s[0], 0.0, 0.0]), not_x)
    is_outside = q_max > 0.0
    sdf = ti.select(is_outside, outside_len, q_max)
    normal = ti.select(is_outside, s * outside / outside_len, inside_normal)
    return sdf, normal


@ti.func
def knife_sdf_normal(p, half, blade_depth, slope):
    centre = ti.Vector([0.0, 0.5 * (half[1] - blade_depth), 0.0])
    body_half = ti.Vector([half[0], 0.5 * (half[1] + blade_depth), half[2]])
    sdf, normal = box_sdf_normal(p - centre, body_half)
    norm = ti.sqrt(1.0 + slope * slope)
    right = (slope * p[0] - p[1] - blade_depth) / norm
    left = (-slope * p[0] - p[1] - blade_depth) / norm
    if right > sdf:
        sdf = right
        normal = ti.Vector([slope, -1.0, 0.0]) / norm
    if left > sdf:
        sdf = left
        normal = ti.Vector([-slope, -1.0, 0.0]) / norm
    return sdf, normal


@ti.func
def capsule_sdf_normal(p, radius, half_length):
    closest = ti.Vector([0.0, 0.0, ti.min(ti.max(p[2], -half_length), half_length)])
    d = p - closest
    length = ti.sqrt(d.dot(d) + 1e-14)
    return length - radius, d / length
