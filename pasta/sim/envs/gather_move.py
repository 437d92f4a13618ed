"""GatherMove (DiffSkill task; env_spec 2.2).

Squeeze scattered dough into one pile on the spatula with the gripper, then carry the pile onto
the cutting board with the spatula. Skills (``conf/tasks/GatherMove.yaml``):

* ``gather``: gripper, the scattered pieces in (1, 2 or 3: DBSCAN joins the small blobs into few
  pieces) -> 1 piece out;
* ``move``: spatula (a box), 1 piece in -> 1 piece out.

An episode is gather, move (horizon 2). The cutting board is a static tool.

Note: the official PASTA code defines PASTA skills (tool, entities in / out) only for
CutRearrange and CRS (``core/utils/pasta_utils.py``); these GatherMove skill definitions are
ours, following DiffSkill's use of the two tools.
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.sim.envs.base import DoughConfiguration, DoughEnv, build_configuration
from pasta.sim.shapes import ScatterPiece, floor_height

SEED_XZ_LOW = (0.64, 0.38)
SEED_XZ_HIGH = (0.76, 0.62)
SEED_Y_SPAN = 0.015


def default_configuration(cfg: TaskConfig, rng: np.random.Generator) -> DoughConfiguration:
    """The generator's scattered init (env_spec 1.7, 2.2): 40 seeds in x [0.64, 0.76],
    z [0.38, 0.62] and y in [floor, floor + 0.015], each with noisy copies (sigma 0.004) lifted by
    0.1, so the blobs drop onto the floor / spatula when the episode starts (the original let them
    drop for 10 steps). Tools at their configured poses. Distractors (``cfg.distractors``) are added.
    """
    floor = floor_height(cfg.sim)
    scatter = ScatterPiece(
        seed_low=(SEED_XZ_LOW[0], floor, SEED_XZ_LOW[1]),
        seed_high=(SEED_XZ_HIGH[0], floor + SEED_Y_SPAN, SEED_XZ_HIGH[1]),
    )
    return build_configuration(cfg, rng, [scatter])


class GatherMoveEnv(DoughEnv):
    __doc__ = __doc__
    task_names = ("GatherMove",)
    _default_configuration = staticmethod(default_configuration)
