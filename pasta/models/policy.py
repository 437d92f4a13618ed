"""Set point-cloud policy ``pi_k(P^obs, P^tool, P^goal)`` (appendix §1.4, model_spec §4).

The point encoder is chosen by ``PolicyConfig.point_encoder`` (the task config's ``policy.encoder``):

* ``pointnet2`` (the appendix's): the observation, tool and goal clouds are concatenated into one cloud,
  each point tagged with a one-hot role (observation ``[1, 0, 0]``, tool ``[0, 1, 0]``, goal ``[0, 0, 1]``),
  encoded by the PointNet++ of ``pasta.models.pointnet`` (1024-d) and mapped to an action by an MLP
  ``1024 -> 512 -> 256 -> action_dim``;
* ``pointnet`` (compact): one PointNet per cloud, max-pooled and concatenated
  (``pasta.models.cloud_pointnet``, 768-d), then ``768 -> 256 -> 256 -> action_dim``.

The action output is **linear** (then multiplied by ``output_scale`` = 1/5, the official "good
initialisation" trick), not tanh: demonstration actions are clamped to [-1, 1] and many sit exactly on
the bounds, which a tanh reaches only asymptotically and with vanishing gradient; the environment clips
actions to [-1, 1] anyway (model_spec §0.1, §4.3).

Also here: the uniform point noise used in training, and the entity filtering of appendix §1.5.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import torch
from torch import nn

from pasta.config.schema import POLICY_ENCODERS, POLICY_FRAMES
from pasta.geometry.distances import chamfer_distance
from pasta.geometry.entities import PIECE_GAP
from pasta.models import random_draws
from pasta.models.cloud_pointnet import CloudPointNet, CloudPointNetConfig
from pasta.models.layers import mlp, orthogonal_init_
from pasta.models.pointnet import PointNetPlusPlusConfig, PointNetPlusPlusEncoder

__all__ = [
    "CENTRE_OFFSET_SCALE",
    "FilteredEntities",
    "PolicyConfig",
    "SetPolicy",
    "GAP_SCALE",
    "check_point_encoder",
    "cloud_gaps",
    "cloud_quantiles",
    "dough_frame",
    "encode_clouds",
    "goal_heading",
    "turn_actions",
    "turn_clouds",
    "filter_entities",
    "point_encoder",
    "tag_point_roles",
    "uniform_point_noise",
]


def tag_point_roles(*clouds: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Concatenate clouds ``(B, N_i, 3)`` and tag each point with the one-hot index of its cloud.

    Returns:
        ``points (B, sum N_i, 3)`` and ``features (B, sum N_i, len(clouds))``.
    """
    if not clouds:
        raise ValueError("need at least one cloud")
    for i, cloud in enumerate(clouds):
        if cloud.ndim != 3 or cloud.shape[-1] != 3 or cloud.shape[0] != clouds[0].shape[0]:
            raise ValueError(f"cloud {i} must have shape ({clouds[0].shape[0]}, N, 3), got {tuple(cloud.shape)}")
    eye = torch.eye(len(clouds), dtype=clouds[0].dtype, device=clouds[0].device)
    features = [eye[i].expand(c.shape[0], c.shape[1], -1) for i, c in enumerate(clouds)]
    return torch.cat(clouds, dim=1), torch.cat(features, dim=1)


def check_point_encoder(name: str) -> None:
    """Raise ``ValueError`` naming ``name`` and the known encoders unless it is one of ``POLICY_ENCODERS``."""
    if name not in POLICY_ENCODERS:
        raise ValueError(f"unknown policy encoder {name!r}; known: {', '.join(POLICY_ENCODERS)}")


