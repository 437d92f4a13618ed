"""Demo generation: seconds per demo (scripted and GBTO) per task and demos per hour, or, with
``--gbto-demos N``, how much GBTO adds to its scripted warm start over N demos per task.

Each task runs in its own process (Taichi is one runtime per process). Prints a
table and writes JSON to ``benchmarks/results/data_<profile>.json`` (``gbto_<profile>.json``).

    python benchmarks/data.py            # small profile, every task
    python benchmarks/data.py --quick    # smoke profile
    python benchmarks/data.py --gbto-demos 5 --tasks CutRearrange CRS   # GBTO against its warm start
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pasta.data.storage import atomic_write_bytes

RESULTS = Path(__file__).resolve().parent / "results"
TASKS = ["LiftSpread", "GatherMove", "CutRearrange", "CRS"]


def measure(task: str, profile: str) -> dict:
    from pasta.config import load
    from pasta.data.configurations import generate_skill_problems
    from pasta.data.demos import generate_demo

    cfg = load(task, profile)
    problem = generate_skill_problems(cfg)[0]
    result = {"task": task, "profile": profile, "skill": problem.skill, "gbto_iterations": cfg.data.gbto_iterations}
    with tempfile.TemporaryDirectory() as out:
        generate_demo(cfg, problem, 0, "scripted", Path(out))  # compile / load kernels
        for method in ("scripted", "gbto"):
            start = time.perf_counter()
            demo = generate_demo(cfg, problem, 1, method, Path(out))
            seconds = time.perf_counter() - start
            result[f"{method}_s"] = seconds
            result[f"{method}_demos_per_hour"] = 3600 / seconds
            result[f"{method}_performance"] = demo.normalised_performance
    return result


def gbto_against_warm_start(task: str, profile: str, n_demos: int) -> dict:
    """The first ``n_demos`` training problems of ``task`` made by GBTO: per demo, the normalised performance
    of the scripted warm start and of GBTO's best iterate replayed in the ordinary simulator."""
    from pasta.config import load
    from pasta.data.configurations import skill_problem
    from pasta.data.demos import generate_demo

    cfg = load(task, profile)
    demos = []
    with tempfile.TemporaryDirectory() as out:
        for config_id in range(n_demos):
            demo = generate_demo(cfg, skill_problem(cfg, config_id), config_id, "gbto", Path(out))
            demos.append({"configuration_id": config_id, "skill": demo.skill, "seconds": demo.seconds,
                          "scripted": demo.scripted_performance, "gbto": demo.gbto_performance,
                          "losses": list(demo.gbto_losses)})
            print(json.dumps(demos[-1]), file=sys.stderr, flush=True)
    gains = [d["gbto"] - d["scripted"] for d in demos]
    return {"task": task, "profile": profile, "gbto_iterations": cfg.data.gbto_iterations, "demos": demos,
            "better_share": sum(g > 0 for g in gains) / len(gains), "median_gain": statistics.median(gains),
            "median_seconds": statistics.median(d["seconds"] for d in demos)}


def write_json(rows: list[dict], name: str) -> Path:
    data = json.dumps(rows, indent=2).encode()
    return atomic_write_bytes(RESULTS / name, lambda handle: handle.write(data))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smoke profile")
    parser.add_argument("--tasks", nargs="+", default=TASKS, choices=TASKS)
    parser.add_argument("--gbto-demos", type=int, default=0, metavar="N",
                        help="GBTO against its scripted warm start on the first N problems of each task")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    profile = "smoke" if args.quick else "small"
    if args.child:
        task, child_profile = args.child
        result = (gbto_against_warm_start(task, child_profile, args.gbto_demos) if args.gbto_demos
                  else measure(task, child_profile))
        print(json.dumps(result))
        return
    extra = ["--gbto-demos", str(args.gbto_demos)] if args.gbto_demos else []
    rows = []
    for task in args.tasks:
        out = subprocess.run([sys.executable, __file__, "--child", task, profile, *extra], stdout=subprocess.PIPE,
                             text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    if args.gbto_demos:
        target = write_json(rows, f"gbto_{profile}.json")
        print(f"\n| task ({profile}) | GBTO iterations | demos | GBTO better | median gain | median s / demo |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['task']} | {r['gbto_iterations']} | {len(r['demos'])} | {r['better_share']:.0%} | "
                  f"{r['median_gain']:+.3f} | {r['median_seconds']:.0f} |")
        print(f"\nwrote {target} (load average {' '.join(f'{v:.2f}' for v in os.getloadavg())})")
        return
    target = write_json(rows, f"data_{profile}.json")
    print(f"\n| task ({profile}) | skill | scripted s/demo | GBTO s/demo ({rows[0]['gbto_iterations']} it.) "
          "| GBTO demos/hour | scripted perf. | GBTO perf. |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['task']} | {r['skill']} | {r['scripted_s']:.1f} | {r['gbto_s']:.1f} | "
              f"{r['gbto_demos_per_hour']:.0f} | {r['scripted_performance']:.2f} | {r['gbto_performance']:.2f} |")
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
