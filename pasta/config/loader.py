"""Resolve a :class:`TaskConfig` from ``conf/``: task YAML -> profile YAML -> overrides.

* ``conf/tasks/<task>.yaml`` holds a task's native (paper-scale) values. A task file may start
  with ``inherit: <other task>``: the other task's file is loaded first and this one is merged
  over it (mappings merge key by key; lists such as ``tools`` and ``skills`` are replaced whole).
* ``conf/profiles/<profile>.yaml`` holds a ``scale:`` block of factors (see ``SCALED_FIELDS``)
  that multiply the task's counts, and any override tree (``sim:``, ``train:``, ...) applied to
  every task. The factors are applied to the task's values first; the profile's explicit values
  are merged afterwards, so they win over scaled ones. Scaled counts are rounded half up and
  never drop below 1. A ``tasks:`` block maps a task name to an override tree for that task alone
  (``tasks: {CRS-Twice: {plan: {receding_horizon: 6}}}``), merged after the profile's own trees.
  In a profile, ``tools`` and ``skills`` may also be mappings from entry names to fields, which change
  those entries alone (``tools: {knife: {blade_angle_deg: 40}}``).
* ``overrides`` are dotted keys, either ``{"sim.n_grid": 40}`` or ``["sim.n_grid=40"]`` (values
  of the string form are parsed with ``yaml.safe_load``). Entries of ``tools`` and ``skills`` are
  selected by name or index (``tools.knife.friction=0.5``). ``scale.<factor>=<value>`` replaces
  one of the profile's factors before it is applied.

Every problem raises :class:`ConfigError` naming the bad key or value and the allowed ones.
The ``conf/`` directory is ``$PASTA_CONF_DIR`` or ``<repo root>/conf``.
"""

from __future__ import annotations

import copy
import difflib
import math
import os
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError
from pydantic.fields import FieldInfo

from pasta.config.schema import PROFILE_NAMES, TASK_NAMES, TaskConfig
from pasta.paths import REPO_ROOT

# Which values each profile scale factor multiplies, as (section, key).
SCALED_FIELDS: dict[str, tuple[tuple[str, str], ...]] = {
    "data": (
        ("data", "n_initial_configs"),
        ("data", "n_target_configs"),
        ("data", "n_train_trajectories"),
        ("data", "n_test_trajectories"),
    ),
    "gbto_iterations": (("data", "gbto_iterations"),),
    "epochs": (("train", "vae_epochs"), ("train", "epochs")),
    "plan_samples": (("plan", "samples"),),
    "plan_iterations": (("plan", "iterations"),),
}
SCALE_KEYS = tuple(SCALED_FIELDS)

# Chosen by load()'s arguments; no YAML layer or override may set them.
_RESERVED = ("task", "profile")


class ConfigError(ValueError):
    """A configuration problem; the message names the bad key or value and the allowed ones."""


# ----------------------------------------------------------------------------------------------
# public entry points


def conf_dir() -> Path:
    """The configuration directory: ``$PASTA_CONF_DIR`` or ``<repo root>/conf``."""
    env = os.environ.get("PASTA_CONF_DIR")
    path = Path(env).expanduser() if env else REPO_ROOT / "conf"
    if not path.is_dir():
        raise ConfigError(
            f"configuration directory {path} not found; set PASTA_CONF_DIR to a folder holding "
            "tasks/ and profiles/"
        )
    return path


def load(
    task: str,
    profile: str = "smoke",
    overrides: Mapping[str, Any] | Sequence[str] | None = None,
) -> TaskConfig:
    """Resolve one task at one profile, with optional dotted-key overrides."""
    root = conf_dir()
    tree = _task_tree(task, root, ())
    scale, profile_tree, per_task = _profile_tree(profile, root)
    items = _parse_overrides(overrides)

    rest: list[tuple[str, Any]] = []
    for key, value in items:
        if key.split(".")[0] == "scale":
            _override_scale(scale, key, value)
        else:
            rest.append((key, value))

    _apply_scale(tree, scale)
    where = f" in profile {profile!r} ({root / 'profiles' / f'{profile}.yaml'})"
    tree = _merge_layer(tree, profile_tree, where)
    tree = _merge_layer(tree, per_task.get(task, {}), where)
    for key, value in rest:
        _override(tree, key, value)
    tree["task"] = task
    tree["profile"] = profile

    try:
        return TaskConfig.model_validate(tree)
    except ValidationError as err:
        raise ConfigError(_translate(err, tree, task, profile)) from None


