"""Mirror augmentation of policy samples: the scene reflected in a vertical plane through the dough's centre.

Every tool of the tasks is symmetric under reflection in its own body axes (a knife, boxes, a two-finger
gripper, a cylinder), the floor is flat, and the skills act the same way on a mirrored scene, so a
demonstration reflected in the plane x = c_x (or z = c_z) through the observed dough's centre is another
valid demonstration. Reflecting the clouds is a sign flip of one coordinate about the centre; the actions
change as the reflection ``M`` (``diag(-1, 1, 1)`` or ``diag(1, 1, -1)``) changes the tool's motion:

* translations are vectors: ``v -> M v``;
* rotation rates are pseudovectors: ``w -> -M w``, whether the tool applies them in the world frame (box) or in
  its body frame (gripper: the mirrored pose is ``M R M``, and ``M R exp(w) M = (M R M) exp(-M w)``);
* a gripper's gap is unchanged;
* a rolling pin rolls and slides along ``y x axis``: a reflection in x turns that direction into minus the
  mirrored one (roll and slide change sign), a reflection in z does not; its yaw, a rotation about y, changes
  sign under both.

``train.policy_mirror`` draws, for every sample of every batch, identity or x (``x``), or one of identity, x, z
and both (``xz``).
"""

from __future__ import annotations

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.models import random_draws
from pasta.sim.engine import ACTION_DIMS

__all__ = ["MIRROR_SIGNS", "mirror_action_signs", "mirror_batch", "reflection_codes"]

# Per tool kind, the action signs under a reflection in x and in z, in the order of the tool's action vector.
MIRROR_SIGNS: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "knife": ((-1, 1, 1), (1, 1, -1)),                                   # x, y, z
    "box": ((-1, 1, 1, 1, -1, -1), (1, 1, -1, -1, -1, 1)),               # x, y, z, rot x, y, z (world)
    "gripper": ((-1, 1, 1, 1, -1, -1, 1), (1, 1, -1, -1, -1, 1, 1)),     # x, y, z, rot x, y, z (body), gap
    "rolling_pin": ((-1, -1, 1, -1, 1, 1), (1, -1, 1, 1, 1, 1)),         # roll, yaw, lift, slide, -, -
}


def mirror_action_signs(cfg: TaskConfig) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The task's full action vector's signs under a reflection in x and in z: each non-static tool's
    ``MIRROR_SIGNS``, concatenated in the order of ``cfg.tools`` (the order of the action vector)."""
    signs_x: list[float] = []
    signs_z: list[float] = []
    for tool in cfg.tools:
        if tool.static:
            continue
        if tool.kind not in MIRROR_SIGNS or len(tool.action_scales) != ACTION_DIMS[tool.kind]:
            raise ValueError(f"no mirror rule for tool {tool.name!r} of kind {tool.kind!r} with "
                             f"{len(tool.action_scales)} action dims")
        x, z = MIRROR_SIGNS[tool.kind]
        signs_x += x
        signs_z += z
    return tuple(signs_x), tuple(signs_z)


def reflection_codes(n: int, planes: str, generator: torch.Generator | None,
                     device: torch.device | str | None = None) -> torch.Tensor:
    """``(n,)`` codes for :func:`mirror_batch`, uniform over 0 (as it is) and 1 (in x) for ``planes`` ``x``, over
    0..3 (also 2: in z, 3: in both) for ``xz``."""
    if planes not in ("x", "xz"):
        raise ValueError(f"mirror planes must be 'x' or 'xz', got {planes!r}")
    return random_draws.randint(2 if planes == "x" else 4, (n,), generator, device=device)


def mirror_batch(obs: torch.Tensor, tool: torch.Tensor, goal: torch.Tensor, actions: torch.Tensor,
                 signs: tuple[tuple[float, ...], tuple[float, ...]], choice: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Reflect each sample as ``choice`` says: 0 as it is, 1 in x, 2 in z, 3 in both.

    Args:
        obs, tool, goal: clouds ``(B, N_i, 3)``; each sample is reflected about its observation's centre.
        actions: ``(B, H * A)``: a chunk of ``H`` actions of the full action vector (length ``A``).
        signs: :func:`mirror_action_signs`.
        choice: ``(B,)`` integers in 0..3.

    Returns:
        The reflected ``obs``, ``tool``, ``goal`` and ``actions``.
    """
    flip_x = (choice % 2 == 1).to(obs.dtype)  # (B,)
    flip_z = (choice >= 2).to(obs.dtype)
    one = torch.ones_like(flip_x)
    scale = torch.stack([1 - 2 * flip_x, one, 1 - 2 * flip_z], dim=1).unsqueeze(1)  # (B, 1, 3)
    centre = obs.mean(dim=1, keepdim=True) * obs.new_tensor([1.0, 0.0, 1.0])

    def reflect(cloud: torch.Tensor) -> torch.Tensor:
        return (cloud - centre) * scale + centre

    sx, sz = (actions.new_tensor(np.asarray(s, dtype=np.float32)) for s in signs)
    if actions.shape[1] % len(sx):
        raise ValueError(f"actions of width {actions.shape[1]} are not chunks of {len(sx)}-d actions")
    h = actions.shape[1] // len(sx)
    sx, sz = sx.repeat(h), sz.repeat(h)
    fx, fz = flip_x.to(actions.dtype).unsqueeze(1), flip_z.to(actions.dtype).unsqueeze(1)
    action_scale = (1 - fx + fx * sx) * (1 - fz + fz * sz)
    return reflect(obs), reflect(tool), reflect(goal), actions * action_scale
