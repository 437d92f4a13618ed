"""The kinematic motion planner every script records its actions with (:class:`Motion`).

An action ``a`` moves the tool by ``a * action_scale`` per environment step (env_spec 1.5), so a
straight segment reaches its end point exactly (tool-tool collisions, e.g. the spatula resting on
the cutting board, are not modelled; the scripts only run into them on the last lowering).
Segments that move dough ramp their speed up and down so that the dough is not thrown (see
:func:`braking_steps`).
"""

from __future__ import annotations

import math

import numpy as np

from pasta.data.skills.scene import half_plate_turn, rotation, yaw_of
from pasta.sim.envs.base import DoughEnv

MAX_BRAKING_STEPS = 30  # a pushing tool slows down over at most this many steps


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def _axis_angle_quat(w: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    axis = np.asarray(w, dtype=np.float64) / theta
    return np.array([math.cos(0.5 * theta), *(math.sin(0.5 * theta) * axis)])


def braking_steps(env: DoughEnv, distance: float, top_speed: float) -> int:
    """Steps over which a tool pushing dough along the ground must slow down so that the dough,
    braked by ground friction alone, keeps up with it instead of sliding on.

    Ground friction takes ``mu |g| T^2`` off the dough's displacement per step every step (``T`` the
    time of one step). A push of ``distance`` at up to ``top_speed`` per step stops over
    ``min(top_speed, sqrt(2 distance brake)) / brake`` steps.
    """
    sim = env.cfg.sim
    brake = env.cfg.material.ground_friction * abs(sim.gravity_m_s2[1]) * (sim.dt_s * sim.substeps_per_step) ** 2
    if brake <= 0 or distance <= 0:
        return 0
    return min(math.ceil(min(top_speed, math.sqrt(2.0 * distance * brake)) / brake), MAX_BRAKING_STEPS)


class Motion:
    """Kinematic model of one tool that records the actions moving it (env_spec 1.5 semantics).

    Per environment step an action ``a`` (clipped to [-1, 1]) moves a knife, box or gripper by
    ``a[:3] * scale`` and turns it by the axis-angle ``a[3:6] * scale`` (box: world frame; gripper:
    body frame); a positive gripper gap action closes by ``a[6] * scale``; a rolling pin rolls by
    ``a0 * scale`` radians about its axis (moving ``radius`` times that across), lifts by
    ``a2 * scale`` and slides by ``a3 * scale``. Like the engine, a step is integrated in
    ``substeps_per_step`` equal parts, each clipping the position to the tool's bounds and the gap to
    [min_gap, max_gap].
    """

    def __init__(self, env: DoughEnv, tool_name: str, n_steps: int):
        self.tool = env.tool(tool_name)
        self.scales = np.asarray(self.tool.action_scales, dtype=np.float64)
        pose = env.tool_poses()[tool_name]
        self.pos = np.asarray(pose.pos, dtype=np.float64)
        self.rot = np.asarray(pose.rot, dtype=np.float64)
        self.gap = float(pose.gap)
        self.n_steps = n_steps
        self.substeps = env.cfg.sim.substeps_per_step
        self.actions: list[np.ndarray] = []

    @property
    def left(self) -> int:
        return self.n_steps - len(self.actions)

    @property
    def yaw(self) -> float:
        return yaw_of(self.rot)

    @property
    def R(self) -> np.ndarray:
        return rotation(self.rot)

    def finish(self) -> np.ndarray:
        out = np.zeros((self.n_steps, len(self.scales)), np.float32)
        if self.actions:
            out[: len(self.actions)] = np.asarray(self.actions, np.float32)
        return out

    def clip_pos(self, pos) -> np.ndarray:
        return np.clip(np.asarray(pos, dtype=np.float64), self.tool.lower_bound, self.tool.upper_bound)

    def step(self, action) -> bool:
        """Record one action and advance the model; False once the step budget is used up."""
        if self.left <= 0:
            return False
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        a[self.scales == 0.0] = 0.0
        self.actions.append(a)
        d = a * self.scales / self.substeps  # the engine spreads a step's motion over its substeps
        kind = self.tool.kind
        for _ in range(self.substeps):
            if kind == "rolling_pin":
                axis = rotation(self.rot) @ np.array([0.0, 0.0, 1.0])
                direction = np.cross([0.0, 1.0, 0.0], axis)
                self.pos = self.pos + direction * (d[0] * self.tool.radius + d[3]) + np.array([0.0, d[2], 0.0])
                self.rot = _quat_mul(_quat_mul(_axis_angle_quat(np.array([0.0, -d[1], 0.0])), self.rot),
                                     _axis_angle_quat(np.array([0.0, 0.0, d[0]])))
            else:
                self.pos = self.pos + d[:3]
                if kind == "box":
                    self.rot = _quat_mul(_axis_angle_quat(d[3:6]), self.rot)
                elif kind == "gripper":
                    self.rot = _quat_mul(self.rot, _axis_angle_quat(d[3:6]))
                    self.gap = float(np.clip(self.gap - d[6], self.tool.min_gap, self.tool.max_gap))
            self.rot = self.rot / np.linalg.norm(self.rot)
            self.pos = self.clip_pos(self.pos)
        return True

    def move(self, pos=None, gap: float | None = None, yaw: float | None = None, speed: float = 1.0,
             ease: int = 0, ease_out: int | None = None) -> None:
        """A straight segment to ``pos`` (and ``gap``; box: world ``yaw``), as fast as ``speed`` allows.

        The speed ramps up linearly over ``ease`` steps and down over ``ease_out`` steps (default
        ``ease``): dough resting on a tool leaves it when the tool stops faster than gravity, and
        dough pushed along the floor slides on when the pusher stops faster than friction would.
        Dimensions without an action (scale 0) are left as they are.
        """
        units = np.zeros(len(self.scales))  # total action (in units of one full step) per dimension
        if pos is not None:
            delta = self.clip_pos(pos) - self.pos
            for i in range(3):
                if self.tool.kind != "rolling_pin" and self.scales[i] > 0:
                    units[i] = delta[i] / self.scales[i]
        if gap is not None and self.tool.kind == "gripper" and self.scales[6] > 0:
            g = float(np.clip(gap, self.tool.min_gap, self.tool.max_gap))
            units[6] = -(g - self.gap) / self.scales[6]
        if yaw is not None and self.tool.kind == "box" and self.scales[4] > 0:
            units[4] = half_plate_turn(yaw - self.yaw) / self.scales[4]
        self._segment(units, speed, ease, ease if ease_out is None else ease_out)

    def follow(self, positions: np.ndarray) -> None:
        """Steps that track a planned path ``(T, 3)`` of the tool's position, one point per step (each
        action is the remaining offset over the action scale, clipped to [-1, 1])."""
        for point in np.asarray(positions, dtype=np.float64):
            units = np.zeros(len(self.scales))
            delta = self.clip_pos(point) - self.pos
            for i in range(3):
                if self.scales[i] > 0:
                    units[i] = delta[i] / self.scales[i]
            if not self.step(units):
                return

    def turn_about_vertical(self, angle: float, speed: float = 1.0) -> bool:
        """Turn a gripper by ``angle`` about world y with its actuated body axis that is vertical."""
        if self.tool.kind != "gripper":
            return False
        R = self.R
        for j in range(3):
            alignment = float(R[1, j])  # world y component of body axis j
            if self.scales[3 + j] > 0 and abs(alignment) > 0.9:
                units = np.zeros(len(self.scales))
                units[3 + j] = math.copysign(angle, alignment) / self.scales[3 + j]
                self._segment(units, speed)
                return True
        return False

    def _segment(self, units: np.ndarray, speed: float, ease_in: int = 0, ease_out: int = 0) -> None:
        """Steps whose actions sum to ``units``: at most ``speed`` per step, ramped at both ends."""
        largest = float(np.abs(units).max()) if len(units) else 0.0
        if largest < 1e-6:
            return
        ramp_in = np.arange(1, ease_in + 1) / (ease_in + 1)
        ramp_out = np.arange(ease_out, 0, -1) / (ease_out + 1)
        cruise = max(0, math.ceil(largest / speed - ramp_in.sum() - ramp_out.sum() - 1e-6))
        weights = np.concatenate([ramp_in, np.ones(cruise), ramp_out])
        for w in weights / weights.sum():
            if not self.step(units * w):
                return