class _Dumper(yaml.SafeDumper):
    """Block-style mappings; lists of scalars (vectors, seeds) on one line."""


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = all(not isinstance(item, list | dict) for item in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_Dumper.add_representer(list, _represent_list)


def to_yaml(cfg: BaseModel) -> str:
    """A resolved config as YAML (the form logged to MLflow and printed by ``pasta config``)."""
    return yaml.dump(cfg.model_dump(mode="json"), Dumper=_Dumper, sort_keys=False)


# ----------------------------------------------------------------------------------------------
# layers


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise ConfigError(f"cannot parse {path}: {err}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path} must hold a mapping at top level, got {type(data).__name__}")
    return data


def _task_tree(task: str, root: Path, chain: tuple[str, ...]) -> dict[str, Any]:
    if task not in TASK_NAMES:
        raise ConfigError(
            f"unknown task {task!r}{_did_you_mean(task, TASK_NAMES)}; tasks: {', '.join(TASK_NAMES)}"
        )
    if task in chain:
        raise ConfigError(f"inherit cycle in task files: {' -> '.join((*chain, task))}")
    path = root / "tasks" / f"{task}.yaml"
    if not path.is_file():
        raise ConfigError(f"task {task!r} has no file {path}")
    tree = _read_yaml(path)
    where = f" in {path}"
    parent = tree.pop("inherit", None)
    if "profile" in tree:
        raise ConfigError(
            f"'profile' may not be set{where}; it is chosen at load time: {', '.join(PROFILE_NAMES)}"
        )
    if tree.get("task", task) != task:
        raise ConfigError(f"task: {tree['task']!r}{where} must match the file name, {task!r}")
    _check_keys(tree, TaskConfig, where, "", exclude=("profile",))
    if parent is not None:
        if parent not in TASK_NAMES:
            raise ConfigError(f"inherit: {parent!r}{where} is not a task; tasks: {', '.join(TASK_NAMES)}")
        tree = _merge(_task_tree(parent, root, (*chain, task)), tree)
    return tree


def _profile_tree(profile: str, root: Path) -> tuple[dict[str, float], dict[str, Any], dict[str, dict[str, Any]]]:
    if profile not in PROFILE_NAMES:
        raise ConfigError(
            f"unknown profile {profile!r}{_did_you_mean(profile, PROFILE_NAMES)}; "
            f"profiles: {', '.join(PROFILE_NAMES)}"
        )
    path = root / "profiles" / f"{profile}.yaml"
    if not path.is_file():
        raise ConfigError(f"profile {profile!r} has no file {path}")
    tree = _read_yaml(path)
    where = f" in {path}"
    scale = tree.pop("scale", None) or {}
    if not isinstance(scale, Mapping):
        raise ConfigError(f"scale{where} must be a mapping of factors ({', '.join(SCALE_KEYS)})")
    for key, value in scale.items():
        _check_scale(key, value, where)
    per_task = tree.pop("tasks", None) or {}
    if not isinstance(per_task, Mapping):
        raise ConfigError(f"tasks{where} must map task names to override trees")
    for name, overrides in per_task.items():
        if name not in TASK_NAMES:
            raise ConfigError(f"tasks.{name}{where} is not a task{_did_you_mean(str(name), TASK_NAMES)}; "
                              f"tasks: {', '.join(TASK_NAMES)}")
        if not isinstance(overrides, Mapping):
            raise ConfigError(f"tasks.{name}{where} must be a mapping of overrides")
        _check_keys(overrides, TaskConfig, where, f"tasks.{name}", exclude=_RESERVED)
    _check_keys(tree, TaskConfig, where, "", exclude=_RESERVED, also=("scale", "tasks"))
    return dict(scale), tree, {name: dict(overrides) for name, overrides in per_task.items()}


def _check_scale(key: Any, value: Any, where: str) -> None:
    if key not in SCALE_KEYS:
        raise ConfigError(
            f"unknown scale factor 'scale.{key}'{where}{_did_you_mean(str(key), SCALE_KEYS)}; "
            f"valid factors: {', '.join(SCALE_KEYS)}"
        )
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if not number or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"scale.{key} = {value!r}{where} is out of range: must be a number > 0")


