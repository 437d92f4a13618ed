"""CutRearrange (DiffSkill + PASTA; env_spec 2.3).

Cut a box of dough in two with the knife, then move each piece to its target with the gripper.
Skills (``conf/tasks/CutRearrange.yaml``; PASTA's own definition, ``core/utils/pasta_utils.py``):

* ``cut``: knife, 1 piece in -> 2 pieces out;
* ``rearrange``: gripper, 1 piece in -> 1 piece out.

An episode is cut, rearrange, rearrange (horizon 3). Tools: knife (3 action dims, z not
actuated), gripper (7 dims; a positive gap action closes it).
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import TaskConfig, ToolConfig
from pasta.sim.envs.base import DoughConfiguration, DoughEnv, ToolPose, build_configuration
from pasta.sim.shapes import BoxPiece, floor_height

DOUGH_HEIGHT = 0.08
KNIFE_CLEARANCE = 0.03


def knife_pose_above(knife: ToolConfig, x: float, z: float, dough_top: float,
                     clearance: float = KNIFE_CLEARANCE) -> ToolPose:
    """The knife over (x, z), at its configured height or higher so its edge clears ``dough_top``.

    At coarse grids the floor, and so the dough, sits higher than in the original (see
    :func:`pasta.sim.shapes.floor_height`); the configured knife height 0.3 (edge at 0.15) would
    then cut into the dough before the skill starts.
    """
    y = max(knife.position[1], dough_top + knife.blade_depth + clearance)
    return ToolPose(pos=(x, y, z), rot=knife.rotation)


def default_configuration(cfg: TaskConfig, rng: np.random.Generator) -> DoughConfiguration:
    """The generator's whole-dough init (env_spec 2.3): a box of size (U(0.2, 0.24), 0.08,
    U(0.04, 0.08)) centred at x = z = 0.5, its bottom on the floor, the knife above its centre
    and the gripper at its configured pose. Distractors (``cfg.distractors``) are added on the floor.
    """
    floor = floor_height(cfg.sim)
    half = (0.5 * rng.uniform(0.2, 0.24), 0.5 * DOUGH_HEIGHT, 0.5 * rng.uniform(0.04, 0.08))
    dough = BoxPiece(centre=(0.5, floor + half[1], 0.5), half_extents=half)
    knife = next(t for t in cfg.tools if t.kind == "knife")
    poses = {knife.name: knife_pose_above(knife, 0.5, 0.5, floor + DOUGH_HEIGHT)}
    return build_configuration(cfg, rng, [dough], poses)


class CutRearrangeEnv(DoughEnv):
    __doc__ = __doc__
    task_names = ("CutRearrange",)
    _default_configuration = staticmethod(default_configuration)
