"""How well each policy configuration learns in the same wall time: held-out action MSE against the zero action.

The policies' inputs are drawn once, with the project's own sampler (``TransitionSampler.policy_samples``:
hindsight goals, entity filtering) from a task's dataset, split by trajectory as training splits it: a pool
of ``--pool`` training samples and up to ``--heldout`` held-out samples per skill. Every configuration then
trains one policy per skill (one Adam over both, as the training loop does) on batches drawn from the same
pool with fresh point noise, for ``--minutes`` of wall time, and its held-out MSE is measured every
``--eval-s`` seconds (not counted in the budget). Drawing the pool once takes the sampler's cost out of the
comparison, so the rows differ by the network alone: encoder, precision, points per cloud, learning rate and
batch size. Fewer points take the first ``points`` of each pooled cloud, which are a uniform random subset.

A configuration is ``encoder:precision:points:lr:batch``, e.g. ``pointnet:bf16:500:1e-3:64``. The table gives
per skill the best held-out MSE divided by the zero-action MSE (issue 13's bar is 0.3), the steps and samples
per second; the load average is printed beside it, and JSON goes to
``benchmarks/results/policy_learning.json``.

    python benchmarks/policy_learning.py                       # CutRearrange, small, the default rows
    python benchmarks/policy_learning.py --minutes 2 --configs pointnet:fp32:1000:1e-3:64
"""

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from pasta.data.storage import atomic_write_bytes

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_CONFIGS = ("pointnet2:fp32:1000:1e-4:10", "pointnet:fp32:1000:1e-3:64", "pointnet:bf16:1000:1e-3:64",
                   "pointnet:fp32:500:1e-3:64")


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def parse_config(text: str) -> dict:
    encoder, precision, points, lr, batch = text.split(":")
    return {"name": text, "encoder": encoder, "precision": precision, "points": int(points), "lr": float(lr),
            "batch": int(batch)}


def draw_samples(sampler, skill: int, wanted: int, rng: np.random.Generator, chunk: int = 64):
    """Up to ``wanted`` policy samples of ``skill``, as clouds and actions (torch tensors)."""
    from pasta.train.policy_loop import ROWS_PER_SAMPLE

    parts = []
    count = 0
    while count < wanted:
        rows = sampler.transitions[skill][rng.integers(sampler.count(skill), size=ROWS_PER_SAMPLE * chunk)]
        samples = sampler.policy_samples(skill, rows, rng, min(chunk, wanted - count))
        if samples is None:
            continue
        parts.append(samples)
        count += len(samples)
    return {key: torch.cat([getattr(s, key) for s in parts]) for key in ("obs_points", "tool_points", "goal_points",
                                                                        "actions")}


def build_pools(task: str, profile: str, method: str, pool: int, heldout: int, seed: int) -> dict:
    from flows.train import dataset_folder
    from pasta.config import load
    from pasta.train.bundle import DEFAULT_FILTER_EPSILON
    from pasta.train.datasets import TransitionSampler
    from pasta.train.entities import PairChamfer
    from pasta.train.stages import load_training_data

    cfg = load(task, profile)
    data = load_training_data(cfg, dataset_folder(task, profile, method))
    chamfer = PairChamfer(data.table)
    train = TransitionSampler(data.demos, data.table, cfg.skills, data.heads_train, DEFAULT_FILTER_EPSILON, chamfer)
    test = TransitionSampler(data.demos, data.table, cfg.skills, data.heads_heldout, DEFAULT_FILTER_EPSILON, chamfer)
    rng = np.random.default_rng(seed)
    names = [skill.name for skill in cfg.skills]
    started = time.perf_counter()
    pools = [draw_samples(train, k, pool, rng) for k in range(len(names))]
    held = [draw_samples(test, k, heldout, rng) for k in range(len(names))]
    return {"cfg": cfg, "names": names, "pool": pools, "heldout": held, "draw_s": time.perf_counter() - started}


def clouds(samples: dict, index, points: int) -> list[torch.Tensor]:
    """The observation, tool and goal clouds of the samples at ``index``, the two big ones cut to ``points``."""
    return [samples["obs_points"][index, :points], samples["tool_points"][index],
            samples["goal_points"][index, :points]]


def heldout_mse(policy, samples: dict, points: int) -> float:
    from pasta.train.metrics import action_mse

    policy.eval()
    with torch.no_grad():  # in chunks: PointNet++ on hundreds of clouds at once takes gigabytes
        predicted = np.concatenate([policy(*clouds(samples, slice(start, start + 32), points)).float().numpy()
                                    for start in range(0, len(samples["actions"]), 32)])
    policy.train()
    return action_mse(predicted, samples["actions"].numpy())


