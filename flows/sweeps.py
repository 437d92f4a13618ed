"""Prefect flow: the planning sweeps of the appendix's §4 (Fig. 2, Table 8, CRS with distractors).

    pasta sweeps --profile small [--only samples horizon distractors]

* ``samples``: CutRearrange planned with a fraction of the profile's samples (Fig. 2a time, Fig. 2b
  performance), 5 seeds each as the appendix (`--seeds` takes fewer).
* ``horizon``: CRS planned with horizons 3 to 6 (Table 8).
* ``distractors``: CRS with 2 extra dough pieces on the board (§4.5).

Planning time per task (Table 6) comes from the main evaluation runs (``pasta run``). Every sweep point
is an evaluation run tagged ``pasta.experiment`` and ``pasta.sweep_value``; points already finished with
the same config are skipped, so an interrupted sweep resumes.
"""

from __future__ import annotations

from collections.abc import Sequence

from prefect import flow

from flows.evaluate import evaluate
from flows.pipeline import pending_seeds
from flows.report import report
from flows.runners import check_workers
from pasta.config import load

SWEEPS = ("samples", "horizon", "distractors")
SAMPLE_FRACTIONS = (0.01, 0.05, 0.2, 0.5, 1.0)
SWEEP_SEEDS = (0, 1, 2, 3, 4)
HORIZONS = (3, 4, 5, 6)


def sample_counts(profile: str, overrides: Sequence[str] = ()) -> list[int]:
    """The sample counts of the Fig. 2 sweep: fractions of the profile's CutRearrange samples, distinct."""
    samples = load("CutRearrange", profile, list(overrides)).plan.samples
    return sorted({max(1, round(fraction * samples)) for fraction in SAMPLE_FRACTIONS})


def sweep_points(sweep: str, profile: str, overrides: Sequence[str] = ()) -> list[tuple[str, str, tuple[str, ...]]]:
    """``(task, sweep value, overrides)`` for every point of one sweep."""
    base = tuple(overrides)
    if sweep == "samples":
        return [("CutRearrange", str(n), (*base, f"plan.samples={n}")) for n in sample_counts(profile, overrides)]
    if sweep == "horizon":
        return [("CRS", str(h), (*base, f"plan.horizon={h}")) for h in HORIZONS]
    if sweep == "distractors":
        return [("CRS", "2", (*base, "distractors=2"))]
    raise ValueError(f"unknown sweep {sweep!r}; known: {', '.join(SWEEPS)}")


@flow(name="sweeps", flow_run_name="sweeps-{profile}")
def sweeps(profile: str = "smoke", only: Sequence[str] = SWEEPS, variant: str = "pasta",
           seeds: Sequence[int] = SWEEP_SEEDS, executor: str = "policy", overrides: Sequence[str] = (),
           workers: int = 2, dask_address: str | None = None) -> dict:
    """Evaluate every sweep point (the models must be trained: ``pasta run`` first).

    Each point's (seed, configuration) pairs run on a process pool of ``workers`` or on the Dask cluster at
    ``dask_address``.
    """
    results: dict[str, dict] = {}
    for sweep in only:
        experiment = f"sweep_{sweep}"
        for task_name, value, point_overrides in sweep_points(sweep, profile, overrides):
            todo = pending_seeds(task_name, profile, variant, seeds, point_overrides, experiment, value)
            results[f"{experiment}={value}"] = (
                evaluate(task_name, profile, variant, seeds=todo, executor=executor, experiment=experiment,
                         sweep_value=value, overrides=point_overrides, workers=workers, dask_address=dask_address)
                if todo else {"skipped": True})
    for task_name in sorted({task for sweep in only for task, _, _ in sweep_points(sweep, profile, overrides)}):
        report(task_name)
    return results


def run(profile: str = "smoke", only: Sequence[str] | None = None, executor: str = "policy",
        overrides: Sequence[str] = (), workers: int = 2, dask_address: str | None = None,
        seeds: Sequence[int] | None = None) -> dict:
    """The CLI's entry point: check the sweep names and configs, then run :func:`sweeps` (``seeds`` None:
    :data:`SWEEP_SEEDS`)."""
    check_workers(workers)
    chosen = tuple(SWEEPS if only is None else only)
    for sweep in chosen:
        for task_name, _, point_overrides in sweep_points(sweep, profile, overrides):
            load(task_name, profile, list(point_overrides))
    return sweeps(profile, chosen, seeds=tuple(SWEEP_SEEDS if seeds is None else seeds), executor=executor,
                  overrides=tuple(overrides), workers=workers, dask_address=dask_address)
