"""Figures of a trained VAE: held-out reconstructions, and the decoded 2-D latent grid (appendix Fig. 3 / 4).

Both are matplotlib figures drawn with the Agg backend and saved as PNG. Clouds are shown from above
(``x`` right, ``z`` up the page, coloured by height ``y``), the view of the paper's figures.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from pasta.models.vae import PointCloudVAE

__all__ = ["latent_grid_figure", "reconstruction_figure"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _draw(ax, points: np.ndarray, title: str, extent: float | None = None) -> None:
    ax.scatter(points[:, 0], points[:, 2], s=1, c=points[:, 1], cmap="copper")
    if extent is not None:
        ax.set_xlim(-extent, extent)
        ax.set_ylim(-extent, extent)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(title, fontsize=7)


def reconstruction_figure(vae: PointCloudVAE, clouds: torch.Tensor, path: str | Path, n: int = 6) -> Path:
    """Top row: ``n`` held-out entities ``(N, M, 3)`` (evenly spaced picks); bottom row: their decoded means."""
    plt = _pyplot()
    picks = np.linspace(0, len(clouds) - 1, min(n, len(clouds))).round().astype(int)
    points = clouds[torch.from_numpy(picks)]
    with torch.no_grad():
        z, _, t = vae.encode(points.to(vae.scale.device))
        decoded = vae.decode(z, t).cpu().numpy()
    fig, axes = plt.subplots(2, len(picks), figsize=(2 * len(picks), 4), squeeze=False)
    for col in range(len(picks)):
        _draw(axes[0, col], points[col].numpy(), f"held-out #{picks[col]}")
        _draw(axes[1, col], decoded[col], f"z = ({z[col, 0]:.2f}, {z[col, 1]:.2f})")
        axes[1, col].set_xlim(axes[0, col].get_xlim())
        axes[1, col].set_ylim(axes[0, col].get_ylim())
    fig.suptitle("VAE: held-out entities (top) and their reconstructions (bottom)", fontsize=9)
    path = Path(path)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def latent_grid_figure(vae: PointCloudVAE, path: str | Path, *, title: str, steps: int = 5,
                       limit: float = 2.0) -> Path:
    """Decode ``z`` on a ``steps x steps`` grid over ``[-limit, limit]^2`` (first two latent dimensions, the rest 0)
    at ``t = 0``; each cell shows the decoded shape at one scale, so sizes compare across the grid."""
    plt = _pyplot()
    values = np.linspace(-limit, limit, steps)
    z = torch.zeros(steps * steps, vae.config.latent_dim)
    grid = torch.from_numpy(np.stack(np.meshgrid(values, values[::-1]), axis=-1).reshape(-1, 2)).float()
    z[:, :2] = grid
    with torch.no_grad():
        shapes = vae.decode(z.to(vae.scale.device), torch.zeros(len(z), 3, device=vae.scale.device)).cpu().numpy()
    extent = float(np.abs(shapes[..., [0, 2]]).max()) * 1.05
    fig, axes = plt.subplots(steps, steps, figsize=(1.6 * steps, 1.6 * steps), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        _draw(ax, shapes[i], f"({grid[i, 0]:.1f}, {grid[i, 1]:.1f})", extent)
    fig.suptitle(title, fontsize=9)
    path = Path(path)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
