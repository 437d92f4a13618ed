"""The dough environment shared by every task.

A :class:`DoughEnv` wraps one :class:`~pasta.sim.engine.MPMSimulator` (shared per process by
compile-time layout) and adds what tasks need on top of raw stepping:

* ``reset(configuration)`` from a :class:`DoughConfiguration` (dough particles, tool poses and
  an optional target point cloud), returning an :class:`Observation`;
* ``step(action)`` with validation that names the step, the value and the tool;
* observations as point clouds (env_spec 3.1): the first ``observation_points`` particles (a
  fixed index set), 100 world-frame surface points per tool, tool states (n_tools, 8);
* exact ``get_state`` / ``set_state`` (including the step counter), ``teleport_tool`` (used
  between skills, env_spec 2.5) and ``settle`` (zero actions).

Several environments may share one simulator (same layout, e.g. CRS and CRS-Twice). Each call
first makes sure the simulator holds this environment's state and runtime parameters; the
previous owner's state is stashed and restored when it is used again. Code that drives the
shared simulator directly between two calls of an environment is not detected.
"""

from __future__ import annotations

import contextlib
import math
import weakref
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from pasta.config.schema import SkillConfig, TaskConfig, ToolConfig
from pasta.sim.engine import ActionError, MPMSimulator, simulator_for
from pasta.sim.shapes import Piece, floor_height, place_distractors, sample_pieces
from pasta.sim.tool_points import ToolPointSet, local_tool_points, tool_points_world, tool_world_bounds

STATE_KEYS = ("x", "v", "C", "F", "tool_pos", "tool_rot", "tool_gap")

# Which environment's state each shared simulator currently holds: id(simulator) -> env.
_OWNERS: dict[int, weakref.ref] = {}


def _read_only(arr: np.ndarray) -> np.ndarray:
    arr.flags.writeable = False
    return arr


def _unit_quaternion(rot: Sequence[float], what: str) -> tuple[float, float, float, float]:
    q = np.asarray(rot, dtype=np.float64).reshape(-1)
    norm = float(np.linalg.norm(q)) if q.shape == (4,) else 0.0
    if q.shape != (4,) or not np.isfinite(q).all() or abs(norm - 1.0) > 1e-2:
        raise ValueError(f"{what}: rotation must be a unit quaternion (w, x, y, z), got {rot!r}")
    q = q / norm
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


@dataclass(frozen=True)
class ToolPose:
    """A tool's pose: position (3,), unit quaternion w first (4,), gripper gap (0 otherwise)."""

    pos: tuple[float, float, float]
    rot: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    gap: float = 0.0

    def __post_init__(self) -> None:
        pos = np.asarray(self.pos, dtype=np.float64).reshape(-1)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise ValueError(f"tool position must be 3 finite numbers, got {self.pos!r}")
        object.__setattr__(self, "pos", tuple(float(p) for p in pos))
        object.__setattr__(self, "rot", _unit_quaternion(self.rot, "tool pose"))
        gap = float(self.gap)
        if not math.isfinite(gap) or gap < 0:
            raise ValueError(f"tool gap must be finite and >= 0, got {self.gap!r}")
        object.__setattr__(self, "gap", gap)

    @classmethod
    def from_tool(cls, tool: ToolConfig) -> ToolPose:
        """The tool's configured ("back") pose."""
        return cls(pos=tool.position, rot=tool.rotation, gap=tool.gap)

    def as_vector(self) -> np.ndarray:
        """(8,) float32: pos, quaternion, gap (the observation's tool state)."""
        return np.array([*self.pos, *self.rot, self.gap], dtype=np.float32)


