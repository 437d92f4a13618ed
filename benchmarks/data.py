"""Demo generation speed: seconds per demo (scripted and GBTO) per task, and demos per hour.

Each task runs in its own process (Taichi is one runtime per process). Prints a
table and writes JSON to ``benchmarks/results/data.json``.

    python benchmarks/data.py            # small profile, every task
    python benchmarks/data.py --quick    # smoke profile
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smoke profile")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(*args.child)))
        return
    profile = "smoke" if args.quick else "small"
    rows = []
    for task in TASKS:
        out = subprocess.run([sys.executable, __file__, "--child", task, profile], capture_output=True, text=True,
                             check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    RESULTS.mkdir(parents=True, exist_ok=True)
    target = RESULTS / f"data_{profile}.json"
    tmp = target.with_suffix(".tmp")
    tmp.write_text(json.dumps(rows, indent=2))
    tmp.replace(target)
    print(f"\n| task ({profile}) | skill | scripted s/demo | GBTO s/demo ({rows[0]['gbto_iterations']} it.) "
          "| GBTO demos/hour | scripted perf. | GBTO perf. |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['task']} | {r['skill']} | {r['scripted_s']:.1f} | {r['gbto_s']:.1f} | "
              f"{r['gbto_demos_per_hour']:.0f} | {r['scripted_performance']:.2f} | {r['gbto_performance']:.2f} |")
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
