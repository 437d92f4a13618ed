"""The ``pasta`` command line.

    pasta config --task CutRearrange --profile smoke [--set sim.n_grid=40 ...]
    pasta sim-demo --task CutRearrange [--profile smoke] [--out DIR]

Each subcommand imports what it needs (the simulator, torch, ...) only when it runs.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from collections.abc import Sequence

from pasta.config.schema import PROFILE_NAMES, TASK_NAMES  # light: pydantic only


def _add_task_profile(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", required=True, choices=TASK_NAMES, help="task name")
    parser.add_argument(
        "--profile", default="smoke", choices=PROFILE_NAMES, help="scale profile (default: smoke)"
    )


def _cmd_config(args: argparse.Namespace) -> int:
    from pasta.config import ConfigError, load, to_yaml

    try:
        cfg = load(args.task, args.profile, args.set)
    except ConfigError as err:
        print(f"pasta config: error: {err}", file=sys.stderr)
        return 2
    sys.stdout.write(to_yaml(cfg))
    return 0


def _cmd_sim_demo(args: argparse.Namespace) -> int:
    demo = importlib.import_module("pasta.sim.demo")
    result = demo.main(task=args.task, profile=args.profile, out=args.out)
    return result if isinstance(result, int) else 0


def _cmd_data(args: argparse.Namespace) -> int:
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "90")
    data_flow = importlib.import_module("flows.data")
    summary = data_flow.run(args.task, profile=args.profile, method=args.method, workers=args.workers,
                            overrides=args.set, dask_address=args.dask_address, seed=args.seed)
    print(json.dumps(summary, indent=1))
    return 0


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
    data.add_argument("--method", default="gbto", help="gbto (scripted warm start + optimisation) or scripted")
    data.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    data.add_argument("--dask-address", default=None, help="run the demos on this Dask scheduler instead")
    data.add_argument("--seed", type=int, default=0)
    data.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    data.set_defaults(func=_cmd_data)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
