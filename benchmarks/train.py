"""Training speed and memory of each model: samples per second and peak RSS, one model per process.

Each measurement runs a few Adam steps of one network at the paper's sizes (default ``ModelConfig``,
Table 3 batch sizes) on random inputs, in its own process on ``--threads`` torch threads (default 2),
so peak memory is that model's alone. Prints a table and writes JSON to
``benchmarks/results/train[_quick].json``.

    python benchmarks/train.py            # 5 timed steps per model
    python benchmarks/train.py --quick    # 2 timed steps per model
    python benchmarks/train.py --device cuda   # on a GPU (writes train_cuda.json; peak GPU memory too)
"""

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
MODELS = ("vae", "feasibility", "cost", "policy", "tool_concat_policy", "shared_encoder_policy")
ACTION_DIM = 10  # CutRearrange


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def build_step(name: str, device: str = "cpu"):
    """``(step, samples per step, what a sample is)`` for one model; ``step()`` runs one Adam step."""
    import torch

    from pasta.models import LatentPrior, ModelConfig, build_models, feasibility_batch, weighted_mse

    generator = torch.Generator().manual_seed(0)
    variant = {"tool_concat_policy": "tool_concat_policy", "shared_encoder_policy": "shared_encoder_policy"}.get(
        name, "pasta")
    models = build_models(variant, ACTION_DIM, ModelConfig())
    prior = LatentPrior(2, (0.2, 0.0, 0.2), (0.8, 0.2, 0.8))

    def points(batch: int, n: int) -> torch.Tensor:
        return (0.4 + 0.2 * torch.rand(batch, n, 3, generator=generator)).to(device)

    def latents(shape: tuple[int, ...]) -> torch.Tensor:
        return prior.sample(shape, generator).to(device)

    if name == "vae":
        model, clouds = models["vae"].to(device), points(64, 1000)
        model.fit_scale(clouds)

        def loss():
            return model.elbo_loss(clouds, generator)[0]
        samples, unit = 64, "entity clouds (batch 64 x 1000 points)"
    elif name == "feasibility":
        model = models["feasibility"][0].to(device)
        obs, goal = latents((256, 1)), latents((256, 2))

        def loss():
            batch = feasibility_batch(obs, goal, None, None, prior, sigma_z=0.02, sigma_t=0.01, hard_copies=10,
                                      n_random=2048, generator=generator)
            return weighted_mse(model(batch.obs, batch.goal, batch.obs_mask, batch.goal_mask), batch.labels,
                                batch.weights)
        samples, unit = 256 + 2560 + 2048, "set pairs (256 positives, 2560 hard, 2048 random; 1->2 skill)"
    elif name == "cost":
        model = models["cost"].to(device)
        a, b, target = latents((512,)), latents((512,)), torch.rand(512, device=device) * 1e-2

        def loss():
            return (model(a, b) - target).square().mean()
        samples, unit = 512, "entity pairs (batch 2 x 256)"
    elif name == "shared_encoder_policy":
        model = models["policy"][0].to(device)
        obs, goal, action = latents((10, 1)), latents((10, 2)), torch.rand(10, 10, device=device)

        def loss():
            return (model(obs, goal) - action).square().sum(1).mean()
        samples, unit = 10, "latent-set samples (batch 10)"
    else:
        model = models["policy"][0].to(device)
        obs, tool, goal = points(10, 1000), points(10, 100), points(10, 1000)
        state, action = torch.rand(10, 8, device=device), torch.rand(10, ACTION_DIM, device=device)

        def loss():
            out = model(obs, goal, state) if name == "tool_concat_policy" else model(obs, tool, goal)
            return (out - action).square().sum(1).mean()
        samples, unit = 10, "point-cloud samples (batch 10, 1000 + 100 + 1000 points)"
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-4)

    def step() -> None:
        optimiser.zero_grad(set_to_none=True)
        loss().backward()
        optimiser.step()
    return step, samples, unit


def measure(name: str, steps: int, threads: int, device: str = "cpu") -> dict:
    import torch

    torch.set_num_threads(threads)
    cuda = device.startswith("cuda")

    def sync() -> None:
        if cuda:
            torch.cuda.synchronize()

    baseline = peak_rss_mb()
    step, samples, unit = build_step(name, device)
    step()  # warm-up
    sync()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    sync()
    seconds = (time.perf_counter() - start) / steps
    return {"model": name, "device": device, "threads": threads, "steps": steps, "s_per_step": seconds,
            "samples_per_step": samples, "samples_per_s": samples / seconds, "sample": unit,
            "rss_before_mb": baseline, "peak_rss_mb": peak_rss_mb(),
            "peak_gpu_mb": torch.cuda.max_memory_allocated() / 2**20 if cuda else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="2 timed steps per model instead of 5")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    parser.add_argument("--child", nargs=3, metavar=("MODEL", "STEPS", "THREADS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.child[0], int(args.child[1]), int(args.child[2]), args.device)))
        return
    steps = 2 if args.quick else 5
    rows = []
    for name in MODELS:
        out = subprocess.run([sys.executable, __file__, "--child", name, str(steps), str(args.threads),
                              "--device", args.device],
                             capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(f"measured {name}", file=sys.stderr)
    print(f"\n{args.device}, {args.threads} torch threads, {steps} timed steps per model\n")
    print("| model | s/step | samples/step | samples/s | peak RSS MB (before build) | peak GPU MB | sample |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        gpu = "—" if r["peak_gpu_mb"] is None else f"{r['peak_gpu_mb']:.0f}"
        print(f"| {r['model']} | {r['s_per_step']:.3f} | {r['samples_per_step']} | {r['samples_per_s']:.1f} "
              f"| {r['peak_rss_mb']:.0f} ({r['rss_before_mb']:.0f}) | {gpu} | {r['sample']} |")
    RESULTS.mkdir(exist_ok=True)
    suffix = ("_quick" if args.quick else "") + ("" if args.device == "cpu" else "_" + args.device.split(":")[0])
    path = RESULTS / f"train{suffix}.json"
    path.write_text(json.dumps({"threads": args.threads, "device": args.device, "steps": steps, "rows": rows},
                               indent=1))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
