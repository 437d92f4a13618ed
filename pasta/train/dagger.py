"""DAgger for the skill policies: run them where they will be used, and label what they see with an expert.

Behaviour cloning trains a policy on the states of the demonstrations only. Executed closed loop, its small
errors take the tool and the dough to states no demonstration shows, where its errors grow (measured at
``small`` on CutRearrange: a one-step error of 0.2x the action variance compounds over 50 steps). DAgger
(Ross, Gordon and Bagnell, 2011) adds the states the policy itself visits, labelled by an expert.

Here a round (:func:`collect_visits`) runs the oracle chain of fresh problems (drawn by the evaluation
generator with a seed of their own, so never the test problems) with the current policies, exactly as the
policy executor runs it (:func:`pasta.evaluate.oracle.oracle_step_inputs`, the tool placed, ``chunk`` actions
per call, settled, parked). At every step the state is recorded with the expert's action chunk: the scripted
skill planned at the skill's start, tracked from the tool's current pose
(:func:`pasta.data.skills.tracking.tracking_actions`). At each call, with probability ``expert_share``, the
expert's chunk is executed instead of the policy's, which keeps the visited states near the useful ones.
The visits then train the policies beside the demonstrations (:class:`pasta.train.visits.VisitPool`,
:func:`pasta.train.policy_loop.train_policies`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.data.configurations import evaluation_problem, oracle_chain
from pasta.data.skills import place_tool_for_skill, scripted_actions, skill_tool
from pasta.data.skills.tracking import scripted_path, tracking_actions
from pasta.data.storage import atomic_write_bytes
from pasta.evaluate.execution import park_tool, policy_view
from pasta.evaluate.oracle import oracle_step_inputs
from pasta.evaluate.policy_action import PolicyInput, checked_action, policy_action, skill_action_range
from pasta.geometry.entities import resample
from pasta.models.variants import variant_spec
from pasta.sim.engine import SimulationError
from pasta.sim.envs import make_env
from pasta.train.bundle import TrainedModels
from pasta.train.datasets import PolicySamples, TransitionSampler
from pasta.train.policy_loop import PolicyResult, PolicySettings, train_policies
from pasta.train.progress import EpochCallback
from pasta.train.visits import VisitPool, concat_samples, take_samples

__all__ = ["DAGGER_GENERATOR_SEED", "DaggerSettings", "collect_visits", "dagger_metrics", "dagger_rounds",
           "split_visits", "visits_path"]

DAGGER_GENERATOR_SEED = 2000  # the problems' generator seed; evaluation draws its test problems with 1000


def _samples(views: list[PolicyInput], chunks: list[np.ndarray]) -> PolicySamples:
    """``B`` visited states and their expert chunks ``(H, A)`` as policy samples (no entity ids: the latent-set
    policy does not take visits)."""
    actions = np.stack(chunks).astype(np.float32)
    return PolicySamples(
        obs_points=torch.from_numpy(np.stack([v.obs_points for v in views]).astype(np.float32)),
        tool_points=torch.from_numpy(np.stack([v.tool_points for v in views]).astype(np.float32)),
        goal_points=torch.from_numpy(np.stack([v.goal_points for v in views]).astype(np.float32)),
        tool_states=torch.from_numpy(np.stack([v.tool_state for v in views]).astype(np.float32)),
        actions=torch.from_numpy(actions[:, 0]),
        action_chunks=torch.from_numpy(actions.reshape(len(actions), -1)),
        phases=torch.tensor([v.phase for v in views], dtype=torch.float32),
        previous_actions=torch.from_numpy(np.stack([v.previous_action for v in views]).astype(np.float32)),
        obs_ids=[np.zeros(0, np.int64)] * len(views),
        goal_ids=[np.zeros(0, np.int64)] * len(views),
    )


def _run_problem(cfg: TaskConfig, bundle: TrainedModels, config_id: int, generator_seed: int, expert_share: float,
                 rng: np.random.Generator, out: dict[str, tuple[list[PolicyInput], list[np.ndarray]]]) -> None:
    """One problem's oracle chain with the policies (the expert's chunk at a share of the calls), recording
    every step's view and expert chunk into ``out``; a skill whose simulation blows up ends the problem."""
    problem = evaluation_problem(cfg, config_id, generator_seed)
    env = make_env(cfg)
    env.reset(problem.initial)
    env.settle(cfg.sim.settle_steps)
    n_steps, horizon, n_points = cfg.sim.steps_per_skill, cfg.policy.chunk, cfg.policy.points
    for h, step in enumerate(oracle_chain(cfg, config_id, generator_seed), start=1):
        inputs = oracle_step_inputs(cfg, env, step, bundle, rng)
        tool = skill_tool(cfg, step.skill).name
        indices = np.flatnonzero(inputs.mask)
        goal_points = resample(inputs.goal_points, n_points, rng)
        views, chunks = out.setdefault(step.skill, ([], []))
        before = env.get_state()
        try:
            place_tool_for_skill(env, step.skill, inputs.mask, inputs.subgoal)
            path = scripted_path(env, tool, scripted_actions(env, step.skill, inputs.subgoal, inputs.mask))
            policy_range = skill_action_range(bundle, step.skill, cfg.eval.policy_action_range)
            acting, acting_range = np.zeros((0, env.action_dim)), None
            applied = np.zeros(env.action_dim, dtype=np.float32)
            for k in range(n_steps):
                view = policy_view(env, tool, indices, goal_points, inputs.goal_latents, k, rng, applied)
                expert = tracking_actions(env, path, k, horizon)
                views.append(view)
                chunks.append(expert)
                if len(acting) == 0:  # the expert's chunk as it is, or the policy's held as the executor holds it
                    if rng.random() < expert_share:
                        acting, acting_range = expert, None
                    else:
                        acting = policy_action(bundle, step.skill, view).reshape(-1, env.action_dim)
                        acting_range = policy_range
                applied = checked_action(acting[0], step.skill, h, k, acting_range)
                env.step(applied)
                acting = acting[1:]
            env.settle(cfg.sim.settle_steps)
        except SimulationError:
            env.set_state(before)
            return
        park_tool(env, tool)


