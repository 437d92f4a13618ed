"""One training step of the set policy, side by side: this checkout's PointNet++ encoder, the reference
PointNet++ and the compact encoder (one PointNet per cloud, ``policy.encoder: pointnet``).

A step is forward, backward and Adam on one batch at the ``small`` profile's sizes (CutRearrange:
``policy_batch_size`` samples of ``observation_points`` observation, ``tool_points`` tool and
``observation_points`` goal points, ``policy_lr``), with random clouds and the default ``PolicyConfig`` of
each encoder. The reference is the PointNet++ of ``--reference`` (a git revision; by default the last one
before the factored set abstraction), imported from git with its own MLP helper and given the same weights
through ``load_state_dict``, so it also checks that checkpoints still load. A process times at least
``--steps`` steps and at least ``MIN_TIMED_S`` seconds, so the compact encoder's short steps are timed over
many.

Each (implementation, repeat) runs in its own process, so peak memory is that implementation's alone;
the repeats are interleaved, so a change in background load hits them alike, and the table shows
medians. A last process runs both PointNet++ encoders on the same batch and reports how far their outputs
and parameter gradients are from the reference's in float64 (this checkout's in float64 and float32, the
reference's in float32). Prints the load average and the CPU count, and writes JSON to
``benchmarks/results/policy_step.json``.

    python benchmarks/policy_step.py                 # 3 repeats of 3 timed steps each, 2 torch threads
    python benchmarks/policy_step.py --repeats 5 --threads 1
    python benchmarks/policy_step.py --reference ''  # this checkout's encoders only
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
import types
from pathlib import Path

from pasta.data.storage import atomic_write_bytes

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
REFERENCE = "cb9bf91e9471d0fdc88fd96a18ef4d6154920511"  # MLP on the grouped (B, S, K, C) tensor as is
TASK, PROFILE = "CutRearrange", "paper"  # the appendix's batch (10) and rate: small trains the compact one at 64
ACTION_DIM = 10  # CutRearrange
MIN_TIMED_S = 2.0  # a process times steps for at least this long
LABELS = {"current": "PointNet++ (pointnet2)", "reference": "PointNet++, reference", "compact": "compact (pointnet)"}


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def sizes() -> dict:
    """Batch, point counts and learning rate of a policy step at the profile."""
    from pasta.config import load

    cfg = load(TASK, PROFILE)
    return {"batch": cfg.train.policy_batch_size, "obs_points": cfg.sim.observation_points,
            "tool_points": cfg.sim.tool_points, "goal_points": cfg.sim.observation_points, "lr": cfg.train.policy_lr}


def module_from_git(rev: str, path: str, name: str) -> types.ModuleType:
    """Execute ``path`` as it was at ``rev`` as a new module ``name``."""
    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{path}"], capture_output=True, text=True,
                            check=True).stdout
    module = types.ModuleType(name)
    sys.modules[name] = module  # dataclasses look their class's module up
    exec(compile(source, f"{rev}:{path}", "exec"), module.__dict__)
    return module


def reference_pointnet(rev: str) -> types.ModuleType:
    """``pasta/models/pointnet.py`` at ``rev``, using ``mlp`` from ``pasta/models/layers.py`` at ``rev``."""
    pointnet = module_from_git(rev, "pasta/models/pointnet.py", "reference_pointnet")
    pointnet.mlp = module_from_git(rev, "pasta/models/layers.py", "reference_layers").mlp
    return pointnet


def build_policy(implementation: str, rev: str, dtype=None):
    """A seeded default ``SetPolicy`` (compact encoder for ``compact``); for ``reference`` its encoder is
    ``rev``'s with the same weights."""
    import torch

    from pasta.models import PolicyConfig, SetPolicy

    encoder = "pointnet" if implementation == "compact" else "pointnet2"
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        policy = SetPolicy(ACTION_DIM, PolicyConfig(point_encoder=encoder))
    if implementation == "reference":
        encoder = reference_pointnet(rev).PointNetPlusPlusEncoder(policy.config.encoder)
        encoder.load_state_dict(policy.encoder.state_dict())
        policy.encoder = encoder
    return policy if dtype is None else policy.to(dtype)


