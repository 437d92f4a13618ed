"""Planner speed: time against the number of samples (appendix Fig. 2a), per task (Table 6), and the
pruned planner against the exhaustive one at CutRearrange's paper scale, side by side.

Networks have the paper's sizes and random weights (``untrained(load(task, "paper"), "pasta", prior)``);
timing does not depend on the weights, the scores are only compared between the two planners.
Each measurement runs in this process after one warm-up plan. Prints tables and writes JSON to
``benchmarks/results/plan.json`` (``plan_quick.json`` with ``--quick``).

    python benchmarks/plan.py              # full: about 15-20 minutes on 2 free cores
    python benchmarks/plan.py --quick      # reduced scale, a few minutes
    python benchmarks/plan.py --threads 1  # torch threads (default 2)
    python benchmarks/plan.py --device cuda  # plan on a GPU (writes plan_cuda.json)
"""

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import torch

from pasta.config import load
from pasta.models.latent_prior import LatentPrior
from pasta.plan import DEFAULT_HALVING, PlanSettings, bundle_skills, enumerate_sequences, plan, plan_receding_horizon
from pasta.train import untrained

RESULTS = Path(__file__).resolve().parent / "results"
PRIOR = LatentPrior(2, (0.2, 0.0, 0.2), (0.8, 0.2, 0.8))
# (task, observed entities, goal entities); CRS-Twice plans cut-push-spread twice with a 3-step window.
TASKS = [("LiftSpread", 1, 1), ("GatherMove", 1, 1), ("CutRearrange", 1, 2), ("CRS", 1, 2), ("CRS-Twice", 1, 3)]
CRS_TWICE = ("cut", "push", "spread") * 2


