"""Aim search: a scripted skill run with a few aims in the simulator, the one that ends nearest its subgoal kept.

A scripted skill is open loop and errs the same way on the same scene (a pushed piece stops short, a pressed
piece springs back, a cut throws its halves). Telling it that its destination lies a little further, or is a
little thinner (an :class:`~pasta.data.skills.aim.Aim`), corrects such an error without changing the script.
The search is a pattern search over the aim's few meaningful coordinates for the skill: from the identity,
each coordinate is tried one step either way, a better aim is kept, and the steps are halved once no
coordinate improves, until the budget of simulated rollouts is spent. Every rollout starts from the same
state and ends as the caller's execution would (the skill's steps, then ``settle_steps`` of rest); the score
is the exact EMD between the observed dough and the subgoal, the task's metric. An aim is only kept when the
dough ends in as many DBSCAN pieces as the subgoal has (or as the script's own rollout left): a cut that
leaves its halves joined by a smear can end nearer its subgoal in EMD and still ruin the next skill, which
then moves the whole dough. The identity is the first rollout, so the aim found is never worse on that
score than the script's own.

Within a plan, a skill's own subgoal is a poor judge: an aim that brings the cut's pieces nearer the cut
subgoal can leave them in a shape the push and the spread then make worse (CRS configuration 4, oracle plan:
0.852 with the scripts alone, 0.829 with each skill's aim chosen on its own subgoal). With ``rest``, each
rollout is followed by the plan's remaining skills, scripted with their own aims, and scored on the final
goal; each skill's search then includes the scripts' own continuation, so the plan ends no further from its
goal than the scripts alone would leave it (up to the simulator's summation order on several threads).

It uses the true simulator as its model, like the demonstrations' trajectory optimisation (GBTO), and costs
``budget`` rollouts of the skill (and of the rest of the plan after each).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from pasta.config.schema import TaskConfig
from pasta.data.skills import Aim, place_tool_for_skill, scripted_actions
from pasta.geometry.distances import earth_movers_distance
from pasta.geometry.entities import label_entities
from pasta.sim.engine import SimulationError
from pasta.sim.envs.base import DoughEnv

# The aim coordinates searched per skill, in the order they are tried: "dx" a shift along x, "sy" a scale
# of the destination's height about its centre, and so on. Only coordinates the script reads: the cut's
# push distances (the pieces' gap, sx, and their position, dx; its cut x follows the pieces' length ratio,
# which no aim changes); the push's stopping point; the spread's press depth (the destination's thickness),
# roll span and centre along x (it rolls along x and never reads z); a carried piece's drop point; the
# gather's squeeze (the pile's width in x and z).
SEARCHED_AXES: dict[str, tuple[str, ...]] = {
    "cut": ("sx", "dx"),
    "push": ("dx", "dz"),
    "spread": ("sy", "sx", "dx"),
    "rearrange": ("dx", "dz"),
    "lift": ("dx", "dy", "dz"),
    "move": ("dx", "dy", "dz"),
    "gather": ("sx", "sz", "dx", "dz"),
}
SHIFT_STEP = 0.01  # first step of a shift coordinate (half a grid cell at grid 48)
SCALE_STEP = 0.1  # first step of a scale coordinate (a factor of 1.1 or 1 / 1.1)
MIN_STEP_SHARE = 0.25  # the search stops once its steps are this share of the first ones
_AXIS = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class AimSearchResult:
    """The best aim found and what it did.

    ``actions`` ``(n_steps, action_dim)`` the skill's actions under it, ``state`` the environment's state
    at the end of its rollout (after the skill's rest steps), ``emd`` its score (EMD to the subgoal, or to
    the final goal after the plan's rest), ``emd_identity`` the script's own (identity aim), ``rollouts`` the
    number of rollouts simulated.
    """

    aim: Aim
    actions: np.ndarray
    state: dict[str, Any]
    emd: float
    emd_identity: float
    rollouts: int


def count_pieces(points: np.ndarray, cfg: TaskConfig) -> int:
    """DBSCAN pieces of a ``(P, 3)`` cloud with the task's parameters (0 when DBSCAN keeps none)."""
    try:
        labels = label_entities(points, eps=cfg.data.dbscan_eps, min_samples=cfg.data.dbscan_min_samples,
                                min_points=cfg.data.dbscan_min_points)
    except ValueError:
        return 0
    return len(np.unique(labels[labels >= 0]))


def moved(aim: Aim, axis: str, step: float) -> Aim:
    """``aim`` with one coordinate (``dx``, ``dy``, ``dz``, ``sx``, ``sy``, ``sz``) moved by ``step``; a
    scale moves by the factor ``exp(step)``."""
    if len(axis) != 2 or axis[0] not in "ds" or axis[1] not in _AXIS:
        raise ValueError(f"unknown aim coordinate {axis!r}; use d or s followed by x, y or z")
    k = _AXIS[axis[1]]
    if axis[0] == "d":
        shift = list(aim.shift)
        shift[k] = round(shift[k] + step, 6)
        return replace(aim, shift=tuple(shift))
    scale = list(aim.scale)
    scale[k] = round(scale[k] * float(np.exp(step)), 6)
    return replace(aim, scale=tuple(scale))


Rest = Callable[[DoughEnv], tuple[np.ndarray, np.ndarray]]


def search_aim(env: DoughEnv, skill: str, target: np.ndarray, mask: np.ndarray | None, budget: int,
               settle_steps: int, rest: Rest | None = None) -> AimSearchResult:
    """Search the aim of ``skill`` from the environment's current state; the environment is left at the end
    of the best rollout.

    Args:
        target: ``(P, 3)`` the subgoal (the whole scene after the skill; its first
            ``cfg.sim.observation_points`` points are compared with the observed dough).
        mask: the attention, as :func:`pasta.data.skills.scripted_actions` takes it.
        budget: rollouts at most (1: the script's own aim alone).
        settle_steps: zero-action steps after the skill's, before the score is taken.
        rest: the rest of the plan: run on the environment at the end of a rollout, it returns the final
            observed dough ``(P, 3)`` and the goal ``(P, 3)`` it is scored against (None: the skill is scored
            on ``target``).

    Raises:
        SimulationError: when the script's own rollout blows up (other aims that blow up are skipped).
    """
    if budget < 1:
        raise ValueError(f"an aim search needs a budget of at least 1 rollout, got {budget}")
    axes = SEARCHED_AXES[skill]
    start = env.get_state()
    goal = np.asarray(target, np.float64)[: env.cfg.sim.observation_points]

    def rollout(aim: Aim) -> tuple[float, int, np.ndarray, dict[str, Any]]:
        env.set_state(start)
        place_tool_for_skill(env, skill, mask, target, aim)
        actions = scripted_actions(env, skill, target, mask, aim=aim)
        for action in actions:
            env.step(action)
        env.settle(settle_steps)
        points = env.observation().dough_points
        state, pieces = env.get_state(), count_pieces(points, cfg)
        if rest is not None:
            try:
                points, final_goal = rest(env)
            except SimulationError:
                return float("inf"), pieces, actions, state
            return earth_movers_distance(points, final_goal, rng=0), pieces, actions, state
        return earth_movers_distance(points, goal, rng=0), pieces, actions, state

    cfg = env.cfg
    best = Aim()
    best_emd, identity_pieces, best_actions, best_state = rollout(best)
    allowed_pieces = {identity_pieces, count_pieces(goal, cfg)}
    identity_emd, tried = best_emd, {best}
    steps = {axis: SHIFT_STEP if axis[0] == "d" else SCALE_STEP for axis in axes}
    first = dict(steps)
    while len(tried) < budget and steps[axes[0]] >= MIN_STEP_SHARE * first[axes[0]]:
        improved = False
        for axis in axes:
            for sign in (1.0, -1.0):
                candidate = moved(best, axis, sign * steps[axis])
                if candidate in tried or len(tried) >= budget:
                    continue
                tried.add(candidate)
                try:
                    emd, pieces, actions, state = rollout(candidate)
                except SimulationError:
                    continue
                if emd < best_emd and pieces in allowed_pieces:
                    best, best_emd, best_actions, best_state, improved = candidate, emd, actions, state, True
                    break
        if not improved:
            steps = {axis: 0.5 * step for axis, step in steps.items()}
    env.set_state(best_state)
    return AimSearchResult(best, best_actions, best_state, best_emd, identity_emd, len(tried))