@dataclass(frozen=True, eq=False)
class DoughConfiguration:
    """What an episode starts from.

    ``particles`` (N, 3) dough positions (N = ``cfg.sim.n_particles``); ``tool_poses`` maps tool
    name -> :class:`ToolPose` (tools left out start at their configured pose); ``target``
    (M, 3) an optional goal point cloud; ``piece_labels`` (N,) optional int labels of the piece
    each particle was sampled in (0 .. main pieces, then distractors). Arrays are stored as
    read-only float32 / int32 copies.
    """

    particles: np.ndarray
    tool_poses: Mapping[str, ToolPose] = field(default_factory=dict)
    target: np.ndarray | None = None
    piece_labels: np.ndarray | None = None

    def __post_init__(self) -> None:
        x = np.array(self.particles, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
            raise ValueError(f"particles must have shape (N, 3), got {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError("particles hold non-finite positions")
        object.__setattr__(self, "particles", _read_only(x))
        poses = {}
        for name, pose in dict(self.tool_poses).items():
            if not isinstance(pose, ToolPose):
                raise TypeError(f"tool_poses[{name!r}] must be a ToolPose, got {type(pose).__name__}")
            poses[name] = pose
        object.__setattr__(self, "tool_poses", MappingProxyType(poses))
        if self.target is not None:
            t = np.array(self.target, dtype=np.float32)
            if t.ndim != 2 or t.shape[1] != 3:
                raise ValueError(f"target must have shape (M, 3), got {t.shape}")
            object.__setattr__(self, "target", _read_only(t))
        if self.piece_labels is not None:
            labels = np.array(self.piece_labels, dtype=np.int32).reshape(-1)
            if labels.shape != (len(x),):
                raise ValueError(f"piece_labels must have shape ({len(x)},), got {labels.shape}")
            object.__setattr__(self, "piece_labels", _read_only(labels))

    @property
    def n_particles(self) -> int:
        return len(self.particles)

    def with_tool_pose(self, name: str, pos=None, rot=None, gap=None) -> DoughConfiguration:
        """A copy with one tool's pose changed (unspecified parts kept, or taken as identity / 0)."""
        old = self.tool_poses.get(name)
        pose = ToolPose(
            pos=pos if pos is not None else (old.pos if old else (0.0, 0.0, 0.0)),
            rot=rot if rot is not None else (old.rot if old else (1.0, 0.0, 0.0, 0.0)),
            gap=gap if gap is not None else (old.gap if old else 0.0),
        )
        return replace(self, tool_poses={**self.tool_poses, name: pose})

    def with_target(self, target: np.ndarray | None) -> DoughConfiguration:
        return replace(self, target=target)


@dataclass(frozen=True, eq=False)
class Observation:
    """Point-cloud observation (env_spec 3.1), all in the world frame; arrays are read-only.

    ``dough_points`` (observation_points, 3): the first particles, a fixed index set.
    ``tool_points``: tool name -> (tool_points, 3) surface points.
    ``tool_states`` (n_tools, 8): position, quaternion (w first), gap.
    ``target_points`` (observation_points, 3) or None: the first points of the target.
    ``step``: environment steps taken since reset.
    """

    dough_points: np.ndarray
    tool_points: Mapping[str, np.ndarray]
    tool_states: np.ndarray
    step: int
    target_points: np.ndarray | None = None


class DoughEnv:
    """One task's environment. Subclasses set ``task_names`` and ``_default_configuration``.

    Args:
        cfg: the resolved task configuration.
        differentiable: build the simulator with gradient fields (for trajectory optimisation).
    """

    task_names: ClassVar[tuple[str, ...]] = ()

    def __init__(self, cfg: TaskConfig, differentiable: bool = False):
        if self.task_names and cfg.task not in self.task_names:
            raise ValueError(f"{type(self).__name__} serves tasks {self.task_names}, got {cfg.task!r}")
        self.cfg = cfg
        self.differentiable = differentiable
        self.tools: tuple[ToolConfig, ...] = cfg.tools
        self.tool_names: tuple[str, ...] = tuple(t.name for t in cfg.tools)
        self._tool_index = {name: k for k, name in enumerate(self.tool_names)}
        self._stash: dict[str, np.ndarray] | None = None
        self._ready = False
        self._action_logs: list[list[np.ndarray]] = []  # open logging_actions() blocks
        self._simulator: MPMSimulator = simulator_for(cfg.sim, cfg.tools, differentiable=differentiable)
        self._sim()  # claim it: stash the previous owner's state, apply this task's parameters
        self._local_points: dict[str, ToolPointSet] = {
            t.name: local_tool_points(t, cfg.sim.tool_points) for t in cfg.tools
        }
        sim = self._simulator
        bounds = [*sim.action_offsets, sim.action_dim]
        self._action_slices = {
            name: slice(bounds[k], bounds[k + 1]) for k, name in enumerate(self.tool_names)
        }
        self._step = 0
        self._target: np.ndarray | None = None

    # ------------------------------------------------------------- properties
    @property
    def task(self) -> str:
        return self.cfg.task

    @property
    def horizon(self) -> int:
        """Skills per episode (CRS-Twice: 6)."""
        return self.cfg.horizon

    @property
    def skills(self) -> tuple[SkillConfig, ...]:
        return self.cfg.skills

    @property
    def simulator(self) -> MPMSimulator:
        """The simulator holding this environment's state (for gradient-based optimisation)."""
        return self._require_reset()

    @property
    def action_dim(self) -> int:
        return self._simulator.action_dim

    @property
    def n_particles(self) -> int:
        return self._simulator.n

    @property
    def step_count(self) -> int:
        """Environment steps taken since the last reset (or restored by ``set_state``)."""
        return self._step

    @property
    def target(self) -> np.ndarray | None:
        return self._target

    @property
    def floor_y(self) -> float:
        return floor_height(self.cfg.sim)

    def tool(self, name: str) -> ToolConfig:
        return self.tools[self._index(name)]

    def back_pose(self, name: str) -> ToolPose:
        """The tool's configured pose (where it is teleported back to between skills)."""
        return ToolPose.from_tool(self.tool(name))

    def tool_action_slice(self, tool_name: str) -> slice:
        """Where a tool's action dims sit in the full action vector."""
        self._index(tool_name)
        return self._action_slices[tool_name]

    def action_for(self, tool_name: str, tool_action: Sequence[float]) -> np.ndarray:
        """A full action (action_dim,) moving only ``tool_name`` (every other dim 0)."""
        s = self.tool_action_slice(tool_name)
        values = np.asarray(tool_action, dtype=np.float32).reshape(-1)
        if values.size != s.stop - s.start:
            raise ValueError(f"tool {tool_name!r} takes {s.stop - s.start} action values, got {values.size}")
        action = np.zeros(self.action_dim, np.float32)
        action[s] = values
        return action

    def _index(self, name: str) -> int:
        try:
            return self._tool_index[name]
        except KeyError:
            raise KeyError(f"unknown tool {name!r}; this task's tools are {list(self.tool_names)}") from None

    # -------------------------------------------------------------- simulator
    def _sim(self) -> MPMSimulator:
        """The simulator, holding this environment's state and runtime parameters."""
        key = id(self._simulator)
        ref = _OWNERS.get(key)
        owner = ref() if ref is not None else None
        if owner is not self:
            if owner is not None and owner._ready and owner._stash is None:
                owner._stash = owner._simulator.get_state()
            simulator_for(self.cfg.sim, self.cfg.tools, differentiable=self.differentiable)
            self._simulator.set_material(self.cfg.material)
            if self._stash is not None:
                self._simulator.set_state(self._stash)
                self._stash = None
            _OWNERS[key] = weakref.ref(self)
        return self._simulator

    def _require_reset(self) -> MPMSimulator:
        if not self._ready:
            raise RuntimeError(f"{type(self).__name__}: call reset() before using the environment")
        return self._sim()

    # ------------------------------------------------------------ episode API
    def default_configuration(self, rng: np.random.Generator) -> DoughConfiguration:
        """A sensible initial configuration of this task (see the task module)."""
        return self._default_configuration(self.cfg, rng)

    @staticmethod
    def _default_configuration(cfg: TaskConfig, rng: np.random.Generator) -> DoughConfiguration:
        raise NotImplementedError

    def reset(self, configuration: DoughConfiguration) -> Observation:
        """Start an episode: particles at rest (v = 0, C = 0, F = I), tools at their poses."""
        if not isinstance(configuration, DoughConfiguration):
            raise TypeError(f"reset needs a DoughConfiguration, got {type(configuration).__name__}")
        if configuration.n_particles != self.n_particles:
            raise ValueError(
                f"configuration has {configuration.n_particles} particles, this environment simulates "
                f"{self.n_particles} (cfg.sim.n_particles)"
            )
        unknown = set(configuration.tool_poses) - set(self.tool_names)
        if unknown:
            raise ValueError(
                f"configuration poses unknown tools {sorted(unknown)}; tools are {list(self.tool_names)}"
            )
        poses = [configuration.tool_poses.get(t.name) or ToolPose.from_tool(t) for t in self.tools]
        for tool, pose in zip(self.tools, poses, strict=True):
            self._check_gap(tool, pose.gap)
        x = np.array(configuration.particles, dtype=np.float32)
        n = len(x)
        state = {
            "x": x,
            "v": np.zeros((n, 3), np.float32),
            "C": np.zeros((n, 3, 3), np.float32),
            "F": np.ascontiguousarray(np.broadcast_to(np.eye(3, dtype=np.float32), (n, 3, 3))),
            "tool_pos": np.array([p.pos for p in poses], np.float32).reshape(len(poses), 3),
            "tool_rot": np.array([p.rot for p in poses], np.float32).reshape(len(poses), 4),
            "tool_gap": np.array([p.gap for p in poses], np.float32).reshape(len(poses)),
        }
        self._stash = None
        self._sim().set_state(state)
        self._target = configuration.target
        self._step = 0
        self._ready = True
        return self.observation()

    def _check_gap(self, tool: ToolConfig, gap: float) -> None:
        if tool.kind == "gripper" and not tool.min_gap - 1e-6 <= gap <= tool.max_gap + 1e-6:
            raise ValueError(f"gripper {tool.name!r}: gap {gap} outside [{tool.min_gap}, {tool.max_gap}]")

    def check_action(self, action: Any) -> np.ndarray:
        """Validate an action: (action_dim,), finite, in [-1, 1]. Errors name the step, value and tool."""
        where = f"step {self._step}"
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ActionError(f"{where}: action {action!r} is not numeric ({exc})") from None
        a = a.reshape(-1)
        if a.size != self.action_dim:
            raise ActionError(f"{where}: action has {a.size} values, expected {self.action_dim}")
        bad = ~np.isfinite(a) | (np.abs(a) > 1.0)
        if bad.any():
            i = int(np.argmax(bad))
            tool = next(name for name, s in self._action_slices.items() if s.start <= i < s.stop)
            problem = "is not finite" if not np.isfinite(a[i]) else "is outside [-1, 1]"
            raise ActionError(
                f"{where}: action value {a[i]!r} at index {i} (tool {tool!r}, dim "
                f"{i - self._action_slices[tool].start}) {problem}"
            )
        return a.astype(np.float32)

    def step(self, action: Any) -> Observation:
        """Advance one environment step under ``action`` (action_dim,) in [-1, 1]."""
        sim = self._require_reset()
        a = self.check_action(action)
        for log in self._action_logs:
            log.append(a.copy())
        sim.step(a, step=self._step)
        self._step += 1
        return self.observation()

    @contextlib.contextmanager
    def logging_actions(self) -> Iterator[list[np.ndarray]]:
        """Within the block, every action :meth:`step` takes, checked and float32 (A,), is appended to the
        yielded list, before it is simulated (so a step that raises is in it)."""
        log: list[np.ndarray] = []
        self._action_logs.append(log)
        try:
            yield log
        finally:
            self._action_logs.remove(log)

    def settle(self, n_steps: int | None = None) -> Observation:
        """Run ``n_steps`` (default ``cfg.sim.settle_steps``) steps with zero action."""
        self._require_reset()
        n = self.cfg.sim.settle_steps if n_steps is None else int(n_steps)
        if n < 0:
            raise ValueError(f"n_steps must be >= 0, got {n_steps}")
        zero = np.zeros(self.action_dim, np.float32)
        for _ in range(n):
            self.step(zero)
        return self.observation()

    def particles(self) -> np.ndarray:
        """All particle positions (N, 3) float32 (a copy)."""
        return self._require_reset().read_particles(0)["x"]

    def tool_poses(self) -> dict[str, ToolPose]:
        """Every tool's current pose."""
        tools = self._require_reset().read_tools(0)
        return {
            name: ToolPose(pos=tools["pos"][k], rot=tools["rot"][k], gap=max(float(tools["gap"][k]), 0.0))
            for k, name in enumerate(self.tool_names)
        }

    def observation(self) -> Observation:
        """The current point-cloud observation."""
        sim = self._require_reset()
        m = self.cfg.sim.observation_points
        x = sim.read_particles(0)["x"]
        tools = sim.read_tools(0)
        states = np.concatenate([tools["pos"], tools["rot"], tools["gap"][:, None]], axis=1)
        points = {
            name: _read_only(tool_points_world(self._local_points[name], pos, rot, float(gap)))
            for name, pos, rot, gap in zip(
                self.tool_names, tools["pos"], tools["rot"], tools["gap"], strict=True
            )
        }
        target = None if self._target is None else _read_only(np.array(self._target[:m], np.float32))
        return Observation(
            dough_points=_read_only(np.ascontiguousarray(x[:m])),
            tool_points=MappingProxyType(points),
            tool_states=_read_only(states.astype(np.float32).reshape(len(self.tool_names), 8)),
            step=self._step,
            target_points=target,
        )

    # ------------------------------------------------------------- state I/O
    def get_state(self) -> dict[str, Any]:
        """Everything needed to resume: x, v, C, F, tool_pos, tool_rot, tool_gap (float32 copies) and step."""
        state: dict[str, Any] = self._require_reset().get_state()
        state["step"] = self._step
        return state

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore a state from :meth:`get_state` exactly (the step counter too)."""
        missing = [k for k in (*STATE_KEYS, "step") if k not in state]
        if missing:
            raise KeyError(f"state lacks {missing}; get_state() gives {[*STATE_KEYS, 'step']}")
        self._stash = None
        self._sim().set_state({k: state[k] for k in STATE_KEYS})
        self._step = int(state["step"])
        self._ready = True

    def teleport_tool(self, name: str, pos: Sequence[float], rot: Sequence[float] | None = None,
                      gap: float | None = None) -> Observation:
        """Put a tool at a pose without simulating (between skills, env_spec 2.5).

        ``rot`` and ``gap`` default to the current ones. The position is clipped to the tool's
        bounds and the gap to [min_gap, max_gap], as the engine does when stepping.
        """
        sim = self._require_reset()
        k = self._index(name)
        tool = self.tools[k]
        state = sim.get_state()
        pos_arr = np.asarray(pos, dtype=np.float64).reshape(-1)
        if pos_arr.shape != (3,) or not np.isfinite(pos_arr).all():
            raise ValueError(f"teleport_tool({name!r}): position must be 3 finite numbers, got {pos!r}")
        state["tool_pos"][k] = np.clip(pos_arr, tool.lower_bound, tool.upper_bound)
        if rot is not None:
            state["tool_rot"][k] = _unit_quaternion(rot, f"teleport_tool({name!r})")
        if gap is not None:
            if not math.isfinite(float(gap)):
                raise ValueError(f"teleport_tool({name!r}): gap must be finite, got {gap!r}")
            g = float(gap)
            if tool.kind == "gripper":
                g = float(np.clip(g, tool.min_gap, tool.max_gap))
            state["tool_gap"][k] = g
        sim.set_state(state)
        return self.observation()


# ------------------------------------------------------------ configurations
def occupied_tool_footprints(cfg: TaskConfig, poses: Mapping[str, ToolPose], below_y: float
                             ) -> list[tuple[np.ndarray, np.ndarray]]:
    """x-z rectangles of the tools that are static or reach below ``below_y`` (no distractors there)."""
    rects = []
    for tool in cfg.tools:
        pose = poses.get(tool.name) or ToolPose.from_tool(tool)
        lo, hi = tool_world_bounds(tool, pose.pos, pose.rot, pose.gap)
        if tool.static or lo[1] < below_y:
            rects.append((lo[[0, 2]], hi[[0, 2]]))
    return rects


def build_configuration(
    cfg: TaskConfig,
    rng: np.random.Generator,
    main_pieces: Sequence[Piece],
    tool_poses: Mapping[str, ToolPose] | None = None,
    target: np.ndarray | None = None,
    distractors: int | None = None,
) -> DoughConfiguration:
    """Sample a configuration: the main pieces plus ``distractors`` (default ``cfg.distractors``).

    Distractors are small boxes on the floor, clear of the main pieces and of every tool that is
    static or reaches near the floor (:func:`pasta.sim.shapes.place_distractors`). The particle
    budget ``cfg.sim.n_particles`` is split between all pieces by volume, and particles are
    shuffled so the observation's first particles sample every piece.
    """
    poses = {t.name: ToolPose.from_tool(t) for t in cfg.tools}
    poses.update(tool_poses or {})
    count = cfg.distractors if distractors is None else distractors
    pieces = list(main_pieces)
    if count:
        floor = floor_height(cfg.sim)
        occupied = [(lo[[0, 2]], hi[[0, 2]]) for lo, hi in (p.bounds() for p in main_pieces)]
        occupied += occupied_tool_footprints(cfg, poses, below_y=floor + 0.1)
        wall = cfg.sim.boundary_cells / cfg.sim.n_grid + 0.02
        pieces += place_distractors(
            rng, count, occupied, floor, sum(p.volume for p in main_pieces),
            region_xz=((wall, wall), (1.0 - wall, 1.0 - wall)),
        )
    points, labels = sample_pieces(rng, pieces, cfg.sim.n_particles)
    return DoughConfiguration(particles=points, tool_poses=poses, target=target, piece_labels=labels)
