"""A short scripted simulator demo of one task, rendered to a strip PNG and a GIF.

``pasta sim-demo --task CutRearrange [--profile smoke] [--out DIR]`` calls :func:`main`. It builds
the task's environment, resets a default configuration (seed 0) and runs a scripted motion of
the first skill's tool:

* knife (CutRearrange, CRS, CRS-Twice): move above the dough's centre, descend through the dough
  to just below the floor, slide the left piece 0.09 away (-x), lift back up. The slide is what
  the original generator's cut targets do (one piece moved 0.1 away, env_spec 2.3): a plain
  down-and-up cut leaves a sheet of dough in the 0.05-wide slot that still joins the halves. At
  grids coarser than about 64 cells the 0.05-thick knife spans under two cells and drags the
  dough instead of cutting it, so the smoke demo (grid 32) ends with one piece; at the paper
  grid (80) it ends with two;
* spatula (LiftSpread): rise under the ball, then carry it towards the board;
* gripper (GatherMove): let the scattered dough drop, close the fingers, open them again.

Frames are rendered every few steps into ``<out>/<task>_<profile>.png`` (and ``.gif``), where
``out`` defaults to ``$PASTA_HOME/demos/<task>/``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pasta.config import load
from pasta.paths import pasta_home
from pasta.sim.envs import DoughEnv, make_env

RENDER_EVERY = 4


def _repeat(env: DoughEnv, tool: str, tool_action: list[float], n: float) -> Iterator[np.ndarray]:
    """``n`` steps of ``tool_action`` (a fractional last step scales the action)."""
    full, frac = int(math.floor(n)), n - math.floor(n)
    for _ in range(full):
        yield env.action_for(tool, tool_action)
    if frac > 1e-6:
        yield env.action_for(tool, [frac * a for a in tool_action])


def cut_script(env: DoughEnv, tool: str = "knife", slide: float = 0.09) -> Iterator[np.ndarray]:
    """Knife above the dough centre, down to 0.01 below the floor, ``slide`` to -x, back up."""
    knife = env.tool(tool)
    x = env.particles()
    centre = x.mean(axis=0)
    start = env.tool_poses()[tool]
    env.teleport_tool(tool, (float(centre[0]), start.pos[1], float(centre[2])))
    yield from _repeat(env, tool, [0.0, 0.0, 0.0], 3)  # let the dough settle onto the floor
    bottom = env.floor_y - 0.01
    descent = (start.pos[1] - knife.blade_depth - bottom) / knife.action_scales[1]
    yield from _repeat(env, tool, [0.0, -1.0, 0.0], descent)
    yield from _repeat(env, tool, [-1.0, 0.0, 0.0], slide / knife.action_scales[0])
    yield from _repeat(env, tool, [0.0, 1.0, 0.0], descent)
    yield from _repeat(env, tool, [0.0, 0.0, 0.0], 2)


def lift_script(env: DoughEnv, tool: str = "spatula") -> Iterator[np.ndarray]:
    """Spatula up under the ball, then towards the board (-x)."""
    yield from _repeat(env, tool, [0.0, 1.0, 0.0, 0.0, 0.0, 0.0], 8)
    yield from _repeat(env, tool, [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 12)
    yield from _repeat(env, tool, [0.0] * 6, 3)


def gather_script(env: DoughEnv, tool: str = "gripper") -> Iterator[np.ndarray]:
    """Let the blobs drop, close the gripper (positive gap action) and open it again."""
    yield from _repeat(env, tool, [0.0] * 7, 8)
    yield from _repeat(env, tool, [0.0] * 6 + [1.0], 10)
    yield from _repeat(env, tool, [0.0] * 6 + [-1.0], 5)


SCRIPTS = {"knife": cut_script, "box": lift_script, "gripper": gather_script}


def run_demo(env: DoughEnv, seed: int = 0, render_every: int = RENDER_EVERY) -> list[dict]:
    """Reset a default configuration, run the first skill's script; return the frames rendered."""
    env.reset(env.default_configuration(np.random.default_rng(seed)))
    skill = env.skills[0]
    tool = env.tool(skill.tool)
    if tool.kind not in SCRIPTS:
        raise ValueError(f"no demo script for a {tool.kind!r} tool (skill {skill.name!r})")

    def frame(label: str) -> dict:
        obs = env.observation()
        return {
            "dough_points": obs.dough_points,
            "tool_points": dict(obs.tool_points),
            "title": f"{env.task} {skill.name}: {label}",
        }

    frames = [frame("start")]
    last = None
    for action in SCRIPTS[tool.kind](env, skill.tool):
        env.step(action)
        last = env.step_count
        if last % render_every == 0:
            frames.append(frame(f"step {last}"))
    if last is not None and last % render_every != 0:
        frames.append(frame(f"step {last}"))
    return frames


def count_pieces(points: np.ndarray, eps: float = 0.03, min_samples: int = 6) -> int:
    """Number of DBSCAN clusters (noise excluded) in a point cloud."""
    from sklearn.cluster import DBSCAN

    labels = DBSCAN(eps=eps, min_samples=min_samples).fit(np.asarray(points)).labels_
    return len(set(labels.tolist()) - {-1})


def main(task: str = "CutRearrange", profile: str = "smoke", out: str | Path | None = None,
         gif: bool = True) -> Path:
    """Run the demo of ``task`` at ``profile``; write and print the strip PNG's path, and return it."""
    from pasta.sim.render import render_strip

    cfg = load(task, profile)
    env = make_env(cfg)
    frames = run_demo(env)
    folder = Path(out) if out is not None else pasta_home() / "demos" / task
    folder.mkdir(parents=True, exist_ok=True)
    png = folder / f"{task}_{profile}.png"
    render_strip(frames, png, gif_path=folder / f"{task}_{profile}.gif" if gif else None)
    pieces = count_pieces(env.particles(), cfg.data.dbscan_eps, cfg.data.dbscan_min_samples)
    print(f"{task} ({profile}): {env.step_count} steps, {pieces} dough piece(s) at the end (DBSCAN)")
    print(png)
    return png
