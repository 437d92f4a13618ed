"""Read a task's stored demonstrations into one flat table of states.

Every trajectory contributes its ``T`` observed states followed by one extra state, its target, so all
point clouds live in one array and an entity can name its state by a single index. The target keeps
the observation's point count (its first ``P`` points, as the official ``load_target_pcs`` takes the
first 1000 particles) and gets DBSCAN labels with the task's parameters (the stored file has none).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.data.storage import DatasetError, DatasetIndex, read_trajectory, validate_trajectory
from pasta.geometry.entities import label_entities, resample

__all__ = ["Demonstrations", "load_demonstrations"]


@dataclass(frozen=True, eq=False)
class Demonstrations:
    """The states and actions of a dataset (``n`` trajectories, ``S = sum(T_i + 1)`` states).

    Attributes:
        points: ``(S, P, 3)`` float32 dough points of every state; state ``first_state[i] + t`` is step ``t``
            of trajectory ``i`` and ``target_state[i] = first_state[i] + T_i`` its target.
        labels: ``(S, P)`` int64 entity labels (``0..K-1``) of every state.
        trajectory_ids: ``(n,)`` ids, in index order.
        skills: skill name of each trajectory.
        skill_index: ``(n,)`` index of each trajectory's skill in the config's skill order.
        first_state: ``(n,)``.
        n_steps: ``(n,)`` ``T_i``.
        actions: per trajectory ``(T_i - 1, A)`` float32.
        tool_points: per trajectory ``(T_i, Q, 3)`` float32 surface points of the skill's tool.
        tool_states: per trajectory ``(T_i, 8)`` float32 state of the skill's tool.
    """

    points: np.ndarray
    labels: np.ndarray
    trajectory_ids: np.ndarray
    skills: tuple[str, ...]
    skill_index: np.ndarray
    first_state: np.ndarray
    n_steps: np.ndarray
    actions: tuple[np.ndarray, ...]
    tool_points: tuple[np.ndarray, ...]
    tool_states: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return len(self.trajectory_ids)

    @property
    def target_state(self) -> np.ndarray:
        """``(n,)`` state index of each trajectory's target."""
        return self.first_state + self.n_steps

    @property
    def state_trajectory(self) -> np.ndarray:
        """``(S,)`` the trajectory (position in this table) each state belongs to."""
        return np.repeat(np.arange(len(self)), self.n_steps + 1)


def _tool_slice(cfg: TaskConfig, tool: str, n_tools: int, n_points: int) -> tuple[int, slice]:
    names = [t.name for t in cfg.tools]
    if tool not in names or n_tools != len(names) or n_points % n_tools:
        raise DatasetError(f"cannot find tool {tool!r} among {names} in stored tool arrays "
                           f"({n_tools} tool states, {n_points} tool points)")
    index = names.index(tool)
    per_tool = n_points // n_tools
    return index, slice(index * per_tool, (index + 1) * per_tool)


def load_demonstrations(folder: str | Path, cfg: TaskConfig, *, seed: int = 0) -> Demonstrations:
    """Read ``folder/index.csv`` and every trajectory it lists.

    Args:
        folder: ``$PASTA_HOME/data/<task>/<profile>/<method>``.
        cfg: the task config (skill order, tools, DBSCAN parameters for the targets).
        seed: for resampling a target that has fewer points than the observation.

    Raises:
        DatasetError: naming the folder or the file, when the index or a trajectory is missing or invalid,
            or a trajectory's skill is not one of the task's.
    """
    folder = Path(folder)
    frame = DatasetIndex.load(folder / "index.csv").frame
    if frame.empty:
        raise DatasetError(f"{folder}: the dataset index lists no trajectories", path=folder)
    skill_names = [s.name for s in cfg.skills]
    tools = {s.name: s.tool for s in cfg.skills}
    points, labels, actions, tool_points, tool_states, skills, n_steps = [], [], [], [], [], [], []
    for row in frame.itertuples(index=False):
        path = folder / row.file_name
        arrays, metadata = read_trajectory(path)
        steps = validate_trajectory(arrays, source=path)
        skill = str(metadata.get("skill", row.skill))
        if skill not in skill_names:
            raise DatasetError(f"{path}: skill {skill!r} is not one of {skill_names}", path=path)
        tool, cols = _tool_slice(cfg, tools[skill], arrays["tool_states"].shape[1], arrays["tool_points"].shape[1])
        dough = arrays["dough_points"].astype(np.float32)
        n_obs = dough.shape[1]
        target = arrays["target_points"].astype(np.float32)
        target = target[:n_obs] if len(target) >= n_obs else resample(target, n_obs, np.random.default_rng(seed))
        target_labels = label_entities(target, cfg.data.dbscan_eps, cfg.data.dbscan_min_samples,
                                       cfg.data.dbscan_min_points)
        points.append(np.concatenate([dough, target[None]]))
        labels.append(np.concatenate([arrays["labels"].astype(np.int64), target_labels[None]]))
        actions.append(arrays["actions"].astype(np.float32))
        tool_points.append(arrays["tool_points"][:, cols].astype(np.float32))
        tool_states.append(arrays["tool_states"][:, tool].astype(np.float32))
        skills.append(skill)
        n_steps.append(steps)
    steps_arr = np.asarray(n_steps, dtype=np.int64)
    return Demonstrations(
        points=np.concatenate(points),
        labels=np.concatenate(labels),
        trajectory_ids=frame["trajectory_id"].to_numpy(dtype=np.int64),
        skills=tuple(skills),
        skill_index=np.asarray([skill_names.index(s) for s in skills], dtype=np.int64),
        first_state=np.concatenate([[0], np.cumsum(steps_arr + 1)[:-1]]).astype(np.int64),
        n_steps=steps_arr,
        actions=tuple(actions),
        tool_points=tuple(tool_points),
        tool_states=tuple(tool_states),
    )
