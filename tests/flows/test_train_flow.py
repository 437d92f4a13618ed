"""The train flow end to end on a tiny synthetic dataset at smoke: a real Prefect run with MLflow logging."""

import mlflow
import pytest

from pasta import tracking
from pasta.paths import checkpoint_dir, data_dir
from pasta.train.locate import trained_models
from tests.models.synthetic import tiny_model_config
from tests.train.synthetic_demos import write_dataset

pytestmark = pytest.mark.flow


def test_train_flow_logs_metrics_figures_and_the_bundle(prefect_server, isolated_store, capsys):
    from flows.train import FINAL_METRICS, train

    write_dataset(data_dir("CutRearrange", "smoke") / "scripted", n_trajectories=10)
    # policy_lr 1e-2 (the task's is 1e-4): smoke's 4 policy steps then beat the all-zero action (measured 0.63 vs 0.67)
    overrides = ("train.feasibility_batch_size=32", "train.cost_batch_size=32", "train.policy_batch_size=4",
                 "train.policy_lr=1e-2")
    summary = train("CutRearrange", "smoke", "pasta", overrides=overrides,
                    networks=tiny_model_config().to_dict())
    assert summary["dataset"].endswith("scripted")
    for key in ("vae_heldout_chamfer", *FINAL_METRICS):
        assert summary[key] == summary[key], key  # present and not NaN
    assert summary["policy_mse"] < summary["policy_zero_mse"], summary  # the policies learnt something
    assert summary["feasibility_auc_random"] > 0.5, summary  # better than chance
    shown = capsys.readouterr().out  # a bar per stage at its last epoch, then the one-line summary
    assert "CutRearrange VAE" in shown and "CutRearrange heads (pasta)" in shown and "held-out policy MSE" in shown
    assert "CutRearrange policies (pasta)" in shown and "steps cut 4, rearrange 4" in shown
    assert f"train CutRearrange pasta done in {summary['wall_s']:.0f} s: VAE held-out Chamfer" in shown

    tracking.configure()
    run = mlflow.get_run(summary["mlflow_run_id"])
    assert run.data.tags["pasta.stage"] == "train" and run.data.tags["pasta.variant"] == "pasta"
    assert run.data.metrics["cost_r2"] == pytest.approx(summary["cost_r2"])
    client = mlflow.MlflowClient()
    history = client.get_metric_history(run.info.run_id, "train_cost_loss")
    assert [m.step for m in history] == [0, 1, 2]  # smoke: 3 head epochs
    # smoke: 4 policy steps per skill, evaluated untrained and every 2 steps; the curve's step is the step count
    # (only cut has held-out samples: the one held-out trajectory of the 10 is a cut)
    assert run.data.metrics["policy_steps_cut"] == run.data.metrics["policy_steps_rearrange"] == 4
    curve = client.get_metric_history(run.info.run_id, "policy_heldout_mse_cut")
    assert [m.step for m in curve] == [0, 2, 4]
    assert [m.step for m in client.get_metric_history(run.info.run_id, "policy_lr")] == [2, 4]
    artifacts = {a.path for folder in ("figures", "checkpoints")
                 for a in client.list_artifacts(run.info.run_id, folder)}
    assert artifacts == {"figures/latent_space.png", "figures/reconstruction.png", "checkpoints/models.pt"}

    bundle = trained_models("CutRearrange", "smoke", "pasta")
    assert bundle.skill_names == ("cut", "rearrange") and bundle.filter_epsilon > 0
    # measured on the training transitions, per axis
    assert len(bundle.reach) == 2 and all(0 <= r < 1 for reach in bundle.reach for r in reach)
    # and the shapes every skill started from (one z per input entity of its training transitions)
    assert len(bundle.input_shapes) == 2 and all(len(skill) > 0 for skill in bundle.input_shapes)
    assert {len(z) for skill in bundle.input_shapes for z in skill} == {bundle.prior.latent_dim}
    # and the range of every action dimension its demonstrations took (the synthetic knife moves along +x only)
    (cut_low, cut_high), _ = bundle.action_range
    assert 0 < cut_low[0] <= cut_high[0] <= 1 and cut_low[1:] == cut_high[1:] == (0.0,) * (bundle.action_dim - 1)

    # without the local file, locate() fetches the run's artifact
    (checkpoint_dir("CutRearrange", "smoke", "pasta") / "models.pt").unlink()
    assert trained_models("CutRearrange", "smoke", "pasta").action_dim == bundle.action_dim
    with pytest.raises(FileNotFoundError, match="pasta train --task CutRearrange --profile smoke --variant flat3d"):
        trained_models("CutRearrange", "smoke", "flat3d")


def test_a_bf16_vae_does_not_reuse_the_fp32_one(tmp_path):
    from flows.train import vae_key
    from pasta.config import load

    (tmp_path / "index.csv").write_text("trajectory_id\n0\n")
    fp32, bf16 = load("CutRearrange", "smoke"), load("CutRearrange", "smoke", ["train.precision=bf16"])
    sizes = tiny_model_config()
    assert vae_key(fp32, tmp_path, False, sizes, 0) != vae_key(bf16, tmp_path, False, sizes, 0)
    assert vae_key(fp32, tmp_path, False, sizes, 0) == vae_key(fp32, tmp_path, False, sizes, 0)