def collect_visits(cfg: TaskConfig, bundle: TrainedModels, config_ids: Sequence[int], *, seed: int,
                   expert_share: float, generator_seed: int = DAGGER_GENERATOR_SEED) -> dict[str, PolicySamples]:
    """One DAgger round: the oracle chains of problems ``config_ids`` (drawn with ``generator_seed``) run with
    ``bundle``'s policies, every step's view labelled with the expert's chunk of ``cfg.policy.chunk`` actions.

    Returns:
        Per skill, the visited states as policy samples (``phases``, ``action_chunks`` ``(B, H * A)``).
    """
    if not 0.0 <= expert_share <= 1.0:
        raise ValueError(f"expert_share must be in [0, 1], got {expert_share}")
    out: dict[str, tuple[list[PolicyInput], list[np.ndarray]]] = {}
    for config_id in config_ids:
        rng = np.random.default_rng([seed, generator_seed, int(config_id)])
        _run_problem(cfg, bundle, int(config_id), generator_seed, expert_share, rng, out)
    return {skill: _samples(views, chunks) for skill, (views, chunks) in out.items() if views}


@dataclass(frozen=True)
class DaggerSettings:
    """DAgger rounds after behaviour cloning (``cfg.train.dagger_*``): their number, the fresh problems per
    round, the share of calls the expert acts for, the policy steps and learning rate per round, and the
    share of each skill's visits kept out of training for its held-out MSE."""

    rounds: int
    problems: int
    expert_share: float
    steps: int
    lr: float
    held_out_share: float = 0.1

    @classmethod
    def from_config(cls, cfg: TaskConfig) -> DaggerSettings:
        train = cfg.train
        return cls(train.dagger_rounds, train.dagger_problems, train.dagger_expert_share, train.dagger_steps,
                   train.dagger_lr)


def visits_path(stem: str | Path, round_number: int) -> Path:
    """Where round ``round_number``'s visits are kept: ``<stem>-dagger-visits-<r>.pt``."""
    return Path(f"{stem}-dagger-visits-{round_number}.pt")


def _save_visits(path: Path, visits: dict[str, PolicySamples]) -> None:
    atomic_write_bytes(path, lambda f: torch.save({k: dataclasses.asdict(v) for k, v in visits.items()}, f))


