"""Simulator speed and memory: forward and forward+backward throughput, episode time per task.

Each measurement runs in its own process (Taichi is one runtime per process and
peak memory is per process), ``--repeats`` times (default 3), the repeats of all
configurations interleaved so that a change in background load hits them alike;
the table shows each configuration's median. Within a process, the plain forward
pass and the differentiable episode's forward and backward passes run in turn,
``ROUNDS`` times, and each part's fastest round counts. Every measurement is made with each
3x3 SVD of ``--svd`` (``SimConfig.svd``: Taichi's built-in and the closed-form
``pasta.sim.svd3``), side by side, and with ``--baseline REV`` also with the
simulator of a git revision (its ``pasta`` and ``conf`` trees, extracted with
``git archive`` and put first on the children's ``PYTHONPATH``), so that a change
is measured against the code before it in the same run. Prints a table with the
load average and the CPU count, and writes JSON to ``benchmarks/results/sim.json``.

    python benchmarks/sim.py            # full set
    python benchmarks/sim.py --quick    # reduced set (one task), a few minutes
    python benchmarks/sim.py --svd fast --repeats 5
    python benchmarks/sim.py --quick --svd fast --baseline HEAD  # this tree against the last commit
    python benchmarks/sim.py --compile  # also time a cold kernel compile (empty cache)
    python benchmarks/sim.py --arch cuda  # Taichi on a GPU (writes sim_cuda.json)
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import get_args

from pasta.config.schema import SimConfig
from pasta.data.storage import atomic_write_bytes

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / "benchmarks" / "results"
WORKING_TREE = "working tree"
LAYOUTS_FULL = [(32, 5000), (48, 8000), (64, 30000)]
LAYOUTS_QUICK = [(32, 5000), (48, 8000)]
TASKS = ["LiftSpread", "GatherMove", "CutRearrange", "CRS", "CRS-Twice"]
TASKS_QUICK = ["CutRearrange"]
SVD_CHOICES = get_args(SimConfig.model_fields["svd"].annotation)  # the schema's: ("taichi", "fast")


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


ROUNDS = 3  # in-process rounds per measurement (measure_layout)


def measure_layout(n_grid: int, n_particles: int, steps: int, grad_steps: int, arch: str = "cpu",
                   svd: str = "taichi") -> dict:
    """Throughput of one (grid, particles) layout with one SVD method: a box pressing a block."""
    import numpy as np

    from pasta.config.schema import MaterialConfig, SimConfig, ToolConfig
    from pasta.sim.autodiff import backpropagate_episode, simulate_episode
    from pasta.sim.engine import simulator_for

    dt, substeps = substeps_for(n_grid)
    sim_cfg = SimConfig(n_grid=n_grid, dt_s=dt, substeps_per_step=substeps, n_particles=n_particles,
                        gravity_m_s2=(0, -600, 0), contact_softness=666.0, arch=arch, svd=svd)
    material = MaterialConfig(youngs_modulus_pa=5e3, poisson_ratio=0.15, yield_stress_pa=150, ground_friction=0.5)
    tool = ToolConfig(name="pusher", kind="box", position=(0.5, 0.2, 0.5), half_extents=(0.06, 0.02, 0.06),
                      action_scales=(0.01, 0.01, 0.01, 0.0, 0.0, 0.0), friction=1.0)
    rng = np.random.default_rng(0)
    x = rng.uniform([0.35, 0.1, 0.35], [0.65, 0.18, 0.65], (n_particles, 3)).astype(np.float32)
    state = {"x": x, "tool_pos": np.array([[0.5, 0.2, 0.5]]), "tool_rot": np.array([[1.0, 0, 0, 0]]),
             "tool_gap": np.zeros(1)}
    press = np.array([0.0, -0.3, 0.0, 0.0, 0.0, 0.0], np.float32)
    result = {"n_grid": n_grid, "n_particles": n_particles, "substeps_per_step": substeps, "svd": svd}

    sim = simulator_for(sim_cfg, [tool], differentiable=False)
    sim.set_material(material)
    sim.set_state(state)
    sim.step(press)  # compile / load kernels
    grad_sim = simulator_for(sim_cfg, [tool], differentiable=True)
    grad_sim.set_material(material)
    actions = np.tile(press, (grad_steps, 1))
    # One warm-up episode of the same length compiles the kernels and leaves the kept steps' buffers for
    # reuse, as GBTO's iterations after its first find them.
    warm = simulate_episode(grad_sim, state, actions)
    backpropagate_episode(grad_sim, warm, {"x": np.ones_like(warm.x)})

    # Rounds of plain forward, differentiable forward and backward in turn; each part's fastest round
    # counts (the least disturbed by the hypervisor and other jobs, which hit all parts alike).
    forward_s = episode_s = backward_s = float("inf")
    for _ in range(ROUNDS):
        sim.set_state(state)
        _sync(arch)
        start = time.perf_counter()
        for t in range(steps):
            sim.step(press, step=t)
        _sync(arch)
        forward_s = min(forward_s, time.perf_counter() - start)
        start = time.perf_counter()
        episode = simulate_episode(grad_sim, state, actions)
        _sync(arch)
        middle = time.perf_counter()
        backpropagate_episode(grad_sim, episode, {"x": np.ones_like(episode.x)})
        _sync(arch)
        episode_s = min(episode_s, middle - start)
        backward_s = min(backward_s, time.perf_counter() - middle)
    result["forward_mps"] = steps * substeps * n_particles / forward_s / 1e6
    result["forward_ms_per_substep"] = forward_s / (steps * substeps) * 1e3
    result["forward_backward_mps"] = grad_steps * substeps * n_particles / (episode_s + backward_s) / 1e6
    # Per substep, the differentiable episode (its forward pass, which keeps what the backward pass needs, and
    # the backward pass) against the plain forward pass above.
    result["forward_backward_over_forward"] = result["forward_mps"] / result["forward_backward_mps"]
    result["backward_over_forward"] = backward_s / (grad_steps * substeps) / (forward_s / (steps * substeps))
    result["peak_rss_mb"] = peak_rss_mb()
    return result


def measure_task(task: str, steps: int, arch: str = "cpu", svd: str = "taichi") -> dict:
    """Seconds for one episode of ``steps`` environment steps of a task at the small profile."""
    import numpy as np

    from pasta.config import load
    from pasta.sim.envs import default_configuration, make_env

    cfg = load(task, "small", [f"sim.arch={arch}", f"sim.svd={svd}"])
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
    return {"task": task, "profile": "small", "svd": svd, "n_grid": cfg.sim.n_grid, "n_particles": cfg.sim.n_particles,
            "steps": steps, "seconds": seconds, "seconds_per_50_steps": seconds * 50 / steps,
            "peak_rss_mb": peak_rss_mb()}


def measure_cold_compile() -> dict:
    """Seconds to compile forward and gradient kernels with an empty offline cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, TI_OFFLINE_CACHE_FILE_PATH=cache)
        start = time.perf_counter()
        run_child(["layout", "32", "2000", "1", "1", "taichi"], env)
        cold = time.perf_counter() - start
        start = time.perf_counter()
        run_child(["layout", "32", "2000", "1", "1", "taichi"], env)
        warm = time.perf_counter() - start
    return {"cold_s": cold, "warm_s": warm}


