"""A small wrapper around MLflow: one place that knows run names, tags and params.

Experiments are named ``pasta/<task>``; every run carries the tags a user filters
on in the MLflow UI (``pasta.task``, ``pasta.stage``, ``pasta.profile``,
``pasta.variant``, ``pasta.seed``, ``pasta.git_commit``) and, when it is given a
config, the whole resolved config as dotted params plus ``config.json``.
Each experiment carries a description (:func:`experiment_description`) saying how to read its runs.
The library itself never imports MLflow; flows do, through this module.
"""

import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import time
from collections.abc import Iterator, Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import mlflow
import pandas as pd
from mlflow.tracking.context import registry as context_registry

from pasta.config.schema import TaskConfig
from pasta.paths import REPO_ROOT, tracking_uri

MAX_PARAM_LENGTH = 500
DESCRIPTION_TAG = "mlflow.note.content"  # the experiment description the MLflow UI shows


def configure() -> str:
    """Point MLflow at ``$MLFLOW_TRACKING_URI`` (default: the project's sqlite file); return the URI."""
    uri = tracking_uri()
    mlflow.set_tracking_uri(uri)
    return uri


def experiment_name(task: str) -> str:
    return f"pasta/{task}"


def artifact_root() -> str | None:
    """Where new experiments keep artifacts: ``$MLFLOW_ARTIFACT_ROOT``, else beside a sqlite store's file.

    MLflow's default for a database store is ``./mlruns`` in the current directory, which would
    scatter artifacts wherever a command happens to run. Other stores keep MLflow's default.
    """
    explicit = os.environ.get("MLFLOW_ARTIFACT_ROOT")
    if explicit:
        return explicit
    uri = tracking_uri()
    if uri.startswith("sqlite:///"):
        return (Path(uri[len("sqlite:///"):]).parent / "mlartifacts").resolve().as_uri()
    return None


def experiment_description(task: str) -> str:
    """What ``pasta/<task>`` holds and the tags that tell its runs apart (Markdown, shown by the MLflow UI)."""
    return (
        f"PASTA runs of the task **{task}**. Read a run by its tags:\n\n"
        "* `pasta.stage`: `data` (demonstrations), `train` (the VAE and one variant's heads), `evaluate` "
        "(one seed on the test configurations), `ablations` (a parent run grouping the Table 5 runs);\n"
        "* `pasta.profile`: `smoke`, `small` or `paper`; `pasta.seed`: the seed;\n"
        "* `pasta.variant`: `pasta`, an ablation or `flat3d` (for data runs: the demo method, `gbto` or "
        "`scripted`);\n"
        "* `pasta.experiment`: what an evaluation belongs to: `main`, `oracle_plan`, `ablation` or "
        "`sweep_<name>` (its point in `pasta.sweep_value`);\n"
        "* `pasta.plan`: `learned` (planned with the trained networks) or `oracle` (the generator's subgoals); "
        "`pasta.executor`: `policy` (learned policies) or `scripted` skills;\n"
        "* `pasta.config_hash`: runs with equal hashes used the same resolved config (`config.json`).\n\n"
        f"`pasta report --task {task}` rebuilds the report from these runs."
    )


def use_experiment(task: str) -> str:
    """Make ``pasta/<task>`` the active experiment, creating it with ``artifact_root()`` and its description;
    returns its id."""
    name = experiment_name(task)
    client = mlflow.MlflowClient()
    existing = client.get_experiment_by_name(name)
    if existing is None:
        root = artifact_root()
        location = f"{root}/{name.replace('/', '_')}" if root else None
        try:
            client.create_experiment(name, artifact_location=location,
                                     tags={DESCRIPTION_TAG: experiment_description(task)})
        except mlflow.exceptions.MlflowException:
            if client.get_experiment_by_name(name) is None:  # not a lost race with another process
                raise
        hide_empty_default_experiment(client)
    elif DESCRIPTION_TAG not in existing.tags:  # made before experiments had descriptions
        client.set_experiment_tag(existing.experiment_id, DESCRIPTION_TAG, experiment_description(task))
    return mlflow.set_experiment(name).experiment_id


