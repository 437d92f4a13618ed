"""Report figures as PNG bytes (matplotlib Agg; the same data gives the same bytes)."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import pandas as pd  # noqa: E402

LATENT_ARTIFACT = "figures/latent_space.png"  # logged by the train flow (Fig. 3 / Fig. 4)


def _png(fig: plt.Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    return buffer.getvalue()


def errorbar_png(x: pd.Series, mean: pd.Series, std: pd.Series, xlabel: str, ylabel: str, title: str) -> bytes:
    """One mean ± std curve (std NaN, as for a single seed, draws no bar); log x when x spans 10x or more."""
    xs = pd.to_numeric(x).to_numpy(dtype=float)
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    ax.errorbar(xs, mean.to_numpy(dtype=float), yerr=std.fillna(0.0).to_numpy(dtype=float), marker="o",
                capsize=3, color="tab:brown")
    if len(xs) and xs.min() > 0 and xs.max() >= 10 * xs.min():
        ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    return _png(fig)


def fig2_pngs(stats: pd.DataFrame, task: str = "CutRearrange") -> dict[str, bytes]:
    """Fig. 2a (planning time) and 2b (performance) against samples from :func:`tables.samples_stats`.

    Returns ``{"fig2a_planning_time": png, "fig2b_performance": png}``, or ``{}`` without sweep runs.
    """
    if stats.empty:
        return {}
    return {
        "fig2a_planning_time": errorbar_png(stats["samples"], stats["time_mean"], stats["time_std"],
                                            "number of samples", "planning time (s)",
                                            f"Fig. 2a: planning time, {task}"),
        "fig2b_performance": errorbar_png(stats["samples"], stats["performance_mean"], stats["performance_std"],
                                          "number of samples", "normalised performance",
                                          f"Fig. 2b: performance, {task}"),
    }