def batch(size: dict, dtype=None):
    """Random clouds ``(obs, tool, goal)`` in ``[0.4, 0.6]^3`` and actions, seeded."""
    import torch

    gen = torch.Generator().manual_seed(1)

    def cloud(n: int) -> torch.Tensor:
        return (0.4 + 0.2 * torch.rand(size["batch"], n, 3, generator=gen)).to(dtype or torch.float32)

    clouds = cloud(size["obs_points"]), cloud(size["tool_points"]), cloud(size["goal_points"])
    return clouds, (2 * torch.rand(size["batch"], ACTION_DIM, generator=gen) - 1).to(dtype or torch.float32)


def timed_steps(step, steps: int) -> tuple[int, float]:
    """Run ``step`` at least ``steps`` times and for at least ``MIN_TIMED_S``; ``(steps run, seconds per step)``."""
    done, start = 0, time.perf_counter()
    while done < steps or time.perf_counter() - start < MIN_TIMED_S:
        step()
        done += 1
    return done, (time.perf_counter() - start) / done


def measure(implementation: str, rev: str, steps: int, threads: int) -> dict:
    """Seconds per training step (mean over ``timed_steps`` after one warm-up step), parameters and peak RSS of
    one implementation."""
    import torch

    torch.set_num_threads(threads)
    size = sizes()
    policy = build_policy(implementation, rev)
    clouds, actions = batch(size)
    optimiser = torch.optim.Adam(policy.parameters(), lr=size["lr"])

    def step() -> None:
        optimiser.zero_grad(set_to_none=True)
        (policy(*clouds) - actions).square().sum(1).mean().backward()
        optimiser.step()

    rss_before = peak_rss_mb()
    step()
    done, seconds = timed_steps(step, steps)
    return {"implementation": implementation, "threads": threads, "steps": done, "s_per_step": seconds,
            "samples_per_s": size["batch"] / seconds, "parameters": sum(p.numel() for p in policy.parameters()),
            "rss_before_mb": rss_before, "peak_rss_mb": peak_rss_mb(), **size}


def relative_gap(a, b) -> float:
    """``max |a - b| / max |b|``."""
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-30))


def output_and_gradients(implementation: str, rev: str, size: dict, dtype):
    """The policy's output on the benchmark batch and the parameter gradients of its loss, in ``dtype``."""
    policy = build_policy(implementation, rev, dtype)
    clouds, actions = batch(size, dtype)
    out = policy(*clouds)
    (out - actions).square().sum(1).mean().backward()
    return out.detach(), {name: p.grad for name, p in policy.named_parameters()}


def gaps(candidate, truth) -> dict:
    """Relative gaps of a candidate's output and worst parameter gradient from the truth's."""
    (out, grads), (true_out, true_grads) = candidate, truth
    by_parameter = {name: relative_gap(grads[name].double(), true_grads[name]) for name in true_grads}
    worst = max(by_parameter, key=by_parameter.__getitem__)
    return {"output": relative_gap(out.double(), true_out), "gradient": by_parameter[worst],
            "gradient_parameter": worst}


def compare(rev: str, threads: int) -> dict:
    """How far the implementations' outputs and parameter gradients are from the reference's in float64.

    In float64 the two must agree to rounding. In float32 both drift from it, gradients most: the
    gradient of a max follows one group member, and float32 cannot tell apart two members whose values
    differ by less than its rounding, so either implementation may follow the other one.
    """
    import torch

    torch.set_num_threads(threads)
    size = sizes()
    truth = output_and_gradients("reference", rev, size, torch.float64)
    cases = [("current", torch.float64), ("current", torch.float32), ("reference", torch.float32)]
    return {f"{implementation} {str(dtype).removeprefix('torch.')}":
            gaps(output_and_gradients(implementation, rev, size, dtype), truth) for implementation, dtype in cases}


