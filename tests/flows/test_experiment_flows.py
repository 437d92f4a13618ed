"""The ablation flow (child runs of one parent run) at smoke, and the sweep points of the sweeps flow."""

from __future__ import annotations

import mlflow
import pytest

from pasta.cli import build_parser
from pasta.config import load

# The smoke profile with short skills, one test configuration, one training epoch and a tiny planner.
OVERRIDES = ("sim.steps_per_skill=3", "sim.settle_steps=1", "plan.samples=8", "plan.iterations=2",
             "data.n_eval_configs=1", "train.vae_epochs=1", "train.epochs=1")


@pytest.mark.flow
def test_ablations_are_child_runs_of_one_parent_and_a_rerun_adds_nothing(prefect_server, isolated_store):
    from flows import ablations

    tmp_path, uri = isolated_store
    variants = ("pasta", "shared_encoder_policy")
    results = ablations.run("CutRearrange", "smoke", variants, method="scripted", workers=1, overrides=OVERRIDES)
    assert set(results) == set(variants)
    assert all(0.0 <= results[v]["success_mean"] <= 1.0 for v in variants)

    again = ablations.run("CutRearrange", "smoke", variants, method="scripted", workers=1, overrides=OVERRIDES)
    assert again == {v: {"skipped": True} for v in variants}

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["pasta/CutRearrange"])
    parents = runs[runs["tags.pasta.stage"] == "ablations"]
    children = runs[runs["tags.pasta.stage"] == "evaluate"]
    assert len(parents) == 1
    assert sorted(children["tags.pasta.variant"]) == sorted(variants)
    assert set(children["tags.mlflow.parentRunId"]) == {parents.iloc[0]["run_id"]}
    assert set(children["tags.pasta.experiment"]) == {"ablation"}
    for _, child in children.iterrows():  # one seed and one configuration: the success of that configuration
        assert child["metrics.success_config_0"] in (0.0, 1.0)
        assert results[child["tags.pasta.variant"]]["success_mean"] == pytest.approx(child["metrics.success_config_0"])
    report = (tmp_path / "reports" / "CutRearrange" / "report.md").read_text()
    table5 = report[report.index("### Table 5"):]
    assert "| shared_encoder_policy | 1 |" in table5 and "| pasta | 1 |" in table5


def test_sweep_points_cover_the_appendix_sweeps_and_their_configs_load():
    from flows.sweeps import SWEEPS, sample_counts, sweep_points

    samples = load("CutRearrange", "small").plan.samples
    counts = sample_counts("small")
    assert counts == sorted(set(counts)) and counts[-1] == samples and counts[0] < samples
    horizons = sweep_points("horizon", "smoke")
    assert [value for _, value, _ in horizons] == ["3", "4", "5", "6"]
    for sweep in SWEEPS:
        for task_name, value, overrides in sweep_points(sweep, "smoke"):
            cfg = load(task_name, "smoke", list(overrides))
            if sweep == "horizon":
                assert cfg.plan.horizon == int(value) and cfg.horizon == 3
            if sweep == "distractors":
                assert cfg.distractors == 2
    with pytest.raises(ValueError, match="'tides'"):
        sweep_points("tides", "smoke")


def test_cli_ablations_and_sweeps_arguments():
    args = build_parser().parse_args(["ablations", "--variants", "pasta", "flat3d", "--method", "scripted"])
    assert (args.task, args.variants, args.method) == ("CutRearrange", ["pasta", "flat3d"], "scripted")
    args = build_parser().parse_args(["sweeps", "--profile", "small", "--only", "horizon"])
    assert (args.profile, args.only, args.seeds) == ("small", ["horizon"], None)
    assert build_parser().parse_args(["sweeps", "--seeds", "0", "2"]).seeds == [0, 2]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["sweeps", "--only", "tides"])