def run_child(args: list[str], env: dict | None = None, arch: Sequence[str] = ()) -> dict:
    out = subprocess.run([sys.executable, __file__, *arch, "--child", *args], capture_output=True, text=True,
                         env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def extract_revision(revision: str, into: Path) -> dict:
    """Extract ``pasta`` and ``conf`` of a git revision into ``into``; the environment that imports them."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", revision, "pasta", "conf"], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    path = os.pathsep.join(p for p in (str(into), os.environ.get("PYTHONPATH", "")) if p)
    return dict(os.environ, PYTHONPATH=path, PASTA_CONF_DIR=str(into / "conf"))


def child_main(args: list[str], arch: str) -> None:
    if args[0] == "layout":
        n_grid, n_particles, steps, grad_steps = map(int, args[1:5])
        result = measure_layout(n_grid, n_particles, steps, grad_steps, arch, args[5])
    else:
        result = measure_task(args[1], int(args[2]), arch, args[3])
    print(json.dumps(result))


def median_result(runs: list[dict]) -> dict:
    """The first run's entries with every float replaced by its median over ``runs``; ``runs``: their number."""
    result = {key: statistics.median(r[key] for r in runs) if isinstance(value, float) else value
              for key, value in runs[0].items()}
    result["runs"] = len(runs)
    return result


def run_repeated(configurations: list[list[str]], repeats: int, arch: Sequence[str],
                 codes: dict[str, dict | None]) -> list[dict]:
    """Median results of each child configuration with each code (label: the children's environment, None
    for this process's), run ``repeats`` times in rounds over all of them; each result names its ``code``."""
    jobs = [(args, label) for args in configurations for label in codes]
    runs: list[list[dict]] = [[] for _ in jobs]
    for _ in range(repeats):
        for done, (args, label) in zip(runs, jobs, strict=True):
            done.append(run_child(args, env=codes[label], arch=arch))
    return [dict(median_result(r), code=label) for r, (_, label) in zip(runs, jobs, strict=True)]


def svd_choices(text: str) -> list[str]:
    """``--svd``: a comma-separated list of ``SVD_CHOICES``."""
    choices = [c.strip() for c in text.split(",") if c.strip()]
    unknown = sorted(set(choices) - set(SVD_CHOICES))
    if not choices or unknown:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of {', '.join(SVD_CHOICES)}, got {text!r}")
    return list(dict.fromkeys(choices))


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def print_table(payload: dict) -> None:
    layouts, tasks, compile_times = payload["layouts"], payload["tasks"], payload["compile"]
    print(f"\n{payload['cpu_count']} CPUs (os.cpu_count()); load average (1, 5, 15 min) "
          f"{payload['load_average_start']} at the start, {payload['load_average_end']} at the end; "
          f"medians of {payload['repeats']} runs")
    print("\n| code | grid | particles | substeps/step | svd | fwd M particle-substeps/s | fwd ms/substep "
          "| fwd+bwd M/s | (fwd+bwd)/fwd | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in layouts:
        print(f"| {r['code']} | {r['n_grid']} | {r['n_particles']} | {r['substeps_per_step']} | {r['svd']} "
              f"| {r['forward_mps']:.2f} | {r['forward_ms_per_substep']:.2f} | {r['forward_backward_mps']:.2f} "
              f"| {r['forward_backward_over_forward']:.2f} | {r['peak_rss_mb']:.0f} |")
    by_layout = {(r["code"], r["n_grid"], r["n_particles"], r["svd"]): r for r in layouts}
    for (code, g, n, svd), r in by_layout.items():
        if svd == "fast" and (code, g, n, "taichi") in by_layout:
            base = by_layout[code, g, n, "taichi"]
            print(f"{code}, grid {g}, {n} particles: svd fast / taichi throughput, forward "
                  f"{r['forward_mps'] / base['forward_mps']:.2f}x, forward+backward "
                  f"{r['forward_backward_mps'] / base['forward_backward_mps']:.2f}x")
        if code == WORKING_TREE and payload["baseline"] and (payload["baseline"], g, n, svd) in by_layout:
            base = by_layout[payload["baseline"], g, n, svd]
            print(f"grid {g}, {n} particles, svd {svd}: {WORKING_TREE} / {payload['baseline']} throughput, forward "
                  f"{r['forward_mps'] / base['forward_mps']:.2f}x, forward+backward "
                  f"{r['forward_backward_mps'] / base['forward_backward_mps']:.2f}x")
    if tasks:
        print("\n| code | task (small) | grid | particles | svd | s per 50-step episode |")
        print("|---|---|---|---|---|---|")
        for r in tasks:
            print(f"| {r['code']} | {r['task']} | {r['n_grid']} | {r['n_particles']} | {r['svd']} "
                  f"| {r['seconds_per_50_steps']:.1f} |")
    if compile_times:
        print(f"\nkernel compile, grid 32 / 2000 particles, forward + gradient kernels: "
              f"{compile_times['cold_s']:.0f} s cold, {compile_times['warm_s']:.0f} s with the offline cache")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="reduced set (a few minutes)")
    parser.add_argument("--svd", type=svd_choices, default=list(SVD_CHOICES),
                        help="comma-separated 3x3 SVD methods to compare (default: taichi,fast)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration, median reported (default 3)")
    parser.add_argument("--baseline", metavar="REV",
                        help="also measure the simulator of this git revision (e.g. HEAD), side by side")
    parser.add_argument("--compile", action="store_true", help="also time a cold kernel compile")
    parser.add_argument("--arch", default="cpu", choices=["cpu", "cuda"], help="Taichi architecture")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child_main(args.child, args.arch)
        return
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    layouts = LAYOUTS_QUICK if args.quick else LAYOUTS_FULL
    tasks = TASKS_QUICK if args.quick else TASKS
    steps, grad_steps, task_steps = (10, 4, 10) if args.quick else (20, 5, 50)
    arch = ["--arch", args.arch]
    with tempfile.TemporaryDirectory() as baseline_dir:
        codes: dict[str, dict | None] = {WORKING_TREE: None}
        if args.baseline:
            codes[args.baseline] = extract_revision(args.baseline, Path(baseline_dir))
        load_start = load_average()
        layout_results = run_repeated([["layout", str(g), str(n), str(steps), str(grad_steps), svd]
                                       for g, n in layouts for svd in args.svd], args.repeats, arch, codes)
        task_results = run_repeated([["task", task, str(task_steps), svd] for task in tasks for svd in args.svd],
                                    args.repeats, arch, codes)
    compile_times = measure_cold_compile() if args.compile else None
    payload = {"quick": args.quick, "arch": args.arch, "cpu_count": os.cpu_count(), "svd": args.svd,
               "baseline": args.baseline, "repeats": args.repeats, "load_average_start": load_start,
               "load_average_end": load_average(), "layouts": layout_results, "tasks": task_results,
               "compile": compile_times, "measured_at": time.strftime("%Y-%m-%dT%H:%M:%S")}
    target = RESULTS / f"sim{'_quick' if args.quick else ''}{'' if args.arch == 'cpu' else '_' + args.arch}.json"
    data = json.dumps(payload, indent=2).encode()
    atomic_write_bytes(target, lambda handle: handle.write(data))
    print_table(payload)
    print(f"\nwrote {target}")


if __name__ == "__main__":
    main()