def run_child(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def median_result(runs: list[dict]) -> dict:
    """The first run's entries with every float replaced by its median over ``runs``; ``runs``: their number."""
    result = {key: statistics.median(r[key] for r in runs) if isinstance(value, float) else value
              for key, value in runs[0].items()}
    result["runs"] = len(runs)
    result["s_per_step_each"] = [r["s_per_step"] for r in runs]
    return result


def print_table(payload: dict) -> None:
    rows, size = payload["rows"], payload["rows"][0]
    print(f"\n{payload['cpu_count']} CPUs (os.cpu_count()), {payload['threads']} torch threads; load average "
          f"(1, 5, 15 min) {payload['load_average_start']} at the start, {payload['load_average_end']} at the end; "
          f"medians of {payload['repeats']} processes, each timing at least {payload['steps']} steps and "
          f"{MIN_TIMED_S:g} s")
    if max(payload["load_average_start"][0], payload["load_average_end"][0]) > 0.5:
        print("WARNING: other work was running (1-min load average > 0.5). Times are inflated, and unevenly: "
              "chains of small ops on several threads (the reference's farthest-point sampling) stall most, so "
              "the speed-up is not an idle machine's either.")
    print(f"\nSetPolicy training step at {PROFILE} ({TASK}): batch {size['batch']}, {size['obs_points']} + "
          f"{size['tool_points']} + {size['goal_points']} points, Adam lr {size['lr']}\n")
    print("| encoder | parameters | s/step (median) | each process | samples/s | peak RSS MB (before the first step) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        each = ", ".join(f"{s:.3g}" for s in r["s_per_step_each"])
        print(f"| {LABELS[r['implementation']]} | {r['parameters']:,} | {r['s_per_step']:.3g} | {each} "
              f"| {r['samples_per_s']:.3g} | {r['peak_rss_mb']:.0f} ({r['rss_before_mb']:.0f}) |")
    seconds = {r["implementation"]: r["s_per_step"] for r in rows}
    print(f"\ncompact encoder: {seconds['current'] / seconds['compact']:.1f}x fewer seconds per step than "
          "this checkout's PointNet++")
    if payload["agreement"]:
        print(f"PointNet++ speed-up: {seconds['reference'] / seconds['current']:.2f}x "
              f"(reference {payload['reference']})")
        print("distance from the reference in float64, relative to the largest magnitude:")
        for name, gap in payload["agreement"].items():
            print(f"  {name}: output {gap['output']:.1e}, parameter gradients at most {gap['gradient']:.1e} "
                  f"({gap['gradient_parameter']})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="processes per implementation, median reported")
    parser.add_argument("--steps", type=int, default=3, help="fewest timed steps per process, after one warm-up step")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--reference", default=REFERENCE, help="git revision of the reference encoder ('' for none)")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, rev, threads = args.child[0], args.child[1], int(args.child[2])
        result = compare(rev, threads) if kind == "compare" else measure(kind, rev, int(args.child[3]), threads)
        print(json.dumps(result))
        return
    if args.repeats < 3 or args.steps < 1:
        parser.error("--repeats must be at least 3 and --steps at least 1")
    implementations = ["current", "reference", "compact"] if args.reference else ["current", "compact"]
    load_start = load_average()
    runs: dict[str, list[dict]] = {name: [] for name in implementations}
    for _ in range(args.repeats):
        for name in implementations:
            runs[name].append(run_child([name, args.reference, str(args.threads), str(args.steps)]))
            print(f"measured {name}: {runs[name][-1]['s_per_step']:.2f} s/step", file=sys.stderr)
    agreement = run_child(["compare", args.reference, str(args.threads)]) if args.reference else None
    payload = {"task": TASK, "profile": PROFILE, "cpu_count": os.cpu_count(), "threads": args.threads,
               "repeats": args.repeats, "steps": args.steps, "reference": args.reference or None,
               "load_average_start": load_start, "load_average_end": load_average(),
               "rows": [median_result(runs[name]) for name in implementations], "agreement": agreement,
               "measured_at": time.strftime("%Y-%m-%dT%H:%M:%S")}
    data = json.dumps(payload, indent=2).encode()
    target = atomic_write_bytes(RESULTS / "policy_step.json", lambda handle: handle.write(data))
    print_table(payload)
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
