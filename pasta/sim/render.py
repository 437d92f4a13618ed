"""Matplotlib pictures of simulator states (Agg backend, no display needed).

* :func:`render_state`: one state as a PNG, a 3-D scatter beside a top-down (x-z) view.
* :func:`render_strip`: several states side by side in one PNG (3-D row over top-down row),
  and optionally the same states as an animated GIF (Pillow).

Axes are fixed to the unit cube, so pictures of different states compare directly. Files are
written atomically (temporary file in the same folder, then ``os.replace``).
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

DOUGH_COLOUR = "#d08c3a"
TARGET_COLOUR = "#3a7bd0"
TOOL_COLOURS = ("#2b2b2b", "#8e44ad", "#16a085", "#c0392b", "#7f8c8d", "#2980b9")


def _atomic_write_bytes(path: Path, data: bytes) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600 files; pictures are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _points(value: Any, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what} must have shape (N, 3), got {arr.shape}")
    return arr


def _frame_fields(frame: Any) -> dict[str, Any]:
    """Accept a mapping or any object with ``dough_points`` / ``tool_points`` attributes (an Observation)."""
    if isinstance(frame, Mapping):
        get = frame.get
    else:
        def get(key, default=None):
            return getattr(frame, key, default)
    dough = get("dough_points")
    if dough is None:
        raise ValueError("a frame needs dough_points")
    return {
        "dough_points": dough,
        "tool_points": get("tool_points") or {},
        "target_points": get("target_points"),
        "title": get("title"),
    }


def _draw(fig: Figure, ax3d, ax_top, dough, tools: Mapping[str, Any], target=None, title=None) -> None:
    dough = _points(dough, "dough_points")
    if target is not None:
        target = _points(target, "target_points")
        ax3d.scatter(target[:, 0], target[:, 2], target[:, 1], s=1, c=TARGET_COLOUR, alpha=0.15,
                     depthshade=False)
        ax_top.scatter(target[:, 0], target[:, 2], s=1, c=TARGET_COLOUR, alpha=0.2, label="target")
    # World y is up: plot (x, z, y) so the 3-D view stands upright.
    ax3d.scatter(dough[:, 0], dough[:, 2], dough[:, 1], s=1.5, c=DOUGH_COLOUR, depthshade=True)
    order = np.argsort(dough[:, 1])  # top-down view: higher points drawn last
    ax_top.scatter(dough[order, 0], dough[order, 2], s=1.5, c=dough[order, 1], cmap="copper",
                   vmin=0.0, vmax=0.3)
    for i, (name, pts) in enumerate(tools.items()):
        pts = _points(pts, f"tool_points[{name!r}]")
        colour = TOOL_COLOURS[i % len(TOOL_COLOURS)]
        ax3d.scatter(pts[:, 0], pts[:, 2], pts[:, 1], s=3, c=colour, marker="^", depthshade=False, label=name)
        ax_top.scatter(pts[:, 0], pts[:, 2], s=3, c=colour, marker="^", alpha=0.6, label=name)
    ax3d.set(xlim=(0, 1), ylim=(0, 1), zlim=(0, 1), xlabel="x", ylabel="z", zlabel="y")
    ax3d.view_init(elev=25, azim=-60)
    ax_top.set(xlim=(0, 1), ylim=(0, 1), xlabel="x", ylabel="z", aspect="equal")
    ax_top.set_title("top (x-z)", fontsize=8)
    for ax in (ax3d, ax_top):
        ax.tick_params(labelsize=6)
    if tools:
        ax_top.legend(loc="upper right", fontsize=6, markerscale=2, framealpha=0.6)
    if title:
        ax3d.set_title(str(title), fontsize=9)


def _figure_bytes(fig: Figure, fmt: str = "png", dpi: int = 100) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, dpi=dpi)
    plt.close(fig)
    return buffer.getvalue()


def _state_figure(dough, tools, target=None, title=None) -> Figure:
    fig = plt.figure(figsize=(8.0, 4.0))
    ax3d = fig.add_subplot(1, 2, 1, projection="3d")
    ax_top = fig.add_subplot(1, 2, 2)
    _draw(fig, ax3d, ax_top, dough, tools, target, title)
    fig.tight_layout()
    return fig


def render_state(
    dough_points: np.ndarray,
    tool_points: Mapping[str, np.ndarray],
    path: str | os.PathLike,
    title: str | None = None,
    target_points: np.ndarray | None = None,
) -> Path:
    """Write one state as a PNG: 3-D scatter (left) and top-down x-z view (right).

    ``dough_points`` (N, 3) and ``target_points`` (M, 3) are world positions; ``tool_points``
    maps tool name -> (P, 3). Returns the path written.
    """
    fig = _state_figure(dough_points, tool_points or {}, target_points, title)
    return _atomic_write_bytes(Path(path), _figure_bytes(fig))


def render_strip(
    frames: Sequence[Any], path: str | os.PathLike, gif_path: str | os.PathLike | None = None,
    gif_frame_ms: int = 400,
) -> Path:
    """Write several states side by side in one PNG (3-D views on top, top-down views below).

    Each frame is a mapping with ``dough_points`` and optional ``tool_points``,
    ``target_points`` and ``title``, or an object with those attributes (an env Observation).
    With ``gif_path`` the states are also written as an animated GIF. Returns the PNG path.
    """
    if not frames:
        raise ValueError("render_strip needs at least one frame")
    fields = [_frame_fields(f) for f in frames]
    n = len(fields)
    fig = plt.figure(figsize=(3.2 * n, 6.4))
    for i, f in enumerate(fields):
        ax3d = fig.add_subplot(2, n, i + 1, projection="3d")
        ax_top = fig.add_subplot(2, n, n + i + 1)
        _draw(fig, ax3d, ax_top, f["dough_points"], f["tool_points"], f["target_points"], f["title"])
    fig.tight_layout()
    png = _atomic_write_bytes(Path(path), _figure_bytes(fig))
    if gif_path is not None:
        write_gif(fields, gif_path, gif_frame_ms)
    return png


def write_gif(frames: Sequence[Any], path: str | os.PathLike, frame_ms: int = 400) -> Path:
    """Write states as an animated GIF (one :func:`render_state` picture per frame)."""
    from PIL import Image

    images = []
    for f in (_frame_fields(f) for f in frames):
        fig = _state_figure(f["dough_points"], f["tool_points"], f["target_points"], f["title"])
        image = Image.open(io.BytesIO(_figure_bytes(fig, dpi=80)))
        images.append(image.convert("P", palette=Image.Palette.ADAPTIVE))
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=frame_ms, loop=0)
    return _atomic_write_bytes(Path(path), buffer.getvalue())
