"""The ``pasta`` command line.

    pasta config --task CutRearrange --profile smoke [--set sim.n_grid=40 ...]
    pasta sim-demo --task CutRearrange [--profile smoke] [--out DIR]
    pasta train --task CutRearrange [--profile smoke] [--variant pasta] [--method gbto|scripted]
    pasta report [--task CutRearrange] [--publish | --out DIR]   # default: build/reports (git-ignored)
    pasta status --task CutRearrange [--profile smoke]   # demos, trained variants, evaluations: what a run reuses
    pasta evaluate --task CutRearrange [--profile smoke] [--variant pasta] [--plan oracle] [--executor scripted]
                   [--seeds 0 1 2]

Each subcommand imports what it needs (the simulator, torch, ...) only when it runs. Every argument,
``--set`` overrides included, is checked before that: a bad value ends in one
``pasta <command>: error: ...`` line and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import re
import sys
from collections.abc import Iterator, Sequence

from pasta.config import ConfigError, load, to_yaml  # light: pydantic and yaml only
from pasta.config.schema import DEMO_METHODS, PROFILE_NAMES, TASK_NAMES, VARIANT_NAMES
from pasta.paths import published_reports_dir

SWEEP_TASKS = ("CutRearrange", "CRS")  # the tasks of flows/sweeps.py's sweep points
DEVICE_PATTERN = re.compile(r"(cpu|cuda|mps|xpu)(:\d+)?")


def positive_int(text: str) -> int:
    """An argparse type: an integer of at least 1 (a worker count)."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer of at least 1, got {text!r}")
    return value


def seed_int(text: str) -> int:
    """An argparse type: a seed, an integer of at least 0."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"a seed must be an integer of at least 0, got {text!r}")
    return value


def torch_device(text: str) -> str:
    """An argparse type: a torch device name (checked by its form, without importing torch)."""
    if not DEVICE_PATTERN.fullmatch(text):
        raise argparse.ArgumentTypeError(f"invalid device {text!r} (choose from cpu, cuda, cuda:N, mps, xpu)")
    return text


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None


def _add_task_profile(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", required=True, choices=TASK_NAMES, help="task name")
    parser.add_argument(
        "--profile", default="smoke", choices=PROFILE_NAMES, help="scale profile (default: smoke)"
    )


def _cmd_config(args: argparse.Namespace) -> int:
    sys.stdout.write(to_yaml(load(args.task, args.profile, args.set)))
    return 0


def _cmd_sim_demo(args: argparse.Namespace) -> int:
    demo = importlib.import_module("pasta.sim.demo")
    result = demo.main(task=args.task, profile=args.profile, out=args.out)
    return result if isinstance(result, int) else 0


@contextlib.contextmanager
def _prefect(args: argparse.Namespace) -> Iterator[None]:
    """Prefect's defaults, then one Prefect server for the whole command and its pool workers
    (``flows.runners.one_prefect_server``; a Dask cluster's workers are left to Prefect)."""
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "90")
    runners = importlib.import_module("flows.runners")
    with runners.one_prefect_server(enabled=getattr(args, "dask_address", None) is None):
        yield


def _cmd_data(args: argparse.Namespace) -> int:
    with _prefect(args):
        data_flow = importlib.import_module("flows.data")
        summary = data_flow.run(args.task, profile=args.profile, method=args.method, workers=args.workers,
                                overrides=args.set, dask_address=args.dask_address, seed=args.seed)
    print(json.dumps(summary, indent=1))
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    with _prefect(args):
        train_flow = importlib.import_module("flows.train")
        summary = train_flow.run(args.task, profile=args.profile, variant=args.variant, method=args.method,
                                 overrides=args.set, seed=args.seed, device=args.device)
    print(json.dumps(summary, indent=1))
    return 0


def report_out_dir(args: argparse.Namespace) -> str | None:
    """The folder ``pasta report`` writes: the published ``reports/`` with ``--publish``, ``--out``'s folder, or
    None for the flow's default (the git-ignored local folder)."""
    return str(published_reports_dir()) if args.publish else args.out


def _cmd_report(args: argparse.Namespace) -> int:
    with _prefect(args):
        report_flow = importlib.import_module("flows.report")
        paths = report_flow.run(args.task, report_out_dir(args))
    for path in paths:
        print(path)
    if not args.publish:
        print("(the published reports/ that git tracks change only with `pasta report --publish`)")
    return 0