def train_config(config: dict, pools: dict, minutes: float, eval_s: float, seed: int) -> dict:
    """Train one policy per skill for ``minutes`` of wall time; the held-out curve and the best ratios."""
    from pasta.models import ModelConfig, build_models
    from pasta.models.policy import uniform_point_noise
    from pasta.train.bundle import action_dim_of
    from pasta.train.metrics import action_mse
    from pasta.train.precision import training_autocast

    cfg, names = pools["cfg"], pools["names"]
    torch.manual_seed(seed)
    models = build_models("pasta", action_dim_of(cfg), ModelConfig().with_policy_encoder(config["encoder"]),
                          n_skills=len(names), seed=seed)
    policies = models["policy"]
    optimiser = torch.optim.Adam(policies.parameters(), lr=config["lr"])
    generator = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    device = torch.device("cpu")
    zero = [action_mse(np.zeros_like(h["actions"].numpy()), h["actions"].numpy()) for h in pools["heldout"]]
    curve = [{"train_s": 0.0, "steps": 0, **{n: heldout_mse(policies[k], pools["heldout"][k], config["points"])
                                            for k, n in enumerate(names)}}]
    steps, trained_s, next_eval = 0, 0.0, eval_s
    while trained_s < 60.0 * minutes:
        started = time.perf_counter()
        loss = 0.0
        for k in range(len(names)):
            index = torch.from_numpy(rng.integers(len(pools["pool"][k]["actions"]), size=config["batch"]))
            inputs = [uniform_point_noise(c, cfg.train.policy_point_noise, generator)
                      for c in clouds(pools["pool"][k], index, config["points"])]
            with training_autocast(config["precision"], device):
                predicted = policies[k](*inputs)
            loss = loss + (predicted.float() - pools["pool"][k]["actions"][index]).square().sum(1).mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        steps += 1
        trained_s += time.perf_counter() - started
        if trained_s >= next_eval or trained_s >= 60.0 * minutes:
            next_eval += eval_s
            curve.append({"train_s": round(trained_s, 1), "steps": steps,
                          **{n: heldout_mse(policies[k], pools["heldout"][k], config["points"])
                             for k, n in enumerate(names)}})
    best = {n: min(point[n] for point in curve) / zero[k] for k, n in enumerate(names)}
    final = {n: curve[-1][n] / zero[k] for k, n in enumerate(names)}
    return {**config, "steps": steps, "train_s": trained_s, "samples_per_s": steps * config["batch"] * len(names)
            / trained_s, "zero_mse": dict(zip(names, zero, strict=True)), "best_ratio": best, "final_ratio": final,
            "curve": curve}


def print_table(payload: dict) -> None:
    names = payload["skills"]
    print(f"\n{payload['task']} {payload['profile']}: {payload['minutes']} min per configuration, pool "
          f"{payload['pool']} / held-out {payload['heldout_samples']} samples per skill, {payload['threads']} "
          f"threads, load average {payload['load_before']} -> {payload['load_after']}, {os.cpu_count()} CPUs")
    print(f"{'configuration':32s} {'steps':>6s} {'samples/s':>9s}  " + "  ".join(
        f"{n + ' best/final':>22s}" for n in names))
    for row in payload["rows"]:
        ratios = "  ".join(f"{row['best_ratio'][n]:10.3f} / {row['final_ratio'][n]:<9.3f}" for n in names)
        print(f"{row['name']:32s} {row['steps']:6d} {row['samples_per_s']:9.1f}  {ratios}")
    print("(held-out action MSE / zero-action MSE; best over the evaluations, and at the end)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="CutRearrange")
    parser.add_argument("--profile", default="small")
    parser.add_argument("--method", default=None, help="dataset: gbto or scripted (default: gbto if present)")
    parser.add_argument("--configs", nargs="+", default=list(DEFAULT_CONFIGS))
    parser.add_argument("--minutes", type=float, default=5.0, help="training wall time per configuration")
    parser.add_argument("--eval-s", type=float, default=30.0, help="training seconds between evaluations")
    parser.add_argument("--pool", type=int, default=2048, help="training samples drawn per skill")
    parser.add_argument("--heldout", type=int, default=96, help="held-out samples drawn per skill (at most)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=RESULTS / "policy_learning.json")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    configs = [parse_config(text) for text in args.configs]
    load_before = load_average()
    pools = build_pools(args.task, args.profile, args.method, args.pool, args.heldout, args.seed)
    print(f"drew the samples in {pools['draw_s']:.0f} s")
    rows = []
    for config in configs:
        rows.append(train_config(config, pools, args.minutes, args.eval_s, args.seed))
        print(f"{config['name']}: best {rows[-1]['best_ratio']}, {rows[-1]['steps']} steps", flush=True)
    payload = {"task": args.task, "profile": args.profile, "minutes": args.minutes, "pool": args.pool,
               "heldout_samples": {n: len(h["actions"]) for n, h in zip(pools["names"], pools["heldout"], strict=True)},
               "threads": args.threads, "skills": pools["names"], "load_before": load_before,
               "load_after": load_average(), "draw_s": pools["draw_s"], "rows": rows}
    print_table(payload)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    data = json.dumps(payload, indent=1).encode()
    atomic_write_bytes(args.out, lambda handle: handle.write(data))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
