"""Simulations that blew up during execution, kept so that they can be replayed without the trained models.

A skill's rollout is deterministic given its start and its actions (the CPU simulator is bit-reproducible), so
a blow-up is kept as the state the skill's actions started from, every action up to and including the one that
blew up, and the resolved config. :func:`replay_blowup` rebuilds the environment and acts them again: it raises
the same :class:`pasta.sim.engine.SimulationError`, and a trace can stop at any step before it.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.data.storage import atomic_write_bytes
from pasta.paths import pasta_home
from pasta.sim.envs import make_env
from pasta.sim.envs.base import DoughEnv

BLOWUP_DIR = "blowups"


def save_blowup(cfg: TaskConfig, start: Mapping[str, Any], actions: Sequence[np.ndarray], message: str,
                folder: Path | None = None) -> Path:
    """Write ``start`` (an environment state, :meth:`DoughEnv.get_state`), ``actions`` (T, A) and the config to
    ``folder`` (default ``$PASTA_HOME/blowups``) as one ``.npz`` named by its content; returns its path."""
    folder = Path(folder) if folder is not None else pasta_home() / BLOWUP_DIR
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {f"state_{key}": np.asarray(value) for key, value in start.items()}
    arrays["actions"] = np.asarray(actions, np.float32).reshape(len(actions), -1)
    arrays["config"] = np.asarray(cfg.model_dump_json())
    arrays["message"] = np.asarray(message)
    digest = hashlib.sha256(json.dumps([cfg.model_dump_json(), message]).encode())
    digest.update(arrays["actions"].tobytes())
    path = folder / f"{cfg.task}-{digest.hexdigest()[:12]}.npz"
    atomic_write_bytes(path, lambda handle: np.savez_compressed(handle, **arrays))
    return path


def load_blowup(path: str | Path) -> tuple[TaskConfig, dict[str, np.ndarray], np.ndarray, str]:
    """The config, start state, actions (T, A) and message of a kept blow-up."""
    with np.load(path) as kept:
        cfg = TaskConfig.model_validate_json(str(kept["config"]))
        start = {key.removeprefix("state_"): kept[key] for key in kept.files if key.startswith("state_")}
        return cfg, start, kept["actions"], str(kept["message"])


def replay_blowup(path: str | Path, n_actions: int | None = None) -> DoughEnv:
    """Act a kept blow-up again from its start: all its actions (raising the same ``SimulationError``) or the first
    ``n_actions`` of them; returns the environment where it stopped."""
    cfg, start, actions, _ = load_blowup(path)
    env = make_env(cfg)
    env.set_state(start)
    for action in actions[:n_actions]:
        env.step(action)
    return env