def _cmd_status(args: argparse.Namespace) -> int:
    status = importlib.import_module("pasta.status")  # MLflow only, no Prefect, no torch
    print(status_text(status.gather(args.task, args.profile)))
    return 0


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]], indent: str = "  ") -> list[str]:
    widths = [max(len(str(cell)) for cell in column) for column in zip(headers, *rows, strict=True)]
    return [(indent + "  ".join(str(cell).ljust(width) for cell, width in zip(row, widths, strict=True))).rstrip()
            for row in (headers, *rows)]


def status_text(status: dict) -> str:
    """``pasta status``'s report of :func:`pasta.status.gather`'s rows."""
    task, profile, source = status["task"], status["profile"], status["models_from"]
    lines = [f"pasta status: {task} at profile {profile}"]
    borrowed = f" (of {source}: {task} uses {source}'s)" if source != task else ""
    lines += ["", f"Demonstrations{borrowed}"]
    if status["demos"]:
        lines += _table(("method", "trajectories", "MLflow data run", "age", "folder"),
                        [(r["method"], str(r["trajectories"]), r["run_id"] or "none", r["age"],
                          r["folder"]) for r in status["demos"]])
    else:
        lines.append(f"  nothing yet: `pasta data --task {source} --profile {profile}` makes them")
    lines += ["", f"Trained variants{borrowed}"]
    if status["trained"]:
        lines += _table(("variant", "MLflow train run", "age", "config", "bundle"),
                        [(r["variant"], r["run_id"] or "none", r["age"],
                          "current" if r["current_config"] else ("other" if r["run_id"] else "-"),
                          r["bundle"] or "not on disk") for r in status["trained"]])
    else:
        lines.append(f"  nothing yet: `pasta train --task {source} --profile {profile}` trains one")
    lines += ["", "Evaluations (finished MLflow runs)"]
    if status["evaluations"]:
        for r in status["evaluations"]:
            experiment = r["experiment"] + (f" = {r['sweep_value']}" if r["sweep_value"] else "")
            config = "current config" if r["current_config"] else "another config"
            lines.append(f"  {experiment}, variant {r['variant']}, plan {r['plan']}, executor {r['executor']} "
                         f"({config}): seeds {' '.join(map(str, r['seeds']))}")
            lines += _table(("seed", "MLflow evaluate run", "age"),
                            [(str(seed), run_id, age)
                             for seed, run_id, age in zip(r["seeds"], r["run_ids"], r["ages"], strict=True)],
                            indent="    ")
    else:
        lines.append(f"  nothing yet: `pasta evaluate --task {task} --profile {profile}` runs one")
    lines += ["", f"`pasta run --task {task} --profile {profile}` (variant pasta, gbto demos) would do:"]
    lines += [f"  {line}" for line in status["reuse"]]
    return "\n".join(lines)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    with _prefect(args):
        evaluate_flow = importlib.import_module("flows.evaluate")
        summary = evaluate_flow.run(args.task, profile=args.profile, variant=args.variant, seeds=args.seeds,
                                    executor=args.executor, overrides=args.set, experiment=args.experiment,
                                    workers=args.workers, dask_address=args.dask_address, plan_source=args.plan,
                                    sweep_value=args.sweep_value)
    print(json.dumps(summary, indent=1))
    print(json.dumps(evaluation_line(summary)))  # the last line, for scripts
    return 0


def evaluation_line(summary: dict) -> dict:
    """The one-line result of ``pasta evaluate``: what was run and its scores over seeds."""
    keys = ("task", "profile", "plan", "executor", "seeds", "performance_mean", "performance_std", "success_mean",
            "success_std")
    return {key: summary[key] for key in keys}


def _cmd_run(args: argparse.Namespace) -> int:
    with _prefect(args):
        pipeline = importlib.import_module("flows.pipeline")
        tasks = pipeline.ALL_TASKS if args.all else (args.task,)
        pipeline.run(tasks, profile=args.profile, variant=args.variant, method=args.method, workers=args.workers,
                     executor=args.executor, overrides=args.set, dask_address=args.dask_address)
    return 0