def hide_empty_default_experiment(client: mlflow.MlflowClient) -> None:
    """Delete MLflow's ``Default`` experiment of a sqlite store while it holds no runs (PASTA logs none there).

    MLflow creates it with every new store; deleting only marks it deleted, so MLflow does not create it
    again. Stores of other kinds (perhaps shared) are left alone.
    """
    if not tracking_uri().startswith("sqlite:"):
        return
    default = client.get_experiment_by_name("Default")
    if default is None or default.lifecycle_stage != "active":
        return
    if not client.search_runs([default.experiment_id], max_results=1):
        with contextlib.suppress(mlflow.exceptions.MlflowException):  # another process deleted it first
            client.delete_experiment(default.experiment_id)


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


# Config sections that training never reads: changing them keeps a training run's progress (flows/train.py).
TRAINING_IRRELEVANT = ("plan", "eval")


def config_hash(cfg: TaskConfig, *, without: tuple[str, ...] = ()) -> str:
    """A short, stable digest of the resolved config: runs with equal hashes ran the same settings.

    ``without`` leaves out top-level sections, e.g. ``TRAINING_IRRELEVANT`` for what training reads."""
    text = json.dumps(cfg.model_dump(mode="json", exclude=set(without)), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


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
        extra_tags: Mapping[str, str] | None = None, started_at: float | None = None) -> Iterator[mlflow.ActiveRun]:
    """Open an MLflow run in ``pasta/<task>`` with the standard tags (and the config, if given).

    ``started_at`` (``time.time()`` seconds, default now) is the run's start time: a flow that logs its work
    once it is done passes the time the work began, so the run's duration in the MLflow UI is the work's.
    The run ends when the block does.

    A run opened in another thread or process joins its parent by ``parent_run_id``: MLflow's
    active run is thread-local, so nothing relies on an ambient run.
    """
    configure()
    experiment_id = use_experiment(task)
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
    if cfg is not None:
        tags["pasta.config_hash"] = config_hash(cfg)
    if parent_run_id:
        tags["mlflow.parentRunId"] = parent_run_id
    created = mlflow.MlflowClient().create_run(
        experiment_id, start_time=round(1000 * (time.time() if started_at is None else started_at)),
        tags=context_registry.resolve_tags(tags), run_name=name)
    with mlflow.start_run(run_id=created.info.run_id, nested=parent_run_id is not None) as active:
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
    """Runs of ``pasta/<task>`` as a DataFrame, filtered by stage and ``pasta.<tag>`` values (an empty frame
    while the experiment does not exist, where ``mlflow.search_runs`` by name would warn)."""
    configure()
    experiment = mlflow.get_experiment_by_name(experiment_name(task))
    if experiment is None:
        return pd.DataFrame()
    filters = [f"tags.`pasta.{key}` = '{value}'" for key, value in tags.items()]
    if stage is not None:
        filters.append(f"tags.`pasta.stage` = '{stage}'")
    return mlflow.search_runs(experiment_ids=[experiment.experiment_id], filter_string=" and ".join(filters))


def finished_run_id(task: str, stage: str, cfg: TaskConfig, **tags: str) -> str | None:
    """The newest FINISHED run of ``stage`` with this exact config and tags, or None (what to skip on resume)."""
    runs = search_runs(task, stage, config_hash=config_hash(cfg), **tags)
    if runs.empty:
        return None
    finished = runs[runs["status"] == "FINISHED"]
    if finished.empty:
        return None
    return str(finished.sort_values("start_time", ascending=False).iloc[0]["run_id"])


def download_latest_artifact(task: str, stage: str, artifact: str, destination: str | Path, **tags: str) -> Path | None:
    """Download ``artifact`` of the newest FINISHED run of ``stage`` with these ``pasta.<tag>`` values into the
    folder ``destination`` (keeping its file name); ``None`` when there is no such run."""
    runs = search_runs(task, stage, **tags)
    if runs.empty:
        return None
    finished = runs[runs["status"] == "FINISHED"].sort_values("start_time", ascending=False)
    if finished.empty:
        return None
    run_id = str(finished.iloc[0]["run_id"])
    folder = Path(destination)
    folder.mkdir(parents=True, exist_ok=True)
    local = mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=artifact)
    target = folder / Path(artifact).name
    shutil.move(local, target)
    return target
