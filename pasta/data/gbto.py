"""Gradient-based trajectory optimisation (GBTO) of one skill's actions through the simulator.

Adam on the per-step actions of the skill's tool (env_spec.md section 5): the loss is
the shape distance between the dough and the target on a particle subsample,
summed over the steps as in the official solver, plus a contact term pulling the
tool towards the dough and a penalty on the final mean velocity. Actions outside
the tool's slice stay zero; every iterate is clamped to [-1, 1]; the best iterate
is kept.
"""

from dataclasses import dataclass

import numpy as np
import torch

from pasta.geometry.distances import chamfer_distance
from pasta.sim.autodiff import differentiable_episode
from pasta.sim.engine import MPMSimulator


@dataclass(frozen=True)
class GBTOSettings:
    """Optimiser settings (env_spec.md section 5.3; iterations scale with the profile)."""

    iterations: int
    lr: float
    velocity_weight: float
    contact_weight: float = 1e-3
    loss_points: int = 500
    softness: float = 666.0


@dataclass(frozen=True)
class GBTOResult:
    """The best action sequence (T, A), its loss, the first iterate's loss and the loss curve."""

    actions: np.ndarray
    best_loss: float
    initial_loss: float
    losses: np.ndarray


def trajectory_loss(
    xs: torch.Tensor,
    vs: torch.Tensor,
    tool_pos: torch.Tensor,
    target: torch.Tensor,
    tool_index: int,
    contact_reach: float,
    settings: GBTOSettings,
) -> torch.Tensor:
    """Loss of one rollout.

    Args:
        xs, vs: particle positions and velocities of the subsample, (T + 1, P, 3).
        tool_pos: tool positions (T + 1, K, 3).
        target: target points (P, 3).
        tool_index: the acting tool; its distance to the nearest particle beyond ``contact_reach``
            is penalised at every step.
    """
    steps = xs.shape[0] - 1
    shape = chamfer_distance(xs[1:], target.expand(steps, -1, -1)).mean()
    gaps = torch.cdist(tool_pos[1:, tool_index : tool_index + 1], xs[1:]).amin(dim=(1, 2))
    contact = torch.clamp(gaps - contact_reach, min=0.0).pow(2).mean()
    velocity = vs[-1].mean(dim=0).pow(2).sum()
    return shape + settings.contact_weight * contact + settings.velocity_weight * velocity


def optimise_actions(
    sim: MPMSimulator,
    state0: dict[str, np.ndarray],
    target_points: np.ndarray,
    tool_index: int,
    contact_reach: float,
    initial_actions: np.ndarray,
    settings: GBTOSettings,
    rng: np.random.Generator,
) -> GBTOResult:
    """Optimise the actions of tool ``tool_index`` so the dough reaches ``target_points``.

    Args:
        sim: a simulator built with ``differentiable=True``.
        state0: the start state (``MPMSimulator.get_state()``).
        target_points: (P, 3) target point cloud.
        initial_actions: (T, A) warm start (zeros, or a scripted skill's actions).
        rng: draws the particle subsample used by the loss at each iteration.
    """
    if not sim.differentiable:
        raise ValueError("GBTO needs a simulator built with differentiable=True")
    start = sim.action_offsets[tool_index]
    width = {"box": 6, "knife": 3, "gripper": 7, "rolling_pin": 6}[sim.tool_kinds[tool_index]]
    mask = torch.zeros(initial_actions.shape[1], dtype=torch.float64)
    mask[start : start + width] = 1.0
    actions = torch.tensor(np.clip(initial_actions, -1.0, 1.0), dtype=torch.float64) * mask
    actions.requires_grad_(True)
    optimiser = torch.optim.Adam([actions], lr=settings.lr)
    target = torch.tensor(np.asarray(target_points), dtype=torch.float64)
    x0 = torch.tensor(np.asarray(state0["x"]), dtype=torch.float64)
    previous_softness = float(sim.softness[None])
    sim.set_softness(settings.softness)
    losses, best_loss, best_actions = [], float("inf"), actions.detach().clone()
    try:
        for _ in range(max(settings.iterations, 1)):
            n = x0.shape[0]
            idx = torch.as_tensor(rng.choice(n, size=min(settings.loss_points, n), replace=False))
            tidx = torch.as_tensor(
                rng.choice(
                    len(target),
                    size=min(settings.loss_points, len(target)),
                    replace=len(target) < settings.loss_points,
                )
            )
            optimiser.zero_grad()
            xs, vs, tool_pos = differentiable_episode(sim, state0, x0, actions)
            loss = trajectory_loss(
                xs[:, idx], vs[:, idx], tool_pos, target[tidx], tool_index, contact_reach, settings
            )
            value = float(loss.detach())
            losses.append(value)
            if value < best_loss:
                best_loss, best_actions = value, actions.detach().clone()
            if settings.iterations == 0:
                break
            loss.backward()
            optimiser.step()
            with torch.no_grad():
                actions.clamp_(-1.0, 1.0)
                actions.mul_(mask)
    finally:
        sim.set_softness(previous_softness)
    return GBTOResult(best_actions.numpy().astype(np.float32), best_loss, losses[0], np.asarray(losses))