def _cmd_ablations(args: argparse.Namespace) -> int:
    with _prefect(args):
        ablations = importlib.import_module("flows.ablations")
        results = ablations.run(args.task, profile=args.profile, variants=args.variants, method=args.method,
                                workers=args.workers, executor=args.executor, overrides=args.set,
                                dask_address=args.dask_address)
    print(json.dumps(results, indent=1, default=str))
    return 0


def _cmd_sweeps(args: argparse.Namespace) -> int:
    with _prefect(args):
        sweeps = importlib.import_module("flows.sweeps")
        results = sweeps.run(profile=args.profile, only=args.only, executor=args.executor, overrides=args.set,
                             workers=args.workers, dask_address=args.dask_address, seeds=args.seeds)
    print(json.dumps(results, indent=1, default=str))
    return 0


def _add_worker_options(parser: argparse.ArgumentParser, workers: int = 2) -> None:
    parser.add_argument("--workers", type=positive_int, default=workers,
                        help=f"worker processes for the simulations: demos and evaluations (default {workers})")
    parser.add_argument("--dask-address", default=None, metavar="ADDRESS",
                        help="run the simulations on this Dask scheduler (tcp://host:8786) instead")


def _add_run_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--method", default="gbto", choices=DEMO_METHODS,
                        help="how demonstrations are made (default gbto)")
    _add_worker_options(parser)
    parser.add_argument("--executor", default="policy", choices=("policy", "scripted"),
                        help="run the planned skills with the learned policies or the scripted skills")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pasta", description="PASTA re-implementation: simulator, data, training, planning."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    config = sub.add_parser("config", help="print the resolved configuration as YAML")
    _add_task_profile(config)
    config.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a dotted key, e.g. sim.n_grid=40 or tools.knife.friction=0.5 (repeatable)",
    )
    config.set_defaults(func=_cmd_config)

    demo = sub.add_parser("sim-demo", help="run a short simulator demo of one task")
    _add_task_profile(demo)
    demo.add_argument("--out", default=None, help="output folder (default: chosen by the demo)")
    demo.set_defaults(func=_cmd_sim_demo)

    data = sub.add_parser("data", help="generate a task's demonstration dataset (Prefect flow, MLflow run)")
    _add_task_profile(data)
    data.add_argument("--method", default="gbto", choices=DEMO_METHODS,
                      help="gbto (scripted warm start + optimisation) or scripted")
    _add_worker_options(data)
    data.add_argument("--seed", type=seed_int, default=0)
    data.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    data.set_defaults(func=_cmd_data)

    train = sub.add_parser("train", help="train a task's VAE and one variant's heads (Prefect flow, MLflow run)")
    _add_task_profile(train)
    train.add_argument("--variant", default="pasta", choices=VARIANT_NAMES,
                       help="pasta, an ablation, or flat3d (default pasta)")
    train.add_argument("--method", default=None, choices=DEMO_METHODS,
                       help="dataset to read: gbto or scripted (default: gbto if present)")
    train.add_argument("--device", default=None, type=torch_device,
                       help="torch device (default: cuda when available, else cpu)")
    train.add_argument("--seed", type=seed_int, default=0)
    train.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    train.set_defaults(func=_cmd_train)

    report = sub.add_parser("report", help="rebuild the reports (tables, figures) from MLflow alone")
    report.add_argument("--task", default=None, choices=TASK_NAMES, help="one task (default: every task with runs)")
    where = report.add_mutually_exclusive_group()
    where.add_argument("--publish", action="store_true",
                       help="write the published reports/ that git tracks (replaces their figures and tables)")
    where.add_argument("--out", default=None, metavar="DIR",
                       help="write into DIR (default: $PASTA_REPORTS_DIR or build/reports, git-ignored)")
    report.set_defaults(func=_cmd_report)

    status = sub.add_parser("status", help="what exists for a task and profile (demos, trained variants, "
                                           "evaluations, their MLflow runs): what a `pasta run` would reuse")
    _add_task_profile(status)
    status.set_defaults(func=_cmd_status)

    evaluate = sub.add_parser("evaluate", help="plan and execute the 5 test configurations (Prefect flow, MLflow runs)")
    _add_task_profile(evaluate)
    evaluate.add_argument("--variant", default="pasta", choices=VARIANT_NAMES,
                          help="trained variant to evaluate (default pasta)")
    evaluate.add_argument("--plan", default="learned", choices=("learned", "oracle"),
                          help="plan with the trained networks, or take the generator's own subgoals (oracle; "
                               "with --executor scripted it needs no trained models)")
    evaluate.add_argument("--executor", default="policy", choices=("policy", "scripted"),
                          help="run the skills with the learned policies or the scripted skills")
    evaluate.add_argument("--seeds", type=seed_int, nargs="+", default=None, help="seeds (default: cfg.eval.seeds)")
    evaluate.add_argument("--experiment", default=None,
                          help="pasta.experiment tag (default main, or oracle_plan with --plan oracle)")
    evaluate.add_argument("--sweep-value", default=None,
                          help="pasta.sweep_value tag: the run's point on a sweep (e.g. the demonstrations behind "
                               "the models of the sweep_data experiment, docs/planning.md)")
    _add_worker_options(evaluate, workers=1)
    evaluate.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    evaluate.set_defaults(func=_cmd_evaluate)

    run = sub.add_parser("run", help="a task's whole pipeline: data, training, evaluation, report (resumable)")
    which = run.add_mutually_exclusive_group(required=True)
    which.add_argument("--task", default=None, choices=TASK_NAMES, help="task name")
    which.add_argument("--all", action="store_true", help="every task, one after another")
    run.add_argument("--profile", default="smoke", choices=PROFILE_NAMES, help="scale profile (default: smoke)")
    run.add_argument("--variant", default="pasta", choices=VARIANT_NAMES,
                     help="pasta, an ablation, or flat3d (default pasta)")
    _add_run_options(run)
    run.set_defaults(func=_cmd_run)

    ablations = sub.add_parser("ablations", help="Table 5: train and evaluate every variant under one parent run")
    ablations.add_argument("--task", default="CutRearrange", choices=TASK_NAMES, help="task (default CutRearrange)")
    ablations.add_argument("--profile", default="smoke", choices=PROFILE_NAMES, help="scale profile")
    ablations.add_argument("--variants", nargs="+", default=None, choices=VARIANT_NAMES,
                           help="variants (default: all six)")
    _add_run_options(ablations)
    ablations.set_defaults(func=_cmd_ablations)

    sweeps = sub.add_parser("sweeps", help="Fig. 2 samples, Table 8 horizons, CRS with distractors")
    sweeps.add_argument("--profile", default="smoke", choices=PROFILE_NAMES, help="scale profile")
    sweeps.add_argument("--only", nargs="+", default=None, choices=("samples", "horizon", "distractors"),
                        help="which sweeps (default: all)")
    sweeps.add_argument("--seeds", type=seed_int, nargs="+", default=None,
                        help="evaluation seeds of every sweep point (default: 0 1 2 3 4, as the appendix)")
    sweeps.add_argument("--executor", default="policy", choices=("policy", "scripted"),
                        help="run the planned skills with the learned policies or the scripted skills")
    _add_worker_options(sweeps)
    sweeps.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    sweeps.set_defaults(func=_cmd_sweeps)
    for command in sub.choices.values():
        command.set_defaults(parser=command)  # its errors read "pasta <command>: error: ..."
    return parser


def override_tasks(args: argparse.Namespace) -> tuple[str, ...]:
    """The tasks whose configurations a command's ``--set`` overrides must fit."""
    if args.command == "sweeps":
        return SWEEP_TASKS
    if getattr(args, "all", False):
        return TASK_NAMES
    return (args.task,)


def check_overrides(args: argparse.Namespace) -> None:
    """Refuse a bad ``--set`` with ``pasta <command>: error: ...`` (exit 2) before anything starts."""
    if not hasattr(args, "set"):
        return
    for task in override_tasks(args):
        try:
            load(task, args.profile, args.set)
        except ConfigError as err:
            args.parser.error(one_line(str(err)))


def one_line(message: str) -> str:
    """A configuration error's bulleted lines joined into one: ``head: first; second``."""
    head, *items = message.splitlines()
    return " ".join([head, "; ".join(item.strip().removeprefix("- ") for item in items)]).strip()


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    check_overrides(args)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
