"""A tiny synthetic CutRearrange dataset written with ``write_trajectory``: no simulator needed.

Cut trajectories: one slab that splits into two halves drifting apart (labels 0 before the split, then
0/1 by side); rearrange trajectories: two slabs, the second sliding towards its target spot. Actions
carry the drift in the skill tool's dimensions, so a policy can learn them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pasta.data.storage import DatasetIndex, write_trajectory

STEPS = 6  # states per trajectory
POINTS = 96  # dough points per state
HALF = np.array([0.04, 0.015, 0.04])
KNIFE_DIMS, GRIPPER_DIMS = slice(0, 3), slice(3, 10)  # CutRearrange: knife 3 + gripper 7 = 10 actions


def _slab(rng: np.random.Generator, centre: np.ndarray, n: int, half: np.ndarray = HALF) -> np.ndarray:
    return centre + half * (2 * rng.random((n, 3)) - 1)


def _trajectory(rng: np.random.Generator, skill: str) -> dict[str, np.ndarray]:
    base = np.array([0.5, 0.05, 0.5]) + np.array([0.2, 0.0, 0.2]) * (2 * rng.random(3) - 1) * [1, 0, 1]
    half_n = POINTS // 2
    unit = 2 * rng.random((POINTS, 3)) - 1
    points, labels = [], []
    if skill == "cut":
        speed = 0.02 + 0.02 * rng.random()
        for t in range(STEPS + 1):  # the last state is the target
            gap = 0.0 if t < 2 else speed * (t - 1)
            left = base + [-HALF[0] / 2 - gap, 0, 0] + unit[:half_n] * (HALF / [2, 1, 1])
            right = base + [HALF[0] / 2 + gap, 0, 0] + unit[half_n:] * (HALF / [2, 1, 1])
            points.append(np.concatenate([left, right]))
            labels.append(np.zeros(POINTS, np.int64) if gap == 0 else np.repeat([0, 1], half_n))
        direction = np.array([speed / 0.04, 0.0, 0.0])
        dims = KNIFE_DIMS
    else:
        other = base + [0.15, 0.0, 0.0]
        goal = base + np.array([-0.1, 0.0, 0.15]) * (1 + 0.5 * rng.random())
        for t in range(STEPS + 1):
            moved = base + (goal - base) * min(t / (STEPS - 1), 1.0)
            points.append(np.concatenate([moved + unit[:half_n] * HALF, other + unit[half_n:] * HALF]))
            labels.append(np.repeat([0, 1], half_n))
        direction = (goal - base) / (STEPS - 1) / 0.03
        dims = GRIPPER_DIMS
    actions = np.zeros((STEPS - 1, 10), np.float32)
    block = np.zeros((STEPS - 1, dims.stop - dims.start), np.float32)
    block[:, :3] = np.clip(direction, -1, 1)
    actions[:, dims] = block
    tool = np.zeros((STEPS, 2, 8), np.float32)
    tool[:, :, :3] = base
    tool[:, :, 3] = 1.0
    tool_points = np.concatenate([base + 0.02 * (2 * rng.random((STEPS, 20, 3)) - 1),
                                  base + [0, 0.1, 0] + 0.02 * (2 * rng.random((STEPS, 20, 3)) - 1)], axis=1)
    return {
        "dough_points": np.stack(points[:STEPS]).astype(np.float32),
        "tool_states": tool,
        "tool_points": tool_points.astype(np.float32),
        "actions": actions,
        "labels": np.stack(labels[:STEPS]).astype(np.int16),
        "target_points": points[STEPS].astype(np.float32),
    }


def write_dataset(folder: str | Path, n_trajectories: int = 10, seed: int = 0) -> Path:
    """Write ``n_trajectories`` (alternately cut and rearrange) and their index into ``folder``."""
    folder = Path(folder)
    rng = np.random.default_rng(seed)
    index = DatasetIndex()
    for i in range(n_trajectories):
        skill = "cut" if i % 2 == 0 else "rearrange"
        name = f"trajectory_{i:06d}.npz"
        write_trajectory(folder / name, _trajectory(rng, skill),
                         {"skill": skill, "trajectory_id": i, "configuration_id": i, "task": "CutRearrange"})
        index.add(trajectory_id=i, configuration_id=i, skill=skill, file_name=name, split="train")
    index.save(folder / "index.csv")
    return folder