def _apply_scale(tree: dict[str, Any], scale: Mapping[str, float]) -> None:
    for factor_name, targets in SCALED_FIELDS.items():
        factor = scale.get(factor_name, 1.0)
        for section, key in targets:
            values = tree.get(section)
            if not isinstance(values, dict):
                continue
            value = values.get(key)
            if isinstance(value, int) and not isinstance(value, bool):
                values[key] = max(1, math.floor(value * factor + 0.5))


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Deep-merge ``over`` into a copy of ``base``; mappings merge, everything else is replaced."""
    out = copy.deepcopy(dict(base))
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _merge_layer(tree: dict[str, Any], layer: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Merge a profile's override tree into a task's. ``tools`` or ``skills`` given as a mapping from entry
    names to fields change those entries alone (``tools: {knife: {blade_angle_deg: 40}}``); as a list they
    replace the task's list, as in a task file."""
    named = {key: layer[key] for key in ("tools", "skills") if isinstance(layer.get(key), Mapping)}
    tree = _merge(tree, {key: value for key, value in layer.items() if key not in named})
    for key, entries in named.items():
        for name, fields in entries.items():
            _override(tree, f"{key}.{name}", fields, where)
    return tree


# ----------------------------------------------------------------------------------------------
# schema walking


def _field_kind(annotation: Any) -> tuple[str, type[BaseModel] | None]:
    """'model' (a nested section), 'list' (a tuple of sections, e.g. tools) or 'value'."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "model", annotation
    if typing.get_origin(annotation) is tuple:
        args = typing.get_args(annotation)
        item = args[0] if len(args) == 2 and args[1] is Ellipsis else None
        if isinstance(item, type) and issubclass(item, BaseModel):
            return "list", item
    return "value", None


def _valid_keys(model: type[BaseModel], exclude: Sequence[str] = (), also: Sequence[str] = ()) -> list[str]:
    return [k for k in model.model_fields if k not in exclude] + list(also)


def _unknown_key(key: str, prefix: str, valid: Sequence[str], where: str) -> ConfigError:
    last = key.split(".")[-1]
    level = f"under '{prefix}'" if prefix else "at top level"
    return ConfigError(
        f"unknown key '{key}'{where}{_did_you_mean(last, valid)}; valid keys {level}: {', '.join(valid)}"
    )


def _did_you_mean(name: str, valid: Sequence[str]) -> str:
    close = difflib.get_close_matches(name, list(valid), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _label(item: Any, index: int) -> str:
    return str(item["name"]) if isinstance(item, Mapping) and "name" in item else str(index)


def _check_keys(
    tree: Mapping[str, Any],
    model: type[BaseModel],
    where: str,
    prefix: str,
    exclude: Sequence[str] = (),
    also: Sequence[str] = (),
) -> None:
    """Refuse keys the schema does not know, naming the valid ones at that level."""
    fields = model.model_fields
    for key, value in tree.items():
        dotted = f"{prefix}.{key}" if prefix else str(key)
        if key in also:
            continue
        if key not in fields or key in exclude:
            raise _unknown_key(dotted, prefix, _valid_keys(model, exclude, also), where)
        kind, sub = _field_kind(fields[key].annotation)
        if kind == "model" and isinstance(value, Mapping):
            _check_keys(value, sub, where, dotted)
        elif kind == "list" and isinstance(value, list):
            for i, item in enumerate(value):
                if isinstance(item, Mapping):
                    _check_keys(item, sub, where, f"{dotted}.{_label(item, i)}")
        elif kind == "list" and isinstance(value, Mapping):  # entries changed by name (a profile's layer)
            for name, item in value.items():
                if not isinstance(item, Mapping):
                    raise ConfigError(f"{dotted}.{name}{where} must be a mapping of {sub.__name__} fields, "
                                      f"got {item!r}")
                _check_keys(item, sub, where, f"{dotted}.{name}")


# ----------------------------------------------------------------------------------------------
# overrides


def _parse_overrides(overrides: Mapping[str, Any] | Sequence[str] | None) -> list[tuple[str, Any]]:
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [(str(key), value) for key, value in overrides.items()]
    if isinstance(overrides, str):
        overrides = [overrides]
    items = []
    for item in overrides:
        if not isinstance(item, str) or "=" not in item:
            raise ConfigError(f"override {item!r} must look like 'key.path=value', e.g. 'sim.n_grid=40'")
        key, _, raw = item.partition("=")
        items.append((key.strip(), _parse_value(raw.strip(), item)))
    return items


def _parse_value(raw: str, item: str) -> Any:
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as err:
        raise ConfigError(f"override {item!r}: cannot parse value {raw!r} as YAML: {err}") from None
    if isinstance(value, str):  # YAML 1.1 reads "1e-4" as a string; accept plain numbers
        for number in (int, float):
            try:
                return number(value)
            except ValueError:
                pass
    return value


def _override_scale(scale: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    if len(parts) == 1 and isinstance(value, Mapping):
        updates = dict(value)
    elif len(parts) == 2:
        updates = {parts[1]: value}
    else:
        raise ConfigError(
            f"override key {key!r}: use 'scale.<factor>=<value>' with a factor of {', '.join(SCALE_KEYS)}"
        )
    for name, factor in updates.items():
        _check_scale(name, factor, " in overrides")
    scale.update(updates)


def _override(tree: dict[str, Any], key: str, value: Any, where: str = " in overrides") -> None:
    """Set one dotted key, checking each segment against the schema (``where`` names the source in errors)."""
    path = key.split(".")
    if any(not part for part in path):
        raise ConfigError(f"override key {key!r} is malformed: expected dotted names like 'sim.n_grid'")
    if path[0] in _RESERVED:
        choices = TASK_NAMES if path[0] == "task" else PROFILE_NAMES
        raise ConfigError(
            f"'{path[0]}' cannot be overridden; pass it as the {path[0]} argument instead "
            f"(one of {', '.join(choices)})"
        )
    node: Any = tree
    model: type[BaseModel] = TaskConfig
    in_list = False
    for depth, part in enumerate(path):
        last = depth == len(path) - 1
        prefix = ".".join(path[:depth])
        if in_list:  # select an entry of tools/skills by name or index
            index = _select(node, part)
            if index is None:
                labels = [_label(item, i) for i, item in enumerate(node)]
                raise ConfigError(
                    f"override key {key!r}{where}: no entry '{part}' in '{prefix}'; "
                    f"valid entries: {', '.join(labels)} (by name or index 0..{len(node) - 1})"
                )
            if last:
                if not isinstance(value, Mapping):
                    raise ConfigError(
                        f"override {key!r} must be a mapping of {model.__name__} fields, got {value!r}"
                    )
                _check_keys(value, model, where, key)
                node[index] = _merge(node[index], value)
                return
            node, in_list = node[index], False
            continue

        fields = model.model_fields
        if part not in fields:
            also = ("scale",) if depth == 0 else ()
            raise _unknown_key(key, prefix, _valid_keys(model, _RESERVED if depth == 0 else (), also), where)
        kind, sub = _field_kind(fields[part].annotation)
        if last:
            if kind == "model" and isinstance(value, Mapping):
                _check_keys(value, sub, where, key)
                current = node.get(part)
                node[part] = _merge(current if isinstance(current, Mapping) else {}, value)
            else:
                if kind == "list" and isinstance(value, list):
                    _check_keys({part: value}, model, where, prefix)
                node[part] = value
            return
        if kind == "value":
            raise ConfigError(
                f"override key {key!r}: '{'.'.join(path[: depth + 1])}' is a value, not a section; "
                "nothing below it can be set"
            )
        child = node.get(part)
        if kind == "model":
            if not isinstance(child, dict):
                child = node[part] = {}
        elif not isinstance(child, list):
            raise ConfigError(
                f"override key {key!r}: '{'.'.join(path[: depth + 1])}' has no entries to select"
            )
        node, model, in_list = child, sub, kind == "list"


def _select(items: list[Any], part: str) -> int | None:
    for i, item in enumerate(items):
        if isinstance(item, Mapping) and item.get("name") == part:
            return i
    if part.isdigit() and int(part) < len(items):
        return int(part)
    return None


# ----------------------------------------------------------------------------------------------
# pydantic errors -> ConfigError

_RANGE_ERRORS = {"greater_than", "greater_than_equal", "less_than", "less_than_equal"}


def _schema_at(loc: Sequence[Any]) -> tuple[type[BaseModel] | None, FieldInfo | None]:
    """Walk the schema along ``loc``: (section model there or None, FieldInfo of its last key or None)."""
    model: type[BaseModel] | None = TaskConfig
    info: FieldInfo | None = None
    for part in loc:
        # an index into tools/skills keeps the entry model; an index into a vector ends the walk
        if isinstance(part, int):
            if info is None or _field_kind(info.annotation)[0] != "list":
                return None, None
            info = None
            continue
        if model is None or part not in model.model_fields:
            return None, None
        info = model.model_fields[part]
        model = _field_kind(info.annotation)[1]
    return model, info


def _dotted(loc: Sequence[Any], tree: Any) -> str:
    """``('tools', 0, 'friction')`` -> ``tools.knife.friction``; vector elements as ``[i]``."""
    text = ""
    node = tree
    for part in loc:
        if isinstance(part, int):
            item = node[part] if isinstance(node, list) and part < len(node) else None
            if isinstance(item, Mapping) and "name" in item:
                text += f".{item['name']}"
            else:
                text += f"[{part}]"
            node = item
        else:
            text += f".{part}" if text else str(part)
            node = node.get(part) if isinstance(node, Mapping) else None
    return text


def _constraint(info: FieldInfo | None) -> str | None:
    if info is None:
        return None
    parts = []
    for meta in info.metadata:
        for attr, symbol in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            bound = getattr(meta, attr, None)
            if bound is not None:
                parts.append(f"{symbol} {bound}")
    return " and ".join(parts) or None


def _translate(err: ValidationError, tree: Mapping[str, Any], task: str, profile: str) -> str:
    lines = []
    for e in err.errors():
        loc, kind, value = e["loc"], e["type"], e.get("input")
        key = _dotted(loc, tree)
        msg = e["msg"].removeprefix("Value error, ")
        if kind in _RANGE_ERRORS:
            constraint = _constraint(_schema_at(loc)[1]) or msg
            lines.append(f"{key} = {value!r} is out of range: must be {constraint}")
        elif kind == "literal_error":
            expected = e.get("ctx", {}).get("expected")
            lines.append(f"{key} = {value!r} is not allowed; allowed values: {expected}")
        elif kind == "extra_forbidden":
            owner = _schema_at(loc[:-1])[0]
            valid = f"; valid keys: {', '.join(owner.model_fields)}" if owner else ""
            lines.append(f"unknown key '{key}'{valid}")
        elif kind == "missing" and loc and isinstance(loc[-1], int):
            lines.append(f"{_dotted(loc[:-1], tree)} = {value!r} has too few values")
        elif kind == "missing":
            lines.append(f"missing required key '{key}'")
        elif key:
            lines.append(f"{key} = {value!r}: {msg}" if kind != "value_error" else f"{key}: {msg}")
        else:
            lines.append(msg)
    return f"invalid configuration for task {task!r}, profile {profile!r}:\n  - " + "\n  - ".join(lines)
