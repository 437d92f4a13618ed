"""Task environments on the MLS-MPM simulator.

``make_env(cfg)`` builds the environment of ``cfg.task``:

=============  ===========================  ==========================================
task           module                       skills (tool, pieces in -> out)
=============  ===========================  ==========================================
LiftSpread     :mod:`.lift_spread`          lift (spatula, 1->1), spread (rolling pin, 1->1)
GatherMove     :mod:`.gather_move`          gather (gripper, scattered->1), move (spatula, 1->1)
CutRearrange   :mod:`.cut_rearrange`        cut (knife, 1->2), rearrange (gripper, 1->1)
CRS            :mod:`.crs`                  cut (knife, 1->2), push (pusher, 1->1), spread (roller, 1->1)
CRS-Twice      :mod:`.crs` (horizon 6)      as CRS, twice
=============  ===========================  ==========================================

The official code defined PASTA skills only for CutRearrange and CRS; the LiftSpread and
GatherMove skill definitions are ours.
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.sim.envs.base import DoughConfiguration, DoughEnv, Observation, ToolPose, build_configuration
from pasta.sim.envs.crs import CRSEnv
from pasta.sim.envs.cut_rearrange import CutRearrangeEnv
from pasta.sim.envs.gather_move import GatherMoveEnv
from pasta.sim.envs.lift_spread import LiftSpreadEnv

ENV_CLASSES: dict[str, type[DoughEnv]] = {
    "LiftSpread": LiftSpreadEnv,
    "GatherMove": GatherMoveEnv,
    "CutRearrange": CutRearrangeEnv,
    "CRS": CRSEnv,
    "CRS-Twice": CRSEnv,
}


def make_env(cfg: TaskConfig, differentiable: bool = False) -> DoughEnv:
    """The environment of ``cfg.task`` (simulator shared per process by compile-time layout)."""
    try:
        cls = ENV_CLASSES[cfg.task]
    except KeyError:
        raise ValueError(f"no environment for task {cfg.task!r}; known: {sorted(ENV_CLASSES)}") from None
    return cls(cfg, differentiable=differentiable)


def default_configuration(cfg: TaskConfig, rng: np.random.Generator) -> DoughConfiguration:
    """The task's default initial configuration, without building an environment."""
    try:
        cls = ENV_CLASSES[cfg.task]
    except KeyError:
        raise ValueError(f"no environment for task {cfg.task!r}; known: {sorted(ENV_CLASSES)}") from None
    return cls._default_configuration(cfg, rng)


__all__ = [
    "ENV_CLASSES",
    "CRSEnv",
    "CutRearrangeEnv",
    "DoughConfiguration",
    "DoughEnv",
    "GatherMoveEnv",
    "LiftSpreadEnv",
    "Observation",
    "ToolPose",
    "build_configuration",
    "default_configuration",
    "make_env",
]
