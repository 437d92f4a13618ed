"""Typed, frozen configuration: ``load(task, profile, overrides)`` resolves ``conf/`` into a
:class:`TaskConfig` (task YAML -> profile YAML -> overrides). See :mod:`pasta.config.loader`."""

from pasta.config.loader import SCALE_KEYS, ConfigError, conf_dir, load, to_yaml
from pasta.config.schema import (
    PROFILE_NAMES,
    TASK_NAMES,
    DataConfig,
    EvalConfig,
    MaterialConfig,
    PlanConfig,
    SimConfig,
    SkillConfig,
    TaskConfig,
    ToolConfig,
    TrainConfig,
)

__all__ = [
    "PROFILE_NAMES",
    "SCALE_KEYS",
    "TASK_NAMES",
    "ConfigError",
    "DataConfig",
    "EvalConfig",
    "MaterialConfig",
    "PlanConfig",
    "SimConfig",
    "SkillConfig",
    "TaskConfig",
    "ToolConfig",
    "TrainConfig",
    "conf_dir",
    "load",
    "to_yaml",
]
