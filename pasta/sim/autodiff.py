"""Reverse-mode gradients through whole episodes, with per-step checkpointing.

The forward pass keeps one checkpoint (particles and tool poses) per
environment step and, while they fit in the simulator's ``adjoint_memory_bytes``,
the step's substep frames with their SVDs and grids (``MPMSimulator.record_step``).
The backward pass walks the steps in reverse: it restores the step's substep
frames, or records them anew from its checkpoint where they were not kept, seeds
the adjoint of the step's last frame and runs the substep adjoints. Both ways
give the same gradients; keeping the frames spares the backward pass a forward
step's work per step.
"""

from dataclasses import dataclass

import numpy as np
import torch

from pasta.sim.engine import MPMSimulator

STATE_KEYS = ("x", "v", "C", "F", "tool_pos", "tool_rot", "tool_gap")


@dataclass
class Episode:
    """A simulated episode: per-step states and what the backward pass needs.

    ``x``, ``v``: (T + 1, N, 3); ``tool_pos``: (T + 1, K, 3); ``tool_rot``: (T + 1, K, 4);
    ``tool_gap``: (T + 1, K). ``checkpoints[t]`` is the full state before step t; ``recorded[t]``
    its record (``MPMSimulator.record_step``), or None where the backward pass records
    the step anew.
    """

    x: np.ndarray
    v: np.ndarray
    tool_pos: np.ndarray
    tool_rot: np.ndarray
    tool_gap: np.ndarray
    actions: np.ndarray
    checkpoints: list[dict[str, np.ndarray]]
    recorded: list[dict[str, np.ndarray] | None]


def simulate_episode(sim: MPMSimulator, state0: dict[str, np.ndarray], actions: np.ndarray) -> Episode:
    """Run ``actions`` (T, A) from ``state0``; keep a checkpoint per step and, on a differentiable
    simulator, the substep frames of the first steps that fit in ``sim.adjoint_memory_bytes``."""
    actions = np.asarray(actions, dtype=np.float32)
    sim.set_state(state0)
    checkpoints = [sim.get_state()]
    recorded: list[dict[str, np.ndarray] | None] = []
    kept_bytes = 0
    for t, action in enumerate(actions):
        if sim.differentiable:
            # Every step records, kept or not: the backward pass records the steps it was not given anew,
            # with the same kernel, so both give the same float rounding.
            step = sim.record_step(action, step=t)
            if kept_bytes + sim.recorded_bytes(step) <= sim.adjoint_memory_bytes:
                kept_bytes += sim.recorded_bytes(step)
                recorded.append(step)
            else:
                sim.release_recorded_step(step)  # its buffers serve the next step
                recorded.append(None)
        else:
            sim.run_substeps(action, step=t)
            recorded.append(None)
        sim.copy_frame(sim.substeps, 0)
        checkpoints.append(sim.get_state())
    stack = {key: np.stack([c[key] for c in checkpoints]) for key in STATE_KEYS}
    return Episode(stack["x"], stack["v"], stack["tool_pos"], stack["tool_rot"], stack["tool_gap"], actions,
                   checkpoints, recorded)


def backpropagate_episode(sim: MPMSimulator, episode: Episode,
                          grads: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Adjoints of the actions (T, A) and of the initial state, given adjoints of the per-step outputs.

    ``grads`` maps a subset of ``x, v, tool_pos, tool_rot, tool_gap`` to arrays shaped
    like the episode's (T + 1, ...) outputs.
    """
    if not sim.differentiable:
        raise RuntimeError("this simulator was built without gradients (differentiable=False)")
    T = len(episode.actions)
    action_grads = np.zeros_like(episode.actions)
    carried = {key: grads[key][T] for key in grads}
    for t in reversed(range(T)):
        recorded = episode.recorded[t]
        if recorded is None:
            # Recorded anew from its checkpoint, with the same kernel as a kept step: the same gradients.
            sim.set_state(episode.checkpoints[t])
            recorded = sim.record_step(episode.actions[t], step=t)
        sim.load_recorded_step(recorded)
        sim.load_action(episode.actions[t])
        sim.clear_tool_grads()
        sim.seed_state_grad(carried, sim.substeps)
        for f in reversed(range(sim.substeps)):
            sim.substep_grad(f)
        # The buffers go back for the next step or episode; a second backward pass records this step anew.
        sim.release_recorded_step(recorded)
        episode.recorded[t] = None
        action_grads[t] = sim.read_action_grad()
        carried = sim.read_state_grad(0)
        for key in grads:
            carried[key] = carried[key] + grads[key][t]
    return action_grads, carried


class EpisodeFunction(torch.autograd.Function):
    """Differentiable episode: (x0 (N, 3), actions (T, A)) -> (x, v (T+1, N, 3), tool_pos (T+1, K, 3)).

    The rest of the initial state (v, C, F, tool poses) comes from ``state0``.
    """

    @staticmethod
    def forward(ctx, x0, actions, sim, state0):
        start = dict(state0)
        start["x"] = x0.detach().cpu().numpy().astype(np.float32)
        episode = simulate_episode(sim, start, actions.detach().cpu().numpy())
        ctx.sim, ctx.episode = sim, episode
        ctx.device, ctx.dtype = x0.device, x0.dtype
        to = lambda a: torch.from_numpy(a).to(device=x0.device, dtype=x0.dtype)  # noqa: E731
        return to(episode.x), to(episode.v), to(episode.tool_pos)

    @staticmethod
    def backward(ctx, grad_x, grad_v, grad_tool_pos):
        grads = {}
        for key, g in (("x", grad_x), ("v", grad_v), ("tool_pos", grad_tool_pos)):
            if g is not None:
                grads[key] = g.detach().cpu().numpy().astype(np.float32)
        action_grads, initial = backpropagate_episode(ctx.sim, ctx.episode, grads)
        to = lambda a: torch.from_numpy(a).to(device=ctx.device, dtype=ctx.dtype)  # noqa: E731
        return to(initial["x"]), to(action_grads), None, None


def differentiable_episode(sim: MPMSimulator, state0: dict[str, np.ndarray], x0: torch.Tensor,
                           actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Simulate ``actions`` (T, A) from ``state0`` with initial positions ``x0`` (N, 3).

    Returns particle positions and velocities (T + 1, N, 3) and tool positions
    (T + 1, K, 3), differentiable with respect to ``x0`` and ``actions``.
    """
    return EpisodeFunction.apply(x0, actions, sim, state0)
