"""Successive halving against the exhaustive planner with *trained* networks, on a task's real test problems.

``benchmarks/plan.py`` compares the two planners with random weights; this script checks the no-score-loss
claim where it matters: the trained bundle of a task (default: ``pasta train``'s ``small`` bundle under
``PASTA_HOME``), the task's evaluation problems (settled initial dough and goal, DBSCAN'd and encoded as
``pasta evaluate`` does), and the planning scale of a profile (default ``paper``: Table 3's samples and
iterations). Both planners get the same seed, hence the same initial latents and attention structures.
Prints a table and writes ``benchmarks/results/plan_trained_<task>.json``.

    python benchmarks/plan_trained.py --task CutRearrange             # 5 problems, paper scale
    python benchmarks/plan_trained.py --task CRS --scale small --problems 2
    python benchmarks/plan_trained.py --encoded problems.pt            # encode once (needs the simulator) ...
    python benchmarks/plan_trained.py --encoded problems.pt --bundle models.pt --device cuda   # ... plan anywhere

With ``--encoded PATH`` the encoded problems are read from ``PATH`` when it exists (no simulator needed,
e.g. on a GPU machine without Taichi) and written there otherwise.
"""

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from pasta.config import load
from pasta.paths import checkpoint_dir
from pasta.plan import DEFAULT_HALVING, PlanSettings, plan
from pasta.train.bundle import load_trained

RESULTS = Path(__file__).resolve().parent / "results"


def encoded_problem(cfg, bundle, config_id: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(K_obs, D)`` and ``(K_goal, D)`` latents of evaluation problem ``config_id``, as ``pasta evaluate``
    prepares them."""
    from pasta.data.configurations import evaluation_problem  # the simulator is imported only to encode
    from pasta.evaluate.problem import prepare_problem

    rng = np.random.default_rng([seed, config_id])
    prepared = prepare_problem(cfg, bundle, evaluation_problem(cfg, config_id), rng)
    return prepared.obs.latents, prepared.goal.latents


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", default="CutRearrange")
    parser.add_argument("--profile", default="small", help="profile the bundle was trained at and problems come from")
    parser.add_argument("--scale", default="paper", help="profile whose planning samples and iterations are used")
    parser.add_argument("--bundle", type=Path, default=None, help="models.pt (default: the profile's pasta bundle)")
    parser.add_argument("--problems", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="torch device to plan on (cpu, cuda)")
    parser.add_argument("--encoded", type=Path, default=None, help="read (or write) the encoded problems here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cfg = load(args.task, args.profile)
    path = args.bundle or checkpoint_dir(args.task, args.profile) / "pasta" / "models.pt"
    bundle = load_trained(path).eval()
    scale = PlanSettings.from_config(load(args.task, args.scale))
    if args.encoded is not None and args.encoded.exists():
        problems = torch.load(args.encoded)[: args.problems]
    else:
        problems = [encoded_problem(cfg, bundle, config_id, seed=0) for config_id in range(args.problems)]
        if args.encoded is not None:
            torch.save(problems, args.encoded)
    rows = []
    for config_id, (obs, goal) in enumerate(problems):
        warm_up = dataclasses.replace(scale, samples=4, iterations=2)
        plan(bundle, obs, goal, cfg.horizon, warm_up, args.device)
        row = {"config_id": config_id, "k_obs": int(obs.shape[0]), "k_goal": int(goal.shape[0])}
        for name, halving in (("exhaustive", ()), ("halving", DEFAULT_HALVING)):
            result = plan(bundle, obs, goal, cfg.horizon, dataclasses.replace(scale, halving=halving, seed=0),
                          args.device)
            row[name] = {"seconds": result.planning_time_s, "score": result.score, "skills": list(result.skills),
                         "attention": [list(map(int, a)) for a in result.attention]}
        row["score_loss"] = row["exhaustive"]["score"] - row["halving"]["score"]
        rows.append(row)
        e, h = row["exhaustive"], row["halving"]
        print(f"problem {config_id}: exhaustive {e['score']:.4f} in {e['seconds']:.1f} s, "
              f"halving {h['score']:.4f} in {h['seconds']:.1f} s", flush=True)
    out = {"task": args.task, "bundle": str(path), "problems_profile": args.profile, "scale": args.scale,
           "samples": scale.samples, "iterations": scale.iterations, "alpha": scale.alpha,
           "halving": list(DEFAULT_HALVING), "threads": args.threads, "device": args.device,
           "torch": torch.__version__,
           "load_average": os.getloadavg(), "rows": rows,
           "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
    RESULTS.mkdir(exist_ok=True)
    suffix = "" if args.device == "cpu" else "_" + args.device.split(":")[0]
    target = RESULTS / f"plan_trained_{args.task}{suffix}.json"
    target.write_text(json.dumps(out, indent=2))
    print(f"\n{args.task} on {args.device}, trained bundle {path}, {scale.samples} samples x {scale.iterations} "
          "iterations per sequence")
    print("| problem | K obs -> goal | exhaustive s | halving s | exhaustive score | halving score | loss "
          "| same plan |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        e, h = r["exhaustive"], r["halving"]
        same = e["skills"] == h["skills"] and e["attention"] == h["attention"]
        print(f"| {r['config_id']} | {r['k_obs']} -> {r['k_goal']} | {e['seconds']:.1f} | {h['seconds']:.1f} "
              f"| {e['score']:.4f} | {h['score']:.4f} | {r['score_loss']:.2e} | {same} |")
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
