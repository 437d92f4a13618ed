"""Bundles: the task config's ``policy.encoder`` builds the policies, and a saved bundle rebuilds them, input
normalisation included."""

from __future__ import annotations

import pytest
import torch

from pasta.config import load
from pasta.models import CloudPointNet, LatentPrior, LatentSetPolicy, PointNetPlusPlusEncoder
from pasta.train.bundle import load_trained, save_trained, untrained
from tests.models.synthetic import box_clouds, tiny_model_config

PRIOR = LatentPrior(2, (0.2, 0.2, 0.2), (0.8, 0.8, 0.8))


def test_policy_encoder_comes_from_the_task_config():
    sizes = tiny_model_config().with_policy_encoder("pointnet")
    appendix = untrained(load("CutRearrange", "smoke"), "pasta", PRIOR, model_config=sizes)
    assert appendix.model_config.policy.point_encoder == "pointnet2"  # the task config wins over the sizes
    assert isinstance(appendix.policy("cut").encoder, PointNetPlusPlusEncoder)
    compact = load("CutRearrange", "smoke", ["policy.encoder=pointnet"])
    tool_concat = untrained(compact, "tool_concat_policy", PRIOR, model_config=tiny_model_config())
    assert isinstance(tool_concat.policy("rearrange").encoder, CloudPointNet)
    latent = untrained(compact, "shared_encoder_policy", PRIOR, model_config=tiny_model_config())
    assert isinstance(latent.policy("cut"), LatentSetPolicy)  # no point encoder to choose


def test_a_saved_compact_bundle_acts_as_the_trained_one(tmp_path):
    cfg = load("CutRearrange", "smoke", ["policy.encoder=pointnet"])
    bundle = untrained(cfg, "pasta", PRIOR, model_config=tiny_model_config(), seed=0)
    gen = torch.Generator().manual_seed(0)
    inputs = box_clouds(3, 64, gen), box_clouds(3, 16, gen), box_clouds(3, 64, gen)
    for k, skill in enumerate(bundle.skill_names):
        bundle.policy(skill).train()(*[c + 0.1 * k for c in inputs])  # each skill fits its own normalisation
    loaded = load_trained(save_trained(tmp_path / "models.pt", bundle), "cpu")
    assert loaded.model_config == bundle.model_config and loaded.model_config.policy.point_encoder == "pointnet"
    bundle.eval()
    with torch.no_grad():
        for skill in bundle.skill_names:
            trained, restored = bundle.policy(skill).encoder, loaded.policy(skill).encoder
            assert torch.equal(restored.centre, trained.centre) and torch.equal(restored.scale, trained.scale)
            assert torch.equal(loaded.policy(skill)(*inputs), bundle.policy(skill)(*inputs))
    assert not torch.equal(loaded.policy("cut").encoder.centre, loaded.policy("rearrange").encoder.centre)



def test_heading_skills_turn_their_tools_action_pairs_and_survive_a_save(tmp_path):
    """``policy.heading_skills``: CRS's pusher is the second tool (after the knife's 3 values), a box, so its
    translation and world-frame rotation pairs turn; the knife's cut and the roller's spread keep the frame."""
    cfg = load("CRS", "smoke", ["policy.encoder=pointnet", "policy.heading_skills=[push,rearrange]"])
    bundle = untrained(cfg, "pasta", PRIOR, model_config=tiny_model_config(), seed=0)
    assert bundle.model_config.policy.heading_pairs == ((), (3, 5, 6, 8), ())
    assert [bundle.policy(skill).heading_pairs for skill in bundle.skill_names] == [(), (3, 5, 6, 8), ()]
    loaded = load_trained(save_trained(tmp_path / "models.pt", bundle), "cpu")
    assert loaded.policy("push").heading_pairs == (3, 5, 6, 8) and loaded.policy("cut").heading_pairs == ()
    both = ["policy.encoder=pointnet", "policy.heading_skills=[push,rearrange]"]
    gripper = untrained(load("CutRearrange", "smoke", both), "pasta", PRIOR, model_config=tiny_model_config())
    assert gripper.policy("rearrange").heading_pairs == (3, 5)  # a gripper turns in its own frame: translation only
    plain = untrained(load("CRS", "smoke", ["policy.encoder=pointnet"]), "pasta", PRIOR,
                      model_config=tiny_model_config())
    assert plain.model_config.policy.heading_pairs == ()


def test_a_heading_skill_must_have_a_tool_that_moves_along_x_and_z():
    with pytest.raises(ValueError, match="heading_skills names 'cut'"):
        load("CRS", "smoke", ["policy.heading_skills=[cut]"])
    with pytest.raises(ValueError, match="heading_skills"):
        load("CRS", "smoke", ["policy.heading_skills=[shove]"])