def problem(k_obs: int, k_goal: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return PRIOR.sample((k_obs,), gen), PRIOR.sample((k_goal,), gen)


def matmul_gflops() -> float:
    """Achieved GFLOP/s of a (4096 x 1024) @ (1024 x 1024) float32 product now (machine load probe)."""
    a, w = torch.randn(4096, 1024), torch.randn(1024, 1024)
    a @ w
    start, n = time.perf_counter(), 5
    for _ in range(n):
        a @ w
    return 2 * 4096 * 1024 * 1024 * n / (time.perf_counter() - start) / 1e9


def sample_iterations(settings: PlanSettings, n_sequences: int) -> int:
    """Objective evaluations the optimiser does: all samples until each halving, then half of them."""
    survivors, done, last = settings.samples * n_sequences, 0, 0
    for it in sorted(settings.halving_iterations()):
        done += survivors * (it + 1 - last)
        last = it + 1
        survivors = max(-(-survivors // 2), min(survivors, settings.min_survivors))
    return done + survivors * (settings.iterations - last)


def time_plan(task: str, k_obs: int, k_goal: int, settings: PlanSettings, device: str = "cpu") -> dict:
    cfg = load(task, "paper")
    bundle = untrained(load("CRS" if task == "CRS-Twice" else task, "paper"), "pasta", PRIOR)
    obs, goal = problem(k_obs, k_goal)
    if task == "CRS-Twice":
        n_sequences = 1
        run = lambda s: plan_receding_horizon(bundle, obs, goal, CRS_TWICE, cfg.plan.receding_horizon, s,  # noqa: E731
                                              device)
    else:
        n_sequences = len(enumerate_sequences(bundle_skills(bundle), cfg.horizon, k_obs, k_goal))
        run = lambda s: plan(bundle, obs, goal, cfg.horizon, s, device)  # noqa: E731
    run(dataclasses.replace(settings, samples=4, iterations=2))  # warm-up
    result = run(settings)
    stages = len(CRS_TWICE) if task == "CRS-Twice" else 1
    work = stages * sample_iterations(settings, n_sequences)
    return {"task": task, "sequences": n_sequences, "samples": settings.samples, "iterations": settings.iterations,
            "halving": list(settings.halving), "seconds": result.planning_time_s, "score": result.score,
            "skills": list(result.skills), "sample_iterations": work,
            "us_per_sample_iteration": result.planning_time_s / work * 1e6}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="torch device to plan on (cpu, cuda)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    quick = args.quick
    base = PlanSettings(lr=0.01, iterations=20 if quick else 100, samples=5000, alpha=10.0, halving=DEFAULT_HALVING)
    device = args.device
    out: dict = {"threads": args.threads, "device": device, "quick": quick, "torch": torch.__version__,
                 "cpu": platform.processor(), "cpu_count": os.cpu_count(), "load_average_start": os.getloadavg(),
                 "matmul_gflops_start": matmul_gflops()}

    # 1. Side by side at CutRearrange's paper scale: exhaustive vs successive halving, same seed.
    scale = dataclasses.replace(base, samples=500 if quick else 5000)
    exhaustive = time_plan("CutRearrange", 1, 2, dataclasses.replace(scale, halving=()), device)
    pruned = time_plan("CutRearrange", 1, 2, scale, device)
    out["side_by_side"] = {"exhaustive": exhaustive, "pruned": pruned,
                           "score_loss": exhaustive["score"] - pruned["score"],
                           "speed_up": exhaustive["seconds"] / pruned["seconds"]}

    # 2. Time against samples per sequence (Fig. 2a), CutRearrange, default (pruned) planner.
    out["samples_sweep"] = [time_plan("CutRearrange", 1, 2, dataclasses.replace(base, samples=n), device)
                            for n in ([100, 500] if quick else [100, 500, 1000, 5000])]

    # 3. Per task at its config's iterations with fewer samples; paper scale extrapolated from the work done.
    out["tasks"] = []
    for task, k_obs, k_goal in TASKS:
        cfg = load(task, "paper")
        settings = PlanSettings.from_config(cfg)
        measured = dataclasses.replace(settings, samples=50 if quick else 500,
                                       iterations=min(settings.iterations, 20) if quick else settings.iterations)
        row = time_plan(task, k_obs, k_goal, measured, device)
        stages = len(CRS_TWICE) if task == "CRS-Twice" else 1
        row["paper_samples"] = settings.samples
        row["paper_iterations"] = settings.iterations
        row["paper_seconds_extrapolated"] = (row["us_per_sample_iteration"] * 1e-6 * stages
                                             * sample_iterations(settings, row["sequences"]))
        out["tasks"].append(row)
    out["load_average_end"] = os.getloadavg()
    out["matmul_gflops_end"] = matmul_gflops()

    RESULTS.mkdir(exist_ok=True)
    suffix = ("_quick" if quick else "") + ("" if device == "cpu" else f"_{device.split(':')[0]}")
    path = RESULTS / f"plan{suffix}.json"
    path.write_text(json.dumps(out, indent=2))
    print_tables(out)
    print(f"\nwrote {path}")


def print_tables(out: dict) -> None:
    print(f"\ndevice {out.get('device', 'cpu')}; torch threads {out['threads']}; "
          f"load average {out['load_average_start'][0]:.1f} -> "
          f"{out['load_average_end'][0]:.1f}; matmul {out['matmul_gflops_start']:.0f} -> "
          f"{out['matmul_gflops_end']:.0f} GFLOP/s")
    side = out["side_by_side"]
    print("\n| CutRearrange, sequences x samples x iterations | planner | s | us/sample-iter | best score |")
    print("|---|---|---|---|---|")
    for name in ("exhaustive", "pruned"):
        r = side[name]
        print(f"| {r['sequences']} x {r['samples']} x {r['iterations']} | {name} {tuple(r['halving'])} "
              f"| {r['seconds']:.1f} | {r['us_per_sample_iteration']:.0f} | {r['score']:.4f} |")
    print(f"speed-up {side['speed_up']:.1f}x, score loss {side['score_loss']:.2e}")
    print("\n| samples per sequence (CutRearrange, 3 sequences) | iterations | s |")
    print("|---|---|---|")
    for r in out["samples_sweep"]:
        print(f"| {r['samples']} | {r['iterations']} | {r['seconds']:.1f} |")
    print("\n| task | sequences | measured samples x iterations | s | paper samples x iterations "
          "| paper s (extrapolated) |")
    print("|---|---|---|---|---|---|")
    for r in out["tasks"]:
        print(f"| {r['task']} | {r['sequences']} | {r['samples']} x {r['iterations']} | {r['seconds']:.1f} "
              f"| {r['paper_samples']} x {r['paper_iterations']} | {r['paper_seconds_extrapolated']:.0f} |")


if __name__ == "__main__":
    main()