def point_encoder(name: str, pointnet2: PointNetPlusPlusConfig, pointnet: CloudPointNetConfig,
                  n_clouds: int) -> PointNetPlusPlusEncoder | CloudPointNet:
    """The point encoder ``name`` of a policy that reads ``n_clouds`` clouds.

    ``pointnet2``: a PointNet++ over the clouds' union with one one-hot role per cloud (``pointnet2``'s
    ``in_features`` must be ``n_clouds``); ``pointnet``: one PointNet per cloud. Both have ``out_dim``.
    """
    check_point_encoder(name)
    if name == "pointnet":
        return CloudPointNet(n_clouds, pointnet)
    if pointnet2.in_features != n_clouds:
        raise ValueError(f"a PointNet++ over {n_clouds} role-tagged clouds needs in_features {n_clouds}, "
                         f"got {pointnet2.in_features}")
    return PointNetPlusPlusEncoder(pointnet2)


def encode_clouds(encoder: PointNetPlusPlusEncoder | CloudPointNet, clouds: Sequence[torch.Tensor]) -> torch.Tensor:
    """Features ``(B, encoder.out_dim)`` of clouds ``(B, N_i, 3)``: each cloud through its own PointNet, or
    their role-tagged union through the PointNet++."""
    if isinstance(encoder, CloudPointNet):
        return encoder(*clouds)
    return encoder(*tag_point_roles(*clouds))


CENTRE_OFFSET_SCALE = 10.0  # metres -> head inputs: offsets of 0.01-0.4 in the unit workspace become 0.1-4


