"""Skill quality: single-skill scripted demos per task and skill, and the oracle plan run by the scripted skills.

For each task, ``--demos`` single-skill problems per skill (the task's training generator, ids in schedule
order) are run as ``pasta data --method scripted`` runs them (:func:`pasta.data.demos.generate_demo`: reset,
settle, place the tool, act, score the last frame). Each demo also gets its sampling-floor cap
``(EMD_initial - floor) / EMD_initial``, where ``floor`` is the EMD between two disjoint 1000-point halves of
the target's particles (two independent samples of the same shape): no execution scores above it. Then the
task's test configurations are evaluated with the oracle plan and the scripted skills
(:func:`pasta.evaluate.problem.evaluate_problem`, ``plan_source="oracle"``) for each ``--seeds`` seed.

Prints a table per part (median and 10th percentile of the normalised performance, the median cap, seconds per
demo) with the machine's load average, and writes JSON to ``benchmarks/results/skills_<profile>.json``.

    python benchmarks/skills.py                                  # small, 10 demos per skill, seed 0
    python benchmarks/skills.py --tasks GatherMove --demos 3 --seeds 0 1 2
"""

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from pasta.config import load
from pasta.config.schema import TASK_NAMES
from pasta.data.configurations import evaluation_problem, skill_problem, skill_schedule
from pasta.data.demos import generate_demo, shape_distance
from pasta.evaluate.problem import evaluate_problem
from pasta.plan import PlanSettings

RESULTS = Path(__file__).resolve().parent / "results"
SCORED_POINTS = 1000


def sampling_floor(target: np.ndarray, seed: int) -> float:
    """EMD between two disjoint ``SCORED_POINTS``-point halves of a ``(P, 3)`` target sample."""
    return shape_distance(target[SCORED_POINTS:2 * SCORED_POINTS], target[:SCORED_POINTS], seed)


def demo_rows(task: str, profile: str, n_demos: int, overrides: list[str]) -> list[dict]:
    """``n_demos`` scripted single-skill demos of every skill of ``task`` (training problems in schedule order)."""
    cfg = load(task, profile, overrides)
    schedule = skill_schedule(cfg)
    skills = list(dict.fromkeys(schedule))
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for skill in skills:
            ids = [i for i, s in enumerate(schedule) if s == skill]
            extra = len(schedule)
            while len(ids) < n_demos:  # beyond the profile's dataset: the generator's later ids
                ids += [i + extra for i in ids[: n_demos - len(ids)]]
                extra += len(schedule)
            for config_id in ids[:n_demos]:
                problem = skill_problem(cfg, config_id)
                demo = generate_demo(cfg, problem, config_id, "scripted", Path(folder), seed=0)
                floor = sampling_floor(np.asarray(problem.target, np.float64), 0)
                cap = (demo.emd_initial - floor) / demo.emd_initial
                rows.append({"task": task, "skill": skill, "config_id": config_id,
                             "performance": demo.normalised_performance, "cap": cap, "seconds": demo.seconds})
                print(f"demo {task} {skill} {config_id}: {demo.normalised_performance:.3f} (cap {cap:.3f})",
                      flush=True)
    return rows


def oracle_rows(task: str, profile: str, seeds: list[int], overrides: list[str]) -> list[dict]:
    cfg = load(task, profile, overrides)
    settings = PlanSettings.from_config(cfg)
    rows = []
    for seed in seeds:
        for config_id in range(cfg.data.n_eval_configs):
            started = time.perf_counter()
            result = evaluate_problem(cfg, None, evaluation_problem(cfg, config_id), seed, "scripted", settings,
                                      "oracle")
            rows.append({"task": task, "seed": seed, "config_id": config_id, "performance": result.performance,
                         "success": result.success, "failure": result.failure,
                         "seconds": time.perf_counter() - started})
            print(f"oracle {task} seed {seed} config {config_id}: {result.performance:.3f}", flush=True)
    return rows


def summarise_demos(rows: list[dict]) -> list[dict]:
    out = []
    for key in dict.fromkeys((r["task"], r["skill"]) for r in rows):
        chosen = [r for r in rows if (r["task"], r["skill"]) == key]
        scores = np.array([r["performance"] for r in chosen])
        out.append({"task": key[0], "skill": key[1], "n": len(chosen), "median": float(np.median(scores)),
                    "p10": float(np.percentile(scores, 10)),
                    "median_cap": float(np.median([r["cap"] for r in chosen])),
                    "seconds_per_demo": float(np.mean([r["seconds"] for r in chosen]))})
    return out


def summarise_oracle(rows: list[dict]) -> list[dict]:
    out = []
    for task in dict.fromkeys(r["task"] for r in rows):
        chosen = [r for r in rows if r["task"] == task]
        per_seed = {}
        for r in chosen:
            per_seed.setdefault(r["seed"], []).append(r)
        means = [np.mean([r["performance"] for r in rs]) for rs in per_seed.values()]
        success = [np.mean([r["success"] for r in rs]) for rs in per_seed.values()]
        out.append({"task": task, "seeds": sorted(per_seed), "performance_mean": float(np.mean(means)),
                    "performance_std": float(np.std(means)), "success_mean": float(np.mean(success)),
                    "failures": sum(r["failure"] is not None for r in chosen),
                    "per_config": [round(r["performance"], 3) for r in chosen]})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", default="small")
    parser.add_argument("--tasks", nargs="+", default=[t for t in TASK_NAMES if t != "CRS-Twice"], choices=TASK_NAMES)
    parser.add_argument("--oracle-tasks", nargs="+", default=None, choices=TASK_NAMES,
                        help="tasks of the oracle part (default: --tasks)")
    parser.add_argument("--demos", type=int, default=10, help="single-skill demos per skill (0: none)")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0],
                        help="oracle evaluation seeds (none: no oracle part)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()

    load_before = os.getloadavg()
    demos, oracle = [], []
    for task in args.tasks if args.demos > 0 else []:
        demos += demo_rows(task, args.profile, args.demos, args.set)
    for task in (args.oracle_tasks or args.tasks) if args.seeds else []:
        oracle += oracle_rows(task, args.profile, args.seeds, args.set)
    load_after = os.getloadavg()

    demo_table, oracle_table = summarise_demos(demos), summarise_oracle(oracle)
    print(f"# skills, profile {args.profile}, {os.cpu_count()} cores, load average "
          f"{load_before[0]:.2f} before, {load_after[0]:.2f} after")
    print(f"{'task':<14}{'skill':<11}{'n':>4}{'median':>9}{'p10':>9}{'cap':>8}{'s/demo':>9}")
    for r in demo_table:
        print(f"{r['task']:<14}{r['skill']:<11}{r['n']:>4}{r['median']:>9.3f}{r['p10']:>9.3f}"
              f"{r['median_cap']:>8.3f}{r['seconds_per_demo']:>9.1f}")
    print(f"\n{'oracle plan, scripted':<24}{'performance':>16}{'success':>9}{'failed':>8}  per configuration")
    for r in oracle_table:
        print(f"{r['task']:<24}{r['performance_mean']:>9.3f} ± {r['performance_std']:.3f}{r['success_mean']:>9.0%}"
              f"{r['failures']:>8}  {r['per_config']}")
    out = args.out or RESULTS / f"skills_{args.profile}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"profile": args.profile, "overrides": args.set, "machine": platform.machine(),
               "cores": os.cpu_count(), "load_average": [load_before, load_after], "demos": demo_table,
               "demo_rows": demos, "oracle": oracle_table, "oracle_rows": oracle}
    out.write_text(json.dumps(payload, indent=1))
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
