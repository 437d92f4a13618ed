"""CutRearrangeSpread (CRS) and CRS-Twice (PASTA; env_spec 2.4).

Cut the dough with the knife, push one piece to its place with the pusher, and flatten it with
the roller. Skills (``conf/tasks/CRS.yaml``; PASTA's ``core/utils/pasta_utils.py``):

* ``cut``: knife, 1 piece in -> 2 pieces out;
* ``push``: pusher (a box), 1 piece in -> 1 piece out;
* ``spread``: roller (a rolling pin), 1 piece in -> 1 piece out.

CRS is cut, push, spread (horizon 3). CRS-Twice is the same environment with horizon 6 (cut,
push, spread, cut, push, spread); only its default dough is longer, so that it can be cut twice.
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.sim.envs.base import DoughConfiguration, DoughEnv, build_configuration
from pasta.sim.envs.cut_rearrange import DOUGH_HEIGHT, knife_pose_above
from pasta.sim.shapes import BoxPiece, floor_height

RIGHT_END_X = 0.9


def default_configuration(cfg: TaskConfig, rng: np.random.Generator) -> DoughConfiguration:
    """The generator's test init (env_spec 2.4): a box of height 0.08 whose right end is at
    x = 0.9, its bottom on the floor, the knife above its centre, pusher and roller at their back
    poses. CRS: length U(0.2, 0.35), z-width U(0.06, 0.08), z = 0.5 + U(-0.2, 0.2). CRS-Twice:
    length U(0.34, 0.35), z = 0.5 + U(-0.15, 0.15). Distractors (``cfg.distractors``) are added.
    """
    floor = floor_height(cfg.sim)
    twice = cfg.task == "CRS-Twice"
    length = rng.uniform(0.34, 0.35) if twice else rng.uniform(0.2, 0.35)
    width = rng.uniform(0.06, 0.08)
    z = 0.5 + rng.uniform(-0.15, 0.15) if twice else 0.5 + rng.uniform(-0.2, 0.2)
    half = (0.5 * length, 0.5 * DOUGH_HEIGHT, 0.5 * width)
    centre = (RIGHT_END_X - half[0], floor + half[1], z)
    dough = BoxPiece(centre=centre, half_extents=half)
    knife = next(t for t in cfg.tools if t.kind == "knife")
    poses = {knife.name: knife_pose_above(knife, centre[0], centre[2], floor + DOUGH_HEIGHT)}
    return build_configuration(cfg, rng, [dough], poses)


class CRSEnv(DoughEnv):
    __doc__ = __doc__
    task_names = ("CRS", "CRS-Twice")
    _default_configuration = staticmethod(default_configuration)