def dough_frame(obs_points: torch.Tensor, *clouds: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Express clouds in the observed dough's horizontal frame (``policy.frame: dough``).

    Every cloud is shifted so that the observation's centre has x = z = 0 (heights stay absolute: the floor
    is at a fixed height and matters to every skill); the offsets of the other clouds' centres from the
    observation's, times ``CENTRE_OFFSET_SCALE``, are returned for the action head, so that where the goal
    and the tool are relative to the dough is one subtraction away rather than something the max-pooled
    features must encode.

    Args:
        obs_points: ``(B, N_o, 3)``.
        clouds: further clouds ``(B, N_i, 3)`` (tool, goal).

    Returns:
        ``[obs, *clouds]`` shifted, and the offsets ``(B, 3 * len(clouds))``.
    """
    centre = obs_points.mean(dim=1, keepdim=True)
    shift = centre * centre.new_tensor([1.0, 0.0, 1.0])
    offsets = [(cloud.mean(dim=1) - centre[:, 0]) * CENTRE_OFFSET_SCALE for cloud in clouds]
    return [obs_points - shift, *(cloud - shift for cloud in clouds)], torch.cat(offsets, dim=-1)


def goal_heading(obs_points: torch.Tensor, goal_points: torch.Tensor) -> torch.Tensor:
    """The horizontal unit direction ``(B, 2)`` as ``(x, z)`` from the observation's centre to the goal's
    (``policy.heading_skills``); ``(1, 0)`` where the two centres are closer than 1e-6 horizontally.

    Args:
        obs_points: ``(B, N_o, 3)``; goal_points: ``(B, N_g, 3)``.
    """
    offset = goal_points.mean(dim=1)[:, [0, 2]] - obs_points.mean(dim=1)[:, [0, 2]]
    length = offset.norm(dim=1, keepdim=True)
    fallback = offset.new_tensor([1.0, 0.0]).expand_as(offset)
    return torch.where(length > 1e-6, offset / length.clamp_min(1e-6), fallback)


def turn_clouds(heading: torch.Tensor, origin: torch.Tensor, *clouds: torch.Tensor) -> list[torch.Tensor]:
    """Turn clouds about the vertical axis through ``origin`` so that ``heading`` becomes +x.

    A point at horizontal offset ``(dx, dz)`` from the origin moves to ``(u . d, u_perp . d)`` with
    ``u = heading`` and ``u_perp = (-u_z, u_x)``; heights are kept.

    Args:
        heading: ``(B, 2)`` unit ``(x, z)`` directions.
        origin: ``(B, 3)``.
        clouds: ``(B, N_i, 3)`` each.

    Returns:
        the turned clouds, same shapes.
    """
    ux, uz = heading[:, 0, None], heading[:, 1, None]
    turned = []
    for cloud in clouds:
        dx = cloud[..., 0] - origin[:, 0, None]
        dz = cloud[..., 2] - origin[:, 2, None]
        turned.append(torch.stack([origin[:, 0, None] + ux * dx + uz * dz, cloud[..., 1],
                                   origin[:, 2, None] - uz * dx + ux * dz], dim=-1))
    return turned


def turn_actions(actions: torch.Tensor, heading: torch.Tensor, pairs: Sequence[int], action_dim: int
                 ) -> torch.Tensor:
    """Turn the horizontal action vectors predicted in the heading frame back to the world: the inverse of
    :func:`turn_clouds` applied to each ``(x, z)`` index pair of every step of a chunk.

    Args:
        actions: ``(B, chunk * action_dim)``.
        heading: ``(B, 2)`` unit ``(x, z)`` directions.
        pairs: flat ``(x_0, z_0, x_1, z_1, ...)`` indices into one step's action vector.
        action_dim: one step's action length.
    """
    steps = actions.reshape(actions.shape[0], -1, action_dim)
    ux, uz = heading[:, 0, None].to(actions.dtype), heading[:, 1, None].to(actions.dtype)
    columns = list(steps.unbind(dim=-1))
    for ix, iz in zip(pairs[0::2], pairs[1::2], strict=True):
        ax, az = steps[..., ix], steps[..., iz]
        columns[ix], columns[iz] = ux * ax - uz * az, uz * ax + ux * az
    return torch.stack(columns, dim=-1).reshape(actions.shape)


def cloud_quantiles(cloud: torch.Tensor, levels: int) -> torch.Tensor:
    """Each axis's coordinate quantiles of a cloud, times ``CENTRE_OFFSET_SCALE`` (``policy.shape_quantiles``).

    The levels are ``levels`` evenly spaced values from 0 (the minimum) to 1 (the maximum). A piece's extent,
    and where the points of a goal split into pieces (the quantiles jump across the gap), become inputs the
    action head reads directly, with the precision of the points rather than of the max-pooled features.

    Args:
        cloud: ``(B, N, 3)``.
        levels: at least 2.

    Returns:
        ``(B, 3 * levels)``: x's quantiles, then y's, then z's.
    """
    if levels < 2:
        raise ValueError(f"cloud quantiles need at least 2 levels (the minimum and the maximum), got {levels}")
    at = torch.linspace(0.0, 1.0, levels, device=cloud.device)
    quantiles = torch.quantile(cloud.float(), at, dim=1)  # (levels, B, 3)
    return (quantiles.permute(1, 2, 0).reshape(cloud.shape[0], 3 * levels) * CENTRE_OFFSET_SCALE).to(cloud.dtype)


GAP_SCALE = 50.0  # metres -> head inputs for gap ends relative to the tool: a 0.01 miss becomes 0.5


def cloud_gaps(cloud: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """Each axis's widest gap between a cloud's points, relative to ``origin``, times ``GAP_SCALE``
    (``policy.gap_features``).

    Along each axis the coordinates are sorted and the widest step between neighbours is found. A step of at
    least ``PIECE_GAP`` separates pieces (a cut's goal: its pieces slid 0.10-0.13 apart); its two ends are where
    the cut's faces lie. Given relative to the tool's centre and finely scaled, the knife's move to the cut
    is a difference of two inputs of order 1 rather than of order 0.1 (the dough-frame offsets' scale); at
    `small`'s budget this did not raise the closed-loop score (docs/training.md, "Gap features"). Narrower
    steps are sampling noise: both ends are then the axis's median and the flag is 0, so that a whole piece
    gives steady inputs.

    Args:
        cloud: ``(B, N, 3)``, ``N >= 2``.
        origin: ``(B, 3)``, e.g. the tool's centre.

    Returns:
        ``(B, 9)``: per axis (x, y, z) the gap's lower end, its upper end and a flag (1 where there is a gap).
    """
    if cloud.ndim != 3 or cloud.shape[-1] != 3 or cloud.shape[1] < 2:
        raise ValueError(f"cloud gaps need a cloud of shape (B, N >= 2, 3), got {tuple(cloud.shape)}")
    if origin.shape != (cloud.shape[0], 3):
        raise ValueError(f"the gaps' origin must have shape ({cloud.shape[0]}, 3), got {tuple(origin.shape)}")
    coords = cloud.float().sort(dim=1).values  # (B, N, 3)
    steps = coords[:, 1:] - coords[:, :-1]  # (B, N - 1, 3)
    widest, at = steps.max(dim=1)  # (B, 3)
    lower = coords.gather(1, at.unsqueeze(1)).squeeze(1)
    upper = coords.gather(1, (at + 1).unsqueeze(1)).squeeze(1)
    median = coords[:, (coords.shape[1] - 1) // 2]
    has_gap = widest >= PIECE_GAP
    origin = origin.float()
    lower = (torch.where(has_gap, lower, median) - origin) * GAP_SCALE
    upper = (torch.where(has_gap, upper, median) - origin) * GAP_SCALE
    features = torch.stack([lower, upper, has_gap.to(lower.dtype)], dim=-1)  # (B, 3, 3)
    return features.reshape(cloud.shape[0], 9).to(cloud.dtype)


def uniform_point_noise(points: torch.Tensor, amplitude: float, generator: torch.Generator | None) -> torch.Tensor:
    """``points + U(-amplitude, amplitude)`` per coordinate (official ``obs_noise`` = 0.005, uniform)."""
    unit = random_draws.rand(points.shape, generator, dtype=points.dtype, device=points.device)
    return points + amplitude * (2.0 * unit - 1.0)


class FilteredEntities(NamedTuple):
    """Entities left after filtering, and boolean keep masks over the inputs ``(K_o,)``, ``(K_g,)``."""

    obs: torch.Tensor
    goal: torch.Tensor
    obs_keep: torch.Tensor
    goal_keep: torch.Tensor


def filter_entities(obs_entities: torch.Tensor, goal_entities: torch.Tensor, epsilon: float) -> FilteredEntities:
    """Drop entities that are already at their goal: any observation or goal entity that takes part in a pair
    with Chamfer distance strictly below ``epsilon`` (appendix §1.5; official ``match_set``, model_spec §0.4).

    Args:
        obs_entities: ``(K_o, N, 3)`` observation entities.
        goal_entities: ``(K_g, M, 3)`` goal entities.
        epsilon: threshold in ``chamfer_distance`` units (squared; official 5e-4 on 200-point subsamples,
            subsample before calling to match it). 0 filters nothing.

    Returns:
        ``FilteredEntities``; kept entities keep their order.
    """
    n_obs, n_goal = obs_entities.shape[0], goal_entities.shape[0]
    if n_obs == 0 or n_goal == 0 or epsilon <= 0:
        return FilteredEntities(
            obs_entities,
            goal_entities,
            torch.ones(n_obs, dtype=torch.bool, device=obs_entities.device),
            torch.ones(n_goal, dtype=torch.bool, device=goal_entities.device),
        )
    with torch.no_grad():
        a = obs_entities.repeat_interleave(n_goal, dim=0)
        b = goal_entities.repeat(n_obs, 1, 1)
        close = (chamfer_distance(a, b) < epsilon).view(n_obs, n_goal)
    obs_keep, goal_keep = ~close.any(dim=1), ~close.any(dim=0)
    return FilteredEntities(obs_entities[obs_keep], goal_entities[goal_keep], obs_keep, goal_keep)


@dataclass(frozen=True)
class PolicyConfig:
    """Set-policy hyper-parameters.

    Attributes:
        point_encoder: ``pointnet2`` (``encoder``, then ``head_channels``) or ``pointnet`` (``pointnet``, then
            ``pointnet.head_channels``); set from the task config's ``policy.encoder``.
        encoder: the PointNet++ (``in_features`` = 3 roles).
        head_channels: hidden widths of the action MLP after the PointNet++ (``[512, 256]``).
        pointnet: the compact encoder and the widths of its action MLP.
        output_scale: the linear output is multiplied by this (official 1/5).
        frame: ``world`` (the appendix's: clouds as observed) or ``dough`` (clouds shifted to the observed
            dough's horizontal centre, and the tool's and goal's centre offsets fed to the action head:
            ``dough_frame``); set from the task config's ``policy.frame``.
        phase_input: the action head also reads the skill's phase, ``step / steps_per_skill`` in [0, 1) (the
            scripted demonstrations are timed motions: approach, act, hold, withdraw); set from the task
            config's ``policy.phase_input``.
        previous_action_input: the action head also reads the action applied at the previous step (zeros at the
            skill's first), in the policy's frame: which way a tool is travelling, which the clouds do not show.
            Set from the task config's ``policy.previous_action``.
        chunk: actions predicted per call: this step's and the next ``chunk - 1`` (action chunking; the
            executor acts them out before it asks again); set from the task config's ``policy.chunk``.
        shape_quantiles: the action head also reads this many coordinate quantiles per axis of the
            observation and goal clouds, in the policy's frame (``cloud_quantiles``); 0: none. Set from the
            task config's ``policy.shape_quantiles``.
        gap_features: the action head also reads the widest gap per axis of the observation and goal clouds,
            relative to the tool's centre (``cloud_gaps``). Set from the task config's ``policy.gap_features``.
        heading_pairs: per skill index, flat ``(x, z)`` index pairs of the skill tool's horizontal action
            vectors; a skill with pairs works in its goal's heading frame (``SetPolicy``), one without in the
            frame above. Empty: none does. Set from the task config's ``policy.heading_skills``.
    """

    point_encoder: str = "pointnet2"
    encoder: PointNetPlusPlusConfig = field(default_factory=PointNetPlusPlusConfig)
    head_channels: tuple[int, ...] = (512, 256)
    pointnet: CloudPointNetConfig = field(default_factory=CloudPointNetConfig)
    output_scale: float = 0.2
    frame: str = "world"
    phase_input: bool = False
    previous_action_input: bool = False
    chunk: int = 1
    shape_quantiles: int = 0
    gap_features: bool = False
    heading_pairs: tuple[tuple[int, ...], ...] = ()

    def __post_init__(self) -> None:
        check_point_encoder(self.point_encoder)
        for pairs in self.heading_pairs:
            if len(pairs) % 2:
                raise ValueError(f"heading pairs come as (x, z) index pairs, got {pairs}")
        if self.shape_quantiles == 1 or self.shape_quantiles < 0:
            raise ValueError(f"shape_quantiles must be 0 or at least 2, got {self.shape_quantiles}")
        if self.chunk < 1:
            raise ValueError(f"a policy predicts at least one action per call, got chunk {self.chunk}")
        if self.frame not in POLICY_FRAMES:
            raise ValueError(f"unknown policy frame {self.frame!r}; known: {', '.join(POLICY_FRAMES)}")

    @property
    def action_head_channels(self) -> tuple[int, ...]:
        """Hidden widths of the action MLP that follows the chosen encoder."""
        return self.pointnet.head_channels if self.point_encoder == "pointnet" else self.head_channels


class SetPolicy(nn.Module):
    """``(obs (B, N_o, 3), tool (B, N_t, 3), goal (B, N_g, 3))`` -> actions ``(B, chunk * action_dim)``: this
    step's action first, then the next ``chunk - 1`` steps' (``(B, action_dim)`` for the default chunk of 1).

    Orthogonal initialisation of the action head (official ``weight_init``); the PointNet++ keeps torch's,
    the compact encoder is orthogonal too.

    With ``heading_pairs`` (the ``(x, z)`` indices of the skill tool's horizontal action vectors) the policy
    works in its goal's heading frame: every cloud is turned about the vertical axis through the observation's
    centre so that the goal lies along +x (:func:`goal_heading`, :func:`turn_clouds`), and the predicted
    horizontal vectors are turned back (:func:`turn_actions`). The policy is then equivariant to turning the
    scene about a vertical axis: a push along any direction is the same push along +x.
    """

    def __init__(self, action_dim: int, config: PolicyConfig = PolicyConfig(), heading_pairs: Sequence[int] = ()
                 ) -> None:
        super().__init__()
        if len(heading_pairs) % 2 or any(not 0 <= i < action_dim for i in heading_pairs):
            raise ValueError(f"heading pairs must be (x, z) index pairs within the {action_dim} action values, "
                             f"got {tuple(heading_pairs)}")
        self.config = config
        self.action_dim = action_dim
        self.heading_pairs = tuple(int(i) for i in heading_pairs)
        self.encoder = point_encoder(config.point_encoder, config.encoder, config.pointnet, n_clouds=3)
        extra = (6 if config.frame == "dough" else 0) + (1 if config.phase_input else 0) + 6 * config.shape_quantiles
        extra += 18 if config.gap_features else 0
        extra += action_dim if config.previous_action_input else 0
        self.head = mlp((self.encoder.out_dim + extra, *config.action_head_channels, action_dim * config.chunk),
                        final_activation=False)
        orthogonal_init_(self.head)

    def forward(self, obs_points: torch.Tensor, tool_points: torch.Tensor, goal_points: torch.Tensor,
                phase: torch.Tensor | None = None, previous_action: torch.Tensor | None = None) -> torch.Tensor:
        """Actions ``(B, chunk * action_dim)``; ``phase`` ``(B,)`` is required when ``config.phase_input``, and
        ``previous_action`` ``(B, action_dim)`` (in the world frame) when ``config.previous_action_input``."""
        batch = obs_points.shape[0]
        if self.config.previous_action_input and (previous_action is None
                                                  or previous_action.shape != (batch, self.action_dim)):
            raise ValueError(f"this policy reads the previous action: need previous_action of shape "
                             f"({batch}, {self.action_dim}), got "
                             f"{None if previous_action is None else tuple(previous_action.shape)}")
        heading = None
        if self.heading_pairs:
            heading = goal_heading(obs_points, goal_points)
            obs_points, tool_points, goal_points = turn_clouds(heading, obs_points.mean(dim=1), obs_points,
                                                               tool_points, goal_points)
            if self.config.previous_action_input:
                previous_action = turn_actions(previous_action, heading * heading.new_tensor([1.0, -1.0]),
                                               self.heading_pairs, self.action_dim)
        if self.config.frame == "dough":
            clouds, offsets = dough_frame(obs_points, tool_points, goal_points)
            features = [encode_clouds(self.encoder, clouds), offsets.to(obs_points.dtype)]
        else:
            clouds = [obs_points, tool_points, goal_points]
            features = [encode_clouds(self.encoder, clouds)]
        if self.config.shape_quantiles:
            features += [cloud_quantiles(clouds[0], self.config.shape_quantiles),
                         cloud_quantiles(clouds[2], self.config.shape_quantiles)]
        if self.config.gap_features:
            tool_centre = clouds[1].mean(dim=1)
            features += [cloud_gaps(clouds[0], tool_centre), cloud_gaps(clouds[2], tool_centre)]
        if self.config.phase_input:
            if phase is None or phase.shape != (obs_points.shape[0],):
                raise ValueError(f"this policy reads the skill's phase: need phase of shape ({obs_points.shape[0]},), "
                                 f"got {None if phase is None else tuple(phase.shape)}")
            features.append(phase.to(obs_points.dtype).unsqueeze(1))
        if self.config.previous_action_input:
            features.append(previous_action.to(obs_points.dtype))
        actions = self.head(torch.cat(features, dim=-1)) * self.config.output_scale
        if heading is not None:
            actions = turn_actions(actions, heading, self.heading_pairs, self.action_dim)
        return actions
