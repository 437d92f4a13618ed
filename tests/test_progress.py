"""Progress bars of the long stages and their one-line summaries."""

from __future__ import annotations

import io
import math
from types import SimpleNamespace

from rich.console import Console

from pasta.progress import ScoreBar, summary
from pasta.train.progress import EpochBars, epoch_status


def quiet_console() -> tuple[Console, io.StringIO]:
    text = io.StringIO()
    return Console(file=text, width=200, force_terminal=False), text


def test_score_bar_counts_results_and_shows_their_mean():
    console, text = quiet_console()
    with ScoreBar("CRS evaluation", total=3, console=console) as bar:
        assert math.isnan(bar.mean)
        results = [bar.done(SimpleNamespace(performance=p)) for p in (0.2, 0.4, 0.9)]
        task = bar.progress.tasks[0]
        assert (task.completed, task.total) == (3, 3)
    assert [r.performance for r in results] == [0.2, 0.4, 0.9]
    assert bar.mean == 0.5
    assert "CRS evaluation" in text.getvalue() and "mean performance 0.500" in text.getvalue()


def test_epoch_status_names_the_loss_and_the_held_out_metric():
    assert epoch_status("vae", {"vae_train_loss": 0.04123, "vae_heldout_chamfer_epoch": 0.0105, "vae_lr": 1e-3}) == (
        "loss 0.04123  held-out Chamfer 0.0105")
    assert epoch_status("heads", {"train_feasibility_loss": 1.5, "cost_r2": 0.2, "policy_mse": 3.0}) == (
        "feasibility loss 1.5  held-out cost R2 0.2")
    assert epoch_status("policy", {"policy_train_loss": 0.5, "policy_heldout_mse": 0.25, "policy_lr": 1e-4}) == (
        "loss 0.5  held-out policy MSE 0.25")


def test_epoch_bars_follow_the_epochs_pass_them_on_and_fill_on_finish():
    console, text = quiet_console()
    seen = []
    bars = EpochBars({"vae": "CRS VAE", "heads": "CRS heads (pasta)"}, {"vae": 4, "heads": 3},
                     then=lambda *call: seen.append(call), console=console)
    with bars:
        bars("vae", 2, {"vae_train_loss": 0.5, "vae_heldout_chamfer_epoch": 0.25})  # resumed after epoch 2
        vae, heads = bars.progress.tasks
        assert vae.completed == 3 and "held-out Chamfer 0.25" in vae.fields["status"]
        bars.finish("vae", "held-out Chamfer 0.2")
        bars.finish("heads", "reused")  # nothing left to train: no epoch callback
        assert (vae.completed, heads.completed) == (4, 3)
    assert seen == [("vae", 2, {"vae_train_loss": 0.5, "vae_heldout_chamfer_epoch": 0.25})]
    assert "CRS heads (pasta)" in text.getvalue()


def test_the_policy_bar_counts_gradient_steps():
    console, _ = quiet_console()
    with EpochBars({"policy": "CRS policies (pasta)"}, {"policy": 300}, console=console) as bars:
        bars("policy", 0, {"policy_heldout_mse": 0.9})  # the untrained evaluation
        assert bars.progress.tasks[0].completed == 0
        bars("policy", 25, {"policy_heldout_mse": 0.5})
        assert bars.progress.tasks[0].completed == 25


def test_summary_is_one_line_with_the_stage_and_wall_time():
    console, text = quiet_console()
    line = summary("evaluate CRS pasta", "performance 0.500", 12.4, console=console)
    assert line == "evaluate CRS pasta done in 12 s: performance 0.500"
    assert text.getvalue() == line + "\n"


def test_a_bar_written_to_a_pipe_is_not_cut_at_80_columns(capsys):
    description = "CutRearrange evaluation (no_smoothing_feasibility, oracle plan, scripted)"
    with ScoreBar(description, total=1) as bar:
        bar.done(SimpleNamespace(performance=0.125))
    out = capsys.readouterr().out
    assert description in out and "mean performance 0.125" in out and "ETA" in out
