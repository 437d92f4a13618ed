"""Training sets built from a ``Demonstrations`` table and its ``EntityTable``.

* ``split_trajectories``: a seeded split by trajectory (the VAE uses 80/20, the heads 90/10, seed 42,
  as the official ``generate_train_eval_split``; the heads' split also holds out one trajectory of every
  skill the permutation left out, so that each policy has a held-out error).
* ``vae_clouds``: the entities of the chosen trajectories' states and targets (the official set VAE also
  trains on goal entities).
* ``TransitionSampler``: per skill, the transitions ``(trajectory, t)`` of the chosen trajectories, and
  from a batch of them the feasibility positives, the policy samples and the cost pairs of model_spec
  §2.3, §4.1 and §3.3:

  - feasibility positive: observation entities at ``t``, goal entities of the same trajectory at a
    hindsight step ``t' ~ U{t, ..., T-1}``; both filtered (every entity in a pair closer than epsilon
    goes, model_spec §0.4) and kept only if exactly ``(N_in, N_out)`` entities remain (any counts
    without filtering);
  - policy sample: goal = the trajectory's target with probability 0.5, else a hindsight state (its cloud
    observed, or at a configured share the VAE's reconstruction of its entities: ``DecodedGoals``); filtered
    with epsilon except for splitting skills (``N_out > N_in``, the official cut), kept when both sides
    are non-empty with counts in ``{N_in, N_out}``; action = the demonstration's action at ``t``;
  - cost pairs: a random entity at ``t`` against a random entity of the trajectory's target, plus as
    many randomly re-paired ones; the target is their true Chamfer distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pasta.config.schema import SkillConfig
from pasta.data.storage import split_by_configuration
from pasta.geometry.entities import resample
from pasta.train.demos import Demonstrations
from pasta.train.entities import EntityTable, PairChamfer, state_cloud

__all__ = [
    "CostPairs",
    "DecodedGoals",
    "FeasibilityPositives",
    "PolicySamples",
    "TransitionSampler",
    "pad_sets",
    "split_trajectories",
    "vae_clouds",
]

HINDSIGHT_GOAL_RATIO = 0.5


def split_trajectories(demos: Demonstrations, test_fraction: float, seed: int = 42, every_skill: bool = False
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Positions (into ``demos``) of the train and held-out trajectories, split by a seeded permutation of ids.

    With ``every_skill``, a skill with at least two trajectories none of which the permutation held out gets
    one of them held out (drawn with ``seed``), so that every skill's held-out error can be measured; a split
    that already holds out every skill is left as it is.
    """
    train_ids, test_ids = split_by_configuration(demos.trajectory_ids.tolist(), test_fraction, seed)
    position = {int(t): i for i, t in enumerate(demos.trajectory_ids)}
    train = [position[t] for t in train_ids]
    test = [position[t] for t in test_ids]
    if every_skill:
        rng = np.random.RandomState(seed)
        for k in np.unique(demos.skill_index):
            of_skill = [i for i in train if demos.skill_index[i] == k]
            if len(of_skill) >= 2 and not any(demos.skill_index[i] == k for i in test):
                moved = of_skill[rng.randint(len(of_skill))]
                train.remove(moved)
                test.append(moved)
    def in_id_order(positions: list[int]) -> np.ndarray:
        return np.asarray(sorted(positions, key=lambda i: int(demos.trajectory_ids[i])), dtype=np.int64)

    return in_id_order(train), in_id_order(test)


def vae_clouds(demos: Demonstrations, table: EntityTable, trajectories: np.ndarray) -> torch.Tensor:
    """``(N, M, 3)`` entity clouds of every state (targets included) of the given trajectories."""
    states = np.concatenate([np.arange(demos.first_state[i], demos.target_state[i] + 1) for i in trajectories])
    return table.clouds[torch.from_numpy(table.of_states(states))]


