"""A small wrapper around MLflow: one place that knows run names, tags and params.

Experiments are named ``pasta/<task>``; every run carries the tags a user filters
on in the MLflow UI (``pasta.task``, ``pasta.stage``, ``pasta.profile``,
``pasta.variant``, ``pasta.seed``, ``pasta.git_commit``) and, when it is given a
config, the whole resolved config as dotted params plus ``config.json``.
The library itself never imports MLflow; flows do, through this module.
"""

import contextlib
import json
import subprocess
from collections.abc import Iterator, Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import mlflow
import pandas as pd

from pasta.config.schema import TaskConfig
from pasta.paths import REPO_ROOT, tracking_uri

MAX_PARAM_LENGTH = 500


def configure() -> str:
    """Point MLflow at ``$MLFLOW_TRACKING_URI`` (default: the project's sqlite file); return the URI."""
    uri = tracking_uri()
    mlflow.set_tracking_uri(uri)
    return uri


def experiment_name(task: str) -> str:
    return f"pasta/{task}"


@lru_cache(maxsize=1)
def git_commit() -> str:
    """The checkout's commit (with ``-dirty`` when it has uncommitted changes), or ``unknown``."""
    try:
        root = REPO_ROOT
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, check=True).stdout.strip()
        return commit + ("-dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Dotted-key view of a nested mapping; sequences of mappings are keyed by index."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, f"{name}."))
        elif isinstance(value, list | tuple) and value and all(isinstance(v, Mapping) for v in value):
            for i, item in enumerate(value):
                label = item.get("name", i)
                flat.update(flatten(item, f"{name}.{label}."))
        else:
            flat[name] = str(value)[:MAX_PARAM_LENGTH]
    return flat


@contextlib.contextmanager
def run(task: str, stage: str, *, profile: str, variant: str | None = None, seed: int | None = None,
        cfg: TaskConfig | None = None, parent_run_id: str | None = None, run_name: str | None = None,
        extra_tags: Mapping[str, str] | None = None) -> Iterator[mlflow.ActiveRun]:
    """Open an MLflow run in ``pasta/<task>`` with the standard tags (and the config, if given).

    A run opened in another thread or process joins its parent by ``parent_run_id``: MLflow's
    active run is thread-local, so nothing relies on an ambient run.
    """
    configure()
    mlflow.set_experiment(experiment_name(task))
    name = run_name or "-".join(part for part in (stage, variant, None if seed is None else f"s{seed}") if part)
    tags = {
        "pasta.task": task,
        "pasta.stage": stage,
        "pasta.profile": profile,
        "pasta.variant": variant or "",
        "pasta.seed": "" if seed is None else str(seed),
        "pasta.git_commit": git_commit(),
        **(extra_tags or {}),
    }
    if parent_run_id:
        tags["mlflow.parentRunId"] = parent_run_id
    with mlflow.start_run(run_name=name, tags=tags, nested=parent_run_id is not None) as active:
        if cfg is not None:
            resolved = cfg.model_dump(mode="json")
            mlflow.log_params(flatten(resolved))
            mlflow.log_dict(resolved, "config.json")
        yield active


def log_metrics(metrics: Mapping[str, float], step: int | None = None) -> None:
    mlflow.log_metrics({k: float(v) for k, v in metrics.items()}, step=step)


def log_artifact(path: str | Path, artifact_path: str | None = None) -> None:
    mlflow.log_artifact(str(path), artifact_path=artifact_path)


def log_table(rows: list[Mapping[str, Any]], name: str) -> None:
    """A list of dicts as a JSON table artifact (``name`` ends in .json)."""
    mlflow.log_text(json.dumps(list(rows), indent=1, default=str), name)


def search_runs(task: str, stage: str | None = None, **tags: str) -> pd.DataFrame:
    """Runs of ``pasta/<task>`` as a DataFrame, filtered by stage and ``pasta.<tag>`` values."""
    configure()
    filters = [f"tags.`pasta.{key}` = '{value}'" for key, value in tags.items()]
    if stage is not None:
        filters.append(f"tags.`pasta.stage` = '{stage}'")
    return mlflow.search_runs(experiment_names=[experiment_name(task)], filter_string=" and ".join(filters))
