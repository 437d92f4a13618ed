"""What exists for a task and profile: demonstrations, trained variants and finished evaluations (``pasta status``).

:func:`gather` reads ``$PASTA_HOME`` and the MLflow store (through :mod:`pasta.tracking`) and returns plain
rows; it creates nothing, imports neither torch nor Prefect, and changes nothing. :func:`reuse_lines` says
what a ``pasta run`` of the task would keep, by the rules of ``flows/pipeline.py``: demo files on disk are
kept, a variant is not retrained when its bundle is on disk and a finished train run has the current config,
and an evaluation seed is not rerun when a finished ``main`` run of it has the current config.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

from pasta import tracking
from pasta.config import load
from pasta.config.schema import DEMO_METHODS, VARIANT_NAMES
from pasta.paths import BUNDLE_FILE, checkpoint_dir, data_dir, model_task

__all__ = ["gather", "human_age", "reuse_lines"]

TRAJECTORY_GLOB = "trajectory_*.npz"  # flows/data.py's file names


def human_age(seconds: float | None) -> str:
    """``"40 s"``, ``"3 min"``, ``"2 h"``, ``"5 d"`` (rounded down); ``"-"`` when unknown."""
    if seconds is None or math.isnan(seconds):
        return "-"
    seconds = max(0.0, seconds)
    for unit, size in (("d", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size:
            return f"{int(seconds // size)} {unit}"
    return f"{int(seconds)} s"


def _tag(run: Mapping[str, Any], name: str) -> str:
    """A ``pasta.<name>`` tag of a row of :func:`tracking.search_runs` ('' when absent)."""
    value = run.get(f"tags.pasta.{name}")
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


def _finished(task: str, stage: str, **tags: str) -> list[dict[str, Any]]:
    """The FINISHED runs of ``stage`` with these tags, newest first, as dicts."""
    runs = tracking.search_runs(task, stage, **tags)
    if runs.empty:
        return []
    finished = runs[runs["status"] == "FINISHED"].sort_values("start_time", ascending=False)
    return finished.to_dict("records")


def _age_s(run: Mapping[str, Any], now: float) -> float | None:
    """Seconds since the run ended (or started, when it has no end time)."""
    for key in ("end_time", "start_time"):
        stamp = run.get(key)
        if stamp is not None and not _missing(stamp):
            return now - stamp.timestamp()
    return None


def _missing(value: Any) -> bool:
    try:
        return bool(value != value)  # NaN and NaT
    except (TypeError, ValueError):
        return False


def _config_hash(task: str, profile: str) -> str:
    return tracking.config_hash(load(task, profile))


def demos(task: str, profile: str, now: float) -> list[dict[str, Any]]:
    """One row per demo method with trajectory files on disk or a finished data run."""
    rows = []
    root = data_dir(task, profile, create=False)
    for method in DEMO_METHODS:
        folder = root / method
        count = sum(1 for _ in folder.glob(TRAJECTORY_GLOB)) if folder.is_dir() else 0
        runs = _finished(task, "data", profile=profile, variant=method)
        if not count and not runs:
            continue
        rows.append({"method": method, "trajectories": count, "folder": str(folder),
                     "run_id": runs[0]["run_id"] if runs else None,
                     "age_s": _age_s(runs[0], now) if runs else None})
        rows[-1]["age"] = human_age(rows[-1]["age_s"])
    return rows


def trained(task: str, profile: str, now: float) -> list[dict[str, Any]]:
    """One row per variant with a bundle on disk or a finished train run; the run is the newest with the
    current config, else the newest (``current_config`` says which)."""
    current = _config_hash(task, profile)
    rows = []
    for variant in VARIANT_NAMES:
        bundle = checkpoint_dir(task, profile, variant, create=False) / BUNDLE_FILE
        runs = _finished(task, "train", profile=profile, variant=variant)
        if not bundle.is_file() and not runs:
            continue
        matching = [r for r in runs if _tag(r, "config_hash") == current]
        run = (matching or runs or [None])[0]
        age_s = _age_s(run, now) if run else None
        rows.append({"variant": variant, "bundle": str(bundle) if bundle.is_file() else None,
                     "run_id": run["run_id"] if run else None, "age_s": age_s, "age": human_age(age_s),
                     "current_config": bool(matching)})
    return rows


def evaluations(task: str, profile: str, now: float) -> list[dict[str, Any]]:
    """One row per (experiment, sweep value, variant, plan, executor, current config or not): its seeds with
    finished evaluation runs (the newest run of each seed), their run ids and ages."""
    current = _config_hash(task, profile)
    groups: dict[tuple, dict[int | str, dict[str, Any]]] = {}
    for run in _finished(task, "evaluate", profile=profile):
        key = (_tag(run, "experiment") or "-", _tag(run, "sweep_value"), _tag(run, "variant") or "-",
               _tag(run, "plan") or "learned",  # runs from before the plan tag planned with the networks
               _tag(run, "executor") or "-", _tag(run, "config_hash") == current)
        seed_text = _tag(run, "seed")
        seed: int | str = int(seed_text) if seed_text.isdigit() else seed_text
        groups.setdefault(key, {}).setdefault(seed, run)  # newest first: keep the first of each seed
    rows = []
    for key in sorted(groups, key=lambda k: (not k[5], k[0], k[1], k[2], k[3], k[4])):
        experiment, sweep_value, variant, plan, executor, is_current = key
        by_seed = groups[key]
        seeds = sorted(by_seed, key=lambda s: (isinstance(s, str), s))
        rows.append({"experiment": experiment, "sweep_value": sweep_value or None, "variant": variant, "plan": plan,
                     "executor": executor, "current_config": is_current, "seeds": seeds,
                     "run_ids": [by_seed[s]["run_id"] for s in seeds],
                     "ages_s": [_age_s(by_seed[s], now) for s in seeds]})
        rows[-1]["ages"] = [human_age(age) for age in rows[-1]["ages_s"]]
    return rows


def gather(task: str, profile: str = "smoke", now: float | None = None) -> dict[str, Any]:
    """Everything :mod:`pasta.status` knows of ``task`` at ``profile``.

    Returns ``task``, ``profile``, ``models_from`` (the task whose demonstrations and models ``task`` uses:
    CRS-Twice uses CRS's), ``demos``, ``trained`` and ``evaluations`` (lists of dicts; ages in seconds,
    ``age_s``, and for people, ``age``) and ``reuse`` (:func:`reuse_lines` for the default variant and method).
    """
    now = time.time() if now is None else now
    source = model_task(task)
    status = {"task": task, "profile": profile, "models_from": source, "demos": demos(source, profile, now),
              "trained": trained(source, profile, now), "evaluations": evaluations(task, profile, now)}
    status["reuse"] = reuse_lines(status)
    return status


def reuse_lines(status: Mapping[str, Any], variant: str = "pasta", method: str = "gbto") -> list[str]:
    """What ``pasta run --task <task> --profile <profile>`` (with this variant and demo method) would reuse."""
    task, profile = status["task"], status["profile"]
    lines = []
    demo = next((row for row in status["demos"] if row["method"] == method), None)
    count = demo["trajectories"] if demo else 0
    lines.append(f"demonstrations: {count} {method} trajectory files kept, the missing ones made" if count
                 else f"demonstrations: all made ({method})")
    model = next((row for row in status["trained"] if row["variant"] == variant), None)
    if model and model["bundle"] and model["current_config"]:
        lines.append(f"training: {variant} reused (run {model['run_id']})")
    else:
        lines.append(f"training: {variant} trained (resuming from its last checkpoint, if any)")
    seeds = list(load(task, profile).eval.seeds)
    done = {seed for row in status["evaluations"] if row["experiment"] == "main" and row["variant"] == variant
            and row["current_config"] and not row["sweep_value"] for seed in row["seeds"]}
    kept = [s for s in seeds if s in done]
    todo = [s for s in seeds if s not in done]
    lines.append("evaluation: " + "; ".join(part for part in (
        f"seeds {' '.join(map(str, kept))} reused" if kept else "",
        f"seeds {' '.join(map(str, todo))} run" if todo else "") if part))
    return lines