def pad_sets(sets: list[np.ndarray], latents: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Entity id lists -> latent sets ``(B, K_max, E)`` (padding repeats entity 0) and masks ``(B, K_max)``."""
    k_max = max(len(s) for s in sets)
    ids = torch.zeros((len(sets), k_max), dtype=torch.long)
    mask = torch.zeros((len(sets), k_max), dtype=torch.bool)
    for row, s in enumerate(sets):
        ids[row, : len(s)] = torch.from_numpy(np.asarray(s, dtype=np.int64))
        mask[row, : len(s)] = True
    return latents[ids.to(latents.device)], mask.to(latents.device)


@dataclass(frozen=True)
class FeasibilityPositives:
    """Filtered (observation, goal) entity id sets of the positives of one batch."""

    obs: list[np.ndarray]
    goal: list[np.ndarray]


@dataclass(frozen=True)
class PolicySamples:
    """``B`` policy samples: clouds, tool, filtered entity ids and the demonstrated actions."""

    obs_points: torch.Tensor  # (B, P, 3)
    tool_points: torch.Tensor  # (B, Q, 3)
    goal_points: torch.Tensor  # (B, P, 3)
    tool_states: torch.Tensor  # (B, 8)
    actions: torch.Tensor  # (B, A)
    action_chunks: torch.Tensor  # (B, H * A) the actions at t .. t + H - 1 (zeros after the last), H = chunk
    phases: torch.Tensor  # (B,) step t of the sample over the trajectory's action count, in [0, 1)
    previous_actions: torch.Tensor  # (B, A) the action at t - 1 (zeros at t = 0)
    obs_ids: list[np.ndarray]
    goal_ids: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.actions)


@dataclass(frozen=True)
class CostPairs:
    """Entity id pairs ``(n,)``, ``(n,)`` and their true Chamfer distances ``(n,)`` float32."""

    a: np.ndarray
    b: np.ndarray
    chamfer: torch.Tensor


@dataclass(frozen=True, eq=False)
class DecodedGoals:
    """The VAE's reconstruction of every entity of an ``EntityTable``, for policy goals like a learned plan's.

    Attributes:
        clouds: ``(N, M, 3)`` float32 decoded entity clouds, world frame, in table order.
        share: share of policy samples whose goal cloud comes from ``clouds``.
    """

    clouds: np.ndarray
    share: float

    def __post_init__(self) -> None:
        if not 0.0 <= self.share <= 1.0:
            raise ValueError(f"share must lie in [0, 1], got {self.share}")
        if self.clouds.ndim != 3 or self.clouds.shape[2] != 3:
            raise ValueError(f"clouds must have shape (N, M, 3), got {self.clouds.shape}")

    def cloud(self, entity_ids: np.ndarray, n_points: int, rng: np.random.Generator) -> np.ndarray:
        """``(n_points, 3)``: the given entities' decoded clouds stacked (as many points each, as the policy
        executor stacks a plan's decoded subgoals) and resampled."""
        return resample(self.clouds[np.asarray(entity_ids)].reshape(-1, 3), n_points, rng)


class TransitionSampler:
    """Per-skill transitions of some trajectories, and the samples of the three heads drawn from them.

    Args:
        demos: the states.
        table: their entities.
        skills: the task's skills (config order).
        trajectories: positions of the trajectories to use.
        filter_epsilon: squared-Chamfer filtering threshold (0: no filtering).
        chamfer: shared memo of entity-pair distances.
        cloud_points: points of the policy samples' observation and goal clouds (default: the dataset's
            observation size, ``cfg.policy.points`` in training).
        chunk: actions per policy sample's ``action_chunks`` (``cfg.policy.chunk`` in training).
        hindsight_ratio: share of policy samples whose goal is a later state of the same trajectory instead of
            its target (``cfg.train.policy_hindsight_ratio``; the official 0.5).
        keep_acted: where filtering would leave no observed entity, keep the observed entity farthest from its
            nearest goal entity and that goal entity (``cfg.train.filter_keeps_acted``; the official drops the
            sample).
        decoded_goals: every table entity's VAE reconstruction and the share of policy samples whose goal cloud
            is built from it (``cfg.train.policy_decoded_goal_share``); ``None``: observed goals only.
        target_share: share of feasibility positives whose goal is the demonstration's target instead of a later
            state of it (``cfg.train.feasibility_target_share``; the official 0).
    """

    def __init__(self, demos: Demonstrations, table: EntityTable, skills: tuple[SkillConfig, ...],
                 trajectories: np.ndarray, filter_epsilon: float, chamfer: PairChamfer,
                 cloud_points: int | None = None, chunk: int = 1,
                 hindsight_ratio: float = HINDSIGHT_GOAL_RATIO, keep_acted: bool = False,
                 decoded_goals: DecodedGoals | None = None, target_share: float = 0.0) -> None:
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        if not 0.0 <= hindsight_ratio <= 1.0:
            raise ValueError(f"hindsight_ratio must lie in [0, 1], got {hindsight_ratio}")
        if not 0.0 <= target_share <= 1.0:
            raise ValueError(f"target_share must lie in [0, 1], got {target_share}")
        if decoded_goals is not None and len(decoded_goals.clouds) != len(table):
            raise ValueError(f"decoded_goals holds {len(decoded_goals.clouds)} entity clouds, the table {len(table)}")
        self.decoded_goals = decoded_goals
        self.hindsight_ratio = hindsight_ratio
        self.target_share = target_share
        self.demos, self.table, self.skills = demos, table, skills
        self.chunk = chunk
        self.cloud_points = cloud_points or demos.points.shape[1]
        self.filter_epsilon = filter_epsilon
        self.keep_acted = keep_acted
        self.chamfer = chamfer
        self.transitions: list[np.ndarray] = []  # per skill: (n_k, 2) rows of (trajectory position, t)
        for k in range(len(skills)):
            rows = [(i, t) for i in trajectories if demos.skill_index[i] == k for t in range(demos.n_steps[i] - 1)]
            self.transitions.append(np.asarray(rows, dtype=np.int64).reshape(-1, 2))

    def count(self, skill: int) -> int:
        return len(self.transitions[skill])

    # -- filtering ----------------------------------------------------------------------------------

    def _filter_all(self, pairs: list[tuple[np.ndarray, np.ndarray]], epsilon: float):
        if epsilon <= 0:
            return pairs
        a = np.concatenate([np.repeat(o, len(g)) for o, g in pairs])
        b = np.concatenate([np.tile(g, len(o)) for o, g in pairs])
        distances = self.chamfer(a, b)
        out, start = [], 0
        for o, g in pairs:
            block = distances[start : start + len(o) * len(g)].reshape(len(o), len(g))
            start += len(o) * len(g)
            close = block < epsilon
            if self.keep_acted and len(o) and len(g) and close.any(axis=1).all():
                # Every observed entity matches a goal entity: a skill that changes its entity a little (a short
                # spread) would leave nothing. The entity the skill changed most is the one it acts on.
                acted = int(np.argmax(block.min(axis=1)))
                close[acted, :] = False
                close[:, int(np.argmin(block[acted]))] = False
            out.append((o[~close.any(axis=1)], g[~close.any(axis=0)]))
        return out

    def _obs_goal(self, rows: np.ndarray, goal_states: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        obs_states = self.demos.first_state[rows[:, 0]] + rows[:, 1]
        return [(self.table.state_entities[s], self.table.state_entities[g])
                for s, g in zip(obs_states, goal_states, strict=True)]

    def _hindsight_states(self, rows: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        last = self.demos.n_steps[rows[:, 0]] - 1
        later = rows[:, 1] + (rng.random(len(rows)) * (last - rows[:, 1] + 1)).astype(np.int64)
        return self.demos.first_state[rows[:, 0]] + np.minimum(later, last)

    # -- the three kinds of samples -----------------------------------------------------------------

    def feasibility_positives(self, skill: int, rows: np.ndarray, rng: np.random.Generator) -> FeasibilityPositives:
        """Positives from the transitions ``rows`` (``(n, 2)``) with hindsight goals, or with a share
        ``target_share`` of them the demonstration's target."""
        goals = self._hindsight_states(rows, rng)
        if self.target_share > 0:
            aimed = rng.random(len(rows)) < self.target_share
            goals = np.where(aimed, self.demos.target_state[rows[:, 0]], goals)
        return self._positives(skill, rows, goals)

    def whole_skill_pairs(self, skill: int) -> FeasibilityPositives:
        """Every trajectory of ``skill`` from its first state to its last, filtered as the positives."""
        rows = self.transitions[skill]
        rows = rows[rows[:, 1] == 0]
        last = self.demos.first_state[rows[:, 0]] + self.demos.n_steps[rows[:, 0]] - 1
        return self._positives(skill, rows, last)

    def _positives(self, skill: int, rows: np.ndarray, goal_states: np.ndarray) -> FeasibilityPositives:
        pairs = self._filter_all(self._obs_goal(rows, goal_states), self.filter_epsilon)
        spec = self.skills[skill]
        keep = [(o, g) for o, g in pairs if len(o) and len(g)
                and (self.filter_epsilon <= 0 or (len(o) in spec.input_counts and len(g) == spec.entities_out))]
        return FeasibilityPositives([o for o, _ in keep], [g for _, g in keep])

    def policy_samples(self, skill: int, rows: np.ndarray, rng: np.random.Generator,
                       limit: int) -> PolicySamples | None:
        """The first ``limit`` valid policy samples among ``rows``; ``None`` when none is valid."""
        spec = self.skills[skill]
        hindsight = self._hindsight_states(rows, rng)
        use_target = rng.random(len(rows)) >= self.hindsight_ratio
        goals = np.where(use_target, self.demos.target_state[rows[:, 0]], hindsight)
        epsilon = 0.0 if spec.entities_out > max(spec.input_counts) else self.filter_epsilon
        allowed = {*spec.input_counts, spec.entities_out}
        pairs: list[tuple[np.ndarray, np.ndarray]] = []
        chosen: list[int] = []
        for start in range(0, len(rows), 2 * limit):  # filter a few rows at a time: only `limit` are needed
            block = slice(start, start + 2 * limit)
            pairs += self._filter_all(self._obs_goal(rows[block], goals[block]), epsilon)
            chosen += [j for j in range(start, len(pairs)) if len(pairs[j][0]) and len(pairs[j][1])
                       and (epsilon <= 0 or (len(pairs[j][0]) in allowed and len(pairs[j][1]) in allowed))]
            if len(chosen) >= limit:
                break
        chosen = chosen[:limit]
        if not chosen:
            return None
        n_points = self.cloud_points
        decoded = self.decoded_goals
        use_decoded = (rng.random(len(chosen)) < decoded.share if decoded is not None and decoded.share > 0
                       else np.zeros(len(chosen), dtype=bool))
        obs_pts, goal_pts = [], []
        for j, from_decoder in zip(chosen, use_decoded, strict=True):
            obs_pts.append(state_cloud(self.demos, self.table, pairs[j][0], n_points, rng))
            if from_decoder:
                goal_pts.append(decoded.cloud(pairs[j][1], n_points, rng))
            else:
                goal_pts.append(state_cloud(self.demos, self.table, pairs[j][1], n_points, rng))
        steps = [(int(i), int(t)) for i, t in rows[chosen]]
        return PolicySamples(
            obs_points=torch.from_numpy(np.stack(obs_pts)),
            tool_points=torch.from_numpy(np.stack([self.demos.tool_points[i][t] for i, t in steps])),
            goal_points=torch.from_numpy(np.stack(goal_pts)),
            tool_states=torch.from_numpy(np.stack([self.demos.tool_states[i][t] for i, t in steps])),
            actions=torch.from_numpy(np.stack([self.demos.actions[i][t] for i, t in steps])),
            action_chunks=torch.from_numpy(np.stack([self._chunk(i, t) for i, t in steps])),
            phases=torch.tensor([t / len(self.demos.actions[i]) for i, t in steps], dtype=torch.float32),
            previous_actions=torch.from_numpy(np.stack([self._previous(i, t) for i, t in steps])),
            obs_ids=[pairs[j][0] for j in chosen],
            goal_ids=[pairs[j][1] for j in chosen],
        )

    def _previous(self, trajectory: int, t: int) -> np.ndarray:
        """``(A,)`` float32: the action of ``trajectory`` at step ``t - 1``, zeros at its first step."""
        actions = self.demos.actions[trajectory]
        if t == 0:
            return np.zeros(actions.shape[1], dtype=np.float32)
        return np.asarray(actions[t - 1], dtype=np.float32)

    def _chunk(self, trajectory: int, t: int) -> np.ndarray:
        """``(chunk * A,)`` the actions of ``trajectory`` from step ``t`` on, zeros after its last step (the
        skill is over: the executor settles with zero actions)."""
        actions = self.demos.actions[trajectory]
        out = np.zeros((self.chunk, actions.shape[1]), dtype=np.float32)
        ahead = actions[t : t + self.chunk]
        out[: len(ahead)] = ahead
        return out.reshape(-1)

    def cost_pairs(self, rows: np.ndarray, rng: np.random.Generator) -> CostPairs:
        """``2n`` pairs: aligned (entity at ``t``, entity of the target) and ``n`` randomly re-paired ones."""
        obs_states = self.demos.first_state[rows[:, 0]] + rows[:, 1]
        target_states = self.demos.target_state[rows[:, 0]]

        def pick(states: np.ndarray) -> np.ndarray:
            return np.asarray([rng.choice(self.table.state_entities[s]) for s in states], dtype=np.int64)

        a, b = pick(obs_states), pick(target_states)
        shuffle_a, shuffle_b = rng.integers(len(rows), size=len(rows)), rng.integers(len(rows), size=len(rows))
        a = np.concatenate([a, pick(obs_states[shuffle_a])])
        b = np.concatenate([b, pick(target_states[shuffle_b])])
        return CostPairs(a, b, torch.from_numpy(self.chamfer(a, b).astype(np.float32)))
