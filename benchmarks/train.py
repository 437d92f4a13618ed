"""Training speed and memory of each model: samples per second and peak RSS, one model per process.

Each measurement runs a few Adam steps of one network at the paper's sizes (default ``ModelConfig``,
Table 3 batch sizes) on random inputs, in its own process on ``--threads`` torch threads (default 2),
so peak memory is that model's alone, once per ``--precision`` (``train.precision``: ``bf16`` runs the
forward pass under the training loops' autocast). Beside them, the same threads' matrix-multiply rate
(GFLOP/s of a 1024 x 1024 product, float32 and bfloat16) says what the machine can do at all. Prints a
table with the load average before and after and writes JSON to ``benchmarks/results/train[_quick].json``.

    python benchmarks/train.py            # 5 timed steps per model
    python benchmarks/train.py --quick    # 2 timed steps per model
    python benchmarks/train.py --models policy,vae --precision fp32,bf16
    python benchmarks/train.py --models policy --heap-pad on,off   # with and without the heap top pad
    python benchmarks/train.py --device cuda   # on a GPU (writes train_cuda.json; peak GPU memory too)
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from pasta.data.storage import atomic_write_bytes  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
MODELS = ("vae", "feasibility", "cost", "policy", "tool_concat_policy", "shared_encoder_policy")
ACTION_DIM = 10  # CutRearrange


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def load_average() -> list[float]:
    return [round(value, 2) for value in os.getloadavg()]


def build_step(name: str, device: str = "cpu", precision: str = "fp32"):
    """``(step, samples per step, what a sample is)`` for one model; ``step()`` runs one Adam step with the
    forward pass in ``precision``."""
    import torch

    from pasta.models import LatentPrior, ModelConfig, build_models, feasibility_batch, weighted_mse
    from pasta.train.precision import training_autocast

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
        with training_autocast(precision, torch.device(device)):
            value = loss()
        value.float().backward()
        optimiser.step()
    return step, samples, unit


def matmul_rate(threads: int, dtype_name: str, device: str = "cpu", size: int = 1024, repeats: int = 20) -> float:
    """GFLOP/s of ``size x size`` matrix products in ``dtype_name`` (``fp32`` or ``bf16``) on ``threads``."""
    import torch

    torch.set_num_threads(threads)
    dtype = torch.bfloat16 if dtype_name == "bf16" else torch.float32
    a = torch.rand(size, size, device=device).to(dtype)
    b = torch.rand(size, size, device=device).to(dtype)
    a @ b  # warm-up
    start = time.perf_counter()
    for _ in range(repeats):
        a @ b
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    return 2 * size**3 * repeats / (time.perf_counter() - start) / 1e9


def measure(name: str, steps: int, threads: int, device: str = "cpu", precision: str = "fp32",
            heap_pad: str = "on") -> dict:
    import torch

    from pasta.train.allocator import keep_freed_memory

    if name == "matmul":
        return {"model": "matmul", "precision": precision, "threads": threads,
                "gflop_per_s": matmul_rate(threads, precision, device)}
    torch.set_num_threads(threads)
    if heap_pad == "on":  # as `pasta train` does
        keep_freed_memory()
    cuda = device.startswith("cuda")

    def sync() -> None:
        if cuda:
            torch.cuda.synchronize()

    baseline = peak_rss_mb()
    step, samples, unit = build_step(name, device, precision)
    step()  # warm-up
    sync()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    sync()
    seconds = (time.perf_counter() - start) / steps
    return {"model": name, "precision": precision, "heap_pad": heap_pad, "device": device, "threads": threads,
            "steps": steps,
            "s_per_step": seconds,
            "samples_per_step": samples, "samples_per_s": samples / seconds, "sample": unit,
            "rss_before_mb": baseline, "peak_rss_mb": peak_rss_mb(),
            "peak_gpu_mb": torch.cuda.max_memory_allocated() / 2**20 if cuda else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="2 timed steps per model instead of 5")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    parser.add_argument("--models", default=",".join(MODELS), help="comma-separated subset of " + ", ".join(MODELS))
    parser.add_argument("--precision", default="fp32,bf16", help="comma-separated: fp32, bf16")
    parser.add_argument("--heap-pad", default="on",
                        help="comma-separated: on (glibc heap top pad, as training sets it; "
                             "pasta/train/allocator.py), off")
    parser.add_argument("--child", nargs=5, metavar=("MODEL", "STEPS", "THREADS", "PRECISION", "HEAP_PAD"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        name, steps, threads, precision, heap_pad = args.child
        print(json.dumps(measure(name, int(steps), int(threads), args.device, precision, heap_pad)))
        return
    models = [m for m in args.models.split(",") if m]
    precisions = [p for p in args.precision.split(",") if p]
    pads = [p for p in args.heap_pad.split(",") if p]
    for value, known, what in ((models, MODELS, "model"), (precisions, ("fp32", "bf16"), "precision"),
                               (pads, ("on", "off"), "heap pad")):
        unknown = sorted(set(value) - set(known))
        if unknown:
            parser.error(f"unknown {what} {unknown}; known: {', '.join(known)}")
    steps = 2 if args.quick else 5
    load_before = load_average()
    rows, reference = [], {}
    for precision in precisions:
        out = subprocess.run([sys.executable, __file__, "--child", "matmul", "0", str(args.threads), precision, "on",
                              "--device", args.device], capture_output=True, text=True, check=True)
        reference[precision] = json.loads(out.stdout.strip().splitlines()[-1])["gflop_per_s"]
        for name in models:
            for pad in pads:
                out = subprocess.run([sys.executable, __file__, "--child", name, str(steps), str(args.threads),
                                      precision, pad, "--device", args.device], capture_output=True, text=True,
                                     check=True)
                rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
                print(f"measured {name} {precision} heap pad {pad}", file=sys.stderr)
    load_after = load_average()
    print(f"\n{args.device}, {args.threads} torch threads, {steps} timed steps per model, {os.cpu_count()} CPUs, "
          f"load average {load_before} -> {load_after}")
    print("matmul 1024^3: " + ", ".join(f"{p} {g:.0f} GFLOP/s" for p, g in reference.items()) + "\n")
    print("| model | precision | heap pad | s/step | samples/step | samples/s | peak RSS MB (before build) "
          "| peak GPU MB | sample |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        gpu = "—" if r["peak_gpu_mb"] is None else f"{r['peak_gpu_mb']:.0f}"
        print(f"| {r['model']} | {r['precision']} | {r['heap_pad']} | {r['s_per_step']:.3f} | {r['samples_per_step']} "
              f"| {r['samples_per_s']:.1f} | {r['peak_rss_mb']:.0f} ({r['rss_before_mb']:.0f}) | {gpu} "
              f"| {r['sample']} |")
    RESULTS.mkdir(exist_ok=True)
    suffix = ("_quick" if args.quick else "") + ("" if args.device == "cpu" else "_" + args.device.split(":")[0])
    path = RESULTS / f"train{suffix}.json"
    payload = {"threads": args.threads, "device": args.device, "steps": steps, "cpu_count": os.cpu_count(),
               "load_before": load_before, "load_after": load_after, "matmul_gflop_per_s": reference, "rows": rows}
    data = json.dumps(payload, indent=1).encode()
    atomic_write_bytes(path, lambda handle: handle.write(data))
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