def _load_visits(path: Path) -> dict[str, PolicySamples]:
    stored = torch.load(path, weights_only=False)
    return {skill: PolicySamples(**fields) for skill, fields in stored.items()}


def split_visits(pool: VisitPool, held_out: Sequence[PolicySamples | None], share: float, seed: int
                 ) -> tuple[VisitPool, list[PolicySamples | None]]:
    """A seeded ``share`` of each skill's visits (at most 64) joins that skill's held-out samples; the rest train."""
    rng = np.random.default_rng(seed)
    train, held = [], []
    for k, samples in enumerate(pool.samples):
        if samples is None or len(samples) < 2:
            train.append(samples)
            held.append(held_out[k])
            continue
        order = rng.permutation(len(samples))
        n_held = min(max(1, int(share * len(samples))), 64)
        kept = take_samples(samples, order[:n_held])
        train.append(take_samples(samples, order[n_held:]))
        held.append(kept if held_out[k] is None else concat_samples([held_out[k], kept]))
    return VisitPool(tuple(train)), held


def dagger_metrics(metrics: dict[str, float]) -> dict[str, float]:
    """The policy loop's ``policy_*`` metrics as ``dagger_*`` (a curve of its own: its held-out samples differ)."""
    return {("dagger_" + key.removeprefix("policy_")) if key.startswith("policy_") else key: value
            for key, value in metrics.items()}


def dagger_rounds(cfg: TaskConfig, bundle: TrainedModels, sampler: TransitionSampler,
                  held_out: Sequence[PolicySamples | None], latents: torch.Tensor, policy: PolicySettings,
                  settings: DaggerSettings, stem: str | Path, *, first_step: int = 0,
                  on_epoch: EpochCallback | None = None) -> list[PolicyResult]:
    """``settings.rounds`` DAgger rounds on ``bundle``'s policies, in place; resumable.

    Round ``r`` (from 1) runs problems ``(r - 1) * problems .. r * problems - 1`` of the DAgger generator seed
    with the policies of round ``r - 1``, keeps their visits in ``<stem>-dagger-visits-<r>.pt``, and trains
    ``settings.steps`` policy steps from ``settings.lr`` (the rest of ``policy``) on the demonstrations and the
    visits of rounds 1..r (progress in ``<stem>-dagger-<r>-policy.pt``; a rerun reuses both). Each round keeps
    the weights with the lowest held-out MSE on the demonstrations' held-out samples and a share of the visits.
    ``on_epoch("dagger", step, metrics)`` counts steps on from ``first_step``, with the policy loop's metrics
    renamed ``dagger_*`` (:func:`dagger_metrics`: their held-out samples include visits) and ``dagger_round``.

    Returns:
        Each round's policy result.
    """
    if settings.rounds and variant_spec(bundle.variant).policy_on_latents:
        raise ValueError(f"variant {bundle.variant!r}: DAgger needs a point-cloud policy (its visits have no "
                         f"entity latents); set train.dagger_rounds=0")
    rounds: list[dict[str, PolicySamples]] = []
    results = []
    for r in range(1, settings.rounds + 1):
        path = visits_path(stem, r)
        if path.is_file():
            visits = _load_visits(path)
        else:
            bundle.eval()
            ids = range((r - 1) * settings.problems, r * settings.problems)
            visits = collect_visits(cfg, bundle, ids, seed=policy.seed * 1000 + r,
                                    expert_share=settings.expert_share)
            _save_visits(path, visits)
        rounds.append(visits)
        train_pool, held = split_visits(VisitPool.merge(bundle.skill_names, rounds), held_out,
                                        settings.held_out_share, seed=r)
        round_settings = dataclasses.replace(policy, steps=settings.steps, lr=settings.lr, patience=None,
                                             seed=policy.seed * 1000 + r)
        offset = first_step + (r - 1) * settings.steps

        def report(stage: str, step: int, metrics: dict[str, float], offset: int = offset, r: int = r) -> None:
            if on_epoch is not None:
                on_epoch("dagger", offset + step, {**dagger_metrics(metrics), "dagger_round": float(r)})

        results.append(train_policies(bundle, sampler, held, latents, round_settings,
                                      Path(f"{stem}-dagger-{r}-policy.pt"), visits=train_pool, on_epoch=report))
    return results
