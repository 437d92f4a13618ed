"""Run the gradient tests' tiny episode on one Taichi architecture and save its result (a child process:
Taichi runs one architecture per process).

    python -m tests.sim.arch_episode cuda out.npz
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from pasta.sim.engine import simulator_for
from tests.sim.test_gradients import MATERIAL, PUSHER, SIM, episode_loss, make_problem


def main(arch: str, out: str) -> None:
    sim = simulator_for(SIM.model_copy(update={"arch": arch}), [PUSHER], differentiable=True)
    sim.set_material(MATERIAL)
    state0, actions, weights_x, weights_v = make_problem(0)
    x0 = torch.tensor(state0["x"], dtype=torch.float64, requires_grad=True)
    actions.requires_grad_(True)
    loss = episode_loss(sim, state0, x0, actions, weights_x, weights_v)
    loss.backward()
    np.savez(out, loss=loss.item(), action_grad=actions.grad.numpy(), x0_grad=x0.grad.numpy())


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
