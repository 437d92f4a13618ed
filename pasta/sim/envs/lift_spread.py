"""LiftSpread (DiffSkill task, also in PASTA; env_spec 2.1).

Lift a ball of dough from the table onto the cutting board with the spatula, then flatten it
with the rolling pin. Skills (``conf/tasks/LiftSpread.yaml``):

* ``lift``: spatula (a box), 1 piece in -> 1 piece out;
* ``spread``: rolling pin, 1 piece in -> 1 piece out.

An episode is lift, spread (horizon 2). The cutting board is a static tool.

Note: the official PASTA code defines PASTA skills (tool, entities in / out) only for
CutRearrange and CRS (``core/utils/pasta_utils.py``); these LiftSpread skill definitions are
ours, following DiffSkill's use of the two tools.
"""

from __future__ import annotations

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.sim.envs.base import DoughConfiguration, DoughEnv, ToolPose, build_configuration
from pasta.sim.shapes import SpherePiece, floor_height

RADII = np.linspace(0.04, 0.07, 10)
DOUGH_X = 0.65


def default_configuration(cfg: TaskConfig, rng: np.random.Generator) -> DoughConfiguration:
    """The generator's table init ("case11", env_spec 2.1): a ball of radius from
    linspace(0.04, 0.07, 10) at x = 0.65, z = 0.5 above the spatula, resting on the spatula or
    the floor, whichever is higher. The rolling pin sits at x = 0.3 + U(-0.08, 0.02),
    y = max(2r + 0.1, dough top) + U(0.04, 0.14) (at least its lower bound), z = 0.5.
    """
    floor = floor_height(cfg.sim)
    r = float(rng.choice(RADII))
    spatula = next(t for t in cfg.tools if t.name == "spatula")
    support = max(floor, spatula.position[1] + spatula.half_extents[1])
    dough = SpherePiece(centre=(DOUGH_X, support + r, 0.5), radius=r)
    pin = next(t for t in cfg.tools if t.kind == "rolling_pin")
    pin_y = max(2 * r + 0.1, support + 2 * r) + rng.uniform(0.04, 0.14)
    pin_pose = ToolPose(pos=(0.3 + rng.uniform(-0.08, 0.02), max(pin_y, pin.lower_bound[1]), 0.5),
                        rot=pin.rotation)
    return build_configuration(cfg, rng, [dough], {pin.name: pin_pose})


class LiftSpreadEnv(DoughEnv):
    __doc__ = __doc__
    task_names = ("LiftSpread",)
    _default_configuration = staticmethod(default_configuration)
