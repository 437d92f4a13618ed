"""Simulator speed and memory: forward and forward+backward throughput, episode time per task.

Each measurement runs in its own process (Taichi is one runtime per process and
peak memory is per process). Prints a table and writes JSON to
``benchmarks/results/sim.json``.

    python benchmarks/sim.py            # full set
    python benchmarks/sim.py --quick    # reduced set, a few minutes
    python benchmarks/sim.py --compile  # also time a cold kernel compile (empty cache)
    python benchmarks/sim.py --arch cuda  # Taichi on a GPU (writes sim_cuda.json)
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
LAYOUTS_FULL = [(32, 5000), (48, 8000), (64, 30000)]
LAYOUTS_QUICK = [(32, 5000), (48, 8000)]
TASKS = ["LiftSpread", "GatherMove", "CutRearrange", "CRS", "CRS-Twice"]


def substeps_for(n_grid: int) -> tuple[float, int]:
    """dt and substeps per 2e-3 s environment step at this grid (the profiles' rule)."""
    dt = 2e-4 * 32 / n_grid
    return dt, round(2e-3 / dt)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _sync(arch: str) -> None:
    """Wait for queued GPU kernels, so timings cover the work and not only its launch."""
    if arch != "cpu":
        import taichi as ti

        ti.sync()


def measure_layout(n_grid: int, n_particles: int, steps: int, grad_steps: int, arch: str = "cpu") -> dict:
    """Throughput of one (grid, particles) layout: a box pressing a block."""
    import numpy as np

    from pasta.config.schema import MaterialConfig, SimConfig, ToolConfig
    from pasta.sim.autodiff import backpropagate_episode, simulate_episode
    from pasta.sim.engine import simulator_for

    dt, substeps = substeps_for(n_grid)
    sim_cfg = SimConfig(n_grid=n_grid, dt_s=dt, substeps_per_step=substeps, n_particles=n_particles,
                        gravity_m_s2=(0, -600, 0), contact_softness=666.0, arch=arch)
    material = MaterialConfig(youngs_modulus_pa=5e3, poisson_ratio=0.15, yield_stress_pa=150, ground_friction=0.5)
    tool = ToolConfig(name="pusher", kind="box", position=(0.5, 0.2, 0.5), half_extents=(0.06, 0.02, 0.06),
                      action_scales=(0.01, 0.01, 0.01, 0.0, 0.0, 0.0), friction=1.0)
    rng = np.random.default_rng(0)
    x = rng.uniform([0.35, 0.1, 0.35], [0.65, 0.18, 0.65], (n_particles, 3)).astype(np.float32)
    state = {"x": x, "tool_pos": np.array([[0.5, 0.2, 0.5]]), "tool_rot": np.array([[1.0, 0, 0, 0]]),
             "tool_gap": np.zeros(1)}
    press = np.array([0.0, -0.3, 0.0, 0.0, 0.0, 0.0], np.float32)
    result = {"n_grid": n_grid, "n_particles": n_particles, "substeps_per_step": substeps}

    sim = simulator_for(sim_cfg, [tool], differentiable=False)
    sim.set_material(material)
    sim.set_state(state)
    sim.step(press)  # compile / load kernels
    sim.set_state(state)
    _sync(arch)
    start = time.perf_counter()
    for t in range(steps):
        sim.step(press, step=t)
    _sync(arch)
    forward_s = time.perf_counter() - start
    result["forward_mps"] = steps * substeps * n_particles / forward_s / 1e6
    result["forward_ms_per_substep"] = forward_s / (steps * substeps) * 1e3

    grad_sim = simulator_for(sim_cfg, [tool], differentiable=True)
    grad_sim.set_material(material)
    actions = np.tile(press, (grad_steps, 1))
    warm = simulate_episode(grad_sim, state, actions[:1])
    backpropagate_episode(grad_sim, warm, {"x": np.ones_like(warm.x)})
    _sync(arch)
    start = time.perf_counter()
    episode = simulate_episode(grad_sim, state, actions)
    _sync(arch)
    middle = time.perf_counter()
    backpropagate_episode(grad_sim, episode, {"x": np.ones_like(episode.x)})
    _sync(arch)
    end = time.perf_counter()
    fwd = middle - start
    result["forward_backward_mps"] = grad_steps * substeps * n_particles / (end - start) / 1e6
    result["forward_backward_over_forward"] = (end - start) / fwd
    result["peak_rss_mb"] = peak_rss_mb()
    return result


def measure_task(task: str, steps: int, arch: str = "cpu") -> dict:
    """Seconds for one episode of ``steps`` environment steps of a task at the small profile."""
    import numpy as np

    from pasta.config import load
    from pasta.sim.envs import default_configuration, make_env

    cfg = load(task, "small", [f"sim.arch={arch}"])
    env = make_env(cfg)
    configuration = default_configuration(cfg, np.random.default_rng(0))
    env.reset(configuration)
    action = np.zeros(env.action_dim, np.float32)
    env.step(action)
    env.reset(configuration)
    _sync(arch)
    start = time.perf_counter()
    for _ in range(steps):
        env.step(action)
    _sync(arch)
    seconds = time.perf_counter() - start
    return {"task": task, "profile": "small", "n_grid": cfg.sim.n_grid, "n_particles": cfg.sim.n_particles,
            "steps": steps, "seconds": seconds, "seconds_per_50_steps": seconds * 50 / steps,
            "peak_rss_mb": peak_rss_mb()}


def measure_cold_compile() -> dict:
    """Seconds to compile forward and gradient kernels with an empty offline cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache)
        start = time.perf_counter()
        run_child(["layout", "32", "2000", "1", "1"], env)
        cold = time.perf_counter() - start
        start = time.perf_counter()
        run_child(["layout", "32", "2000", "1", "1"], env)
        warm = time.perf_counter() - start
    return {"cold_s": cold, "warm_s": warm}


def run_child(args: list[str], env: dict | None = None, arch: Sequence[str] = ()) -> dict:
    out = subprocess.run([sys.executable, __file__, *arch, "--child", *args], capture_output=True, text=True,
                         env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def child_main(args: list[str], arch: str) -> None:
    if args[0] == "layout":
        n_grid, n_particles, steps, grad_steps = map(int, args[1:5])
        result = measure_layout(n_grid, n_particles, steps, grad_steps, arch)
    else:
        result = measure_task(args[1], int(args[2]), arch)
    print(json.dumps(result))


def print_table(layouts: list[dict], tasks: list[dict], compile_times: dict | None) -> None:
    print("\n| grid | particles | substeps/step | fwd M particle-substeps/s | fwd ms/substep "
          "| fwd+bwd M/s | (fwd+bwd)/fwd | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|")
    for r in layouts:
        print(f"| {r['n_grid']} | {r['n_particles']} | {r['substeps_per_step']} | {r['forward_mps']:.2f} "
              f"| {r['forward_ms_per_substep']:.2f} | {r['forward_backward_mps']:.2f} "
              f"| {r['forward_backward_over_forward']:.2f} | {r['peak_rss_mb']:.0f} |")
    if tasks:
        print("\n| task (small) | grid | particles | s per 50-step episode |")
        print("|---|---|---|---|")
        for r in tasks:
            print(f"| {r['task']} | {r['n_grid']} | {r['n_particles']} | {r['seconds_per_50_steps']:.1f} |")
    if compile_times:
        print(f"\nkernel compile, grid 32 / 2000 particles, forward + gradient kernels: "
              f"{compile_times['cold_s']:.0f} s cold, {compile_times['warm_s']:.0f} s with the offline cache")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="reduced set (a few minutes)")
    parser.add_argument("--compile", action="store_true", help="also time a cold kernel compile")
    parser.add_argument("--arch", default="cpu", choices=["cpu", "cuda"], help="Taichi architecture")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child_main(args.child, args.arch)
        return
    layouts = LAYOUTS_QUICK if args.quick else LAYOUTS_FULL
    steps, grad_steps, task_steps = (5, 2, 10) if args.quick else (20, 5, 50)
    arch = ["--arch", args.arch]
    layout_results = [run_child(["layout", str(g), str(n), str(steps), str(grad_steps)], arch=arch)
                      for g, n in layouts]
    task_results = [run_child(["task", task, str(task_steps)], arch=arch) for task in TASKS]
    compile_times = measure_cold_compile() if args.compile else None
    RESULTS.mkdir(parents=True, exist_ok=True)
    payload = {"quick": args.quick, "arch": args.arch, "cpu_count": os.cpu_count(), "layouts": layout_results,
               "tasks": task_results, "compile": compile_times, "measured_at": time.strftime("%Y-%m-%dT%H:%M:%S")}
    target = RESULTS / f"sim{'_quick' if args.quick else ''}{'' if args.arch == 'cpu' else '_' + args.arch}.json"
    tmp = target.with_suffix(".tmp")
    tmp.write_text(json.dumps(payload, indent=2))
    tmp.replace(target)
    print_table(layout_results, task_results, compile_times)
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
