"""Pictures of simulator states: valid PNG / GIF files, written atomically."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from pasta.sim.render import render_state, render_strip


def _state(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    dough = rng.uniform((0.4, 0.09, 0.45), (0.6, 0.17, 0.55), (500, 3)).astype(np.float32)
    tools = {"knife": rng.uniform((0.48, 0.2, 0.44), (0.52, 0.4, 0.56), (100, 3))}
    return {"dough_points": dough, "tool_points": tools}


def test_render_state_writes_a_valid_png(tmp_path):
    s = _state()
    target = s["dough_points"] + np.array([0.1, 0.0, 0.0])
    path = render_state(s["dough_points"], s["tool_points"], tmp_path / "sub" / "state.png", title="t",
                        target_points=target)
    assert path == tmp_path / "sub" / "state.png"
    with Image.open(path) as image:
        image.verify()
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size[0] > image.size[1] > 100
    assert [p.name for p in path.parent.iterdir()] == ["state.png"]  # no temporary file left


def _pixels(path) -> np.ndarray:
    with Image.open(path) as image:
        assert image.format == "PNG"
        return np.asarray(image.convert("RGB"))


def test_render_state_without_tools(tmp_path):
    s = _state()
    path = render_state(s["dough_points"], {}, tmp_path / "bare.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bare = _pixels(path)
    # the same state given as float64 draws the same picture
    again = render_state(s["dough_points"].astype(np.float64), {}, tmp_path / "again.png")
    np.testing.assert_array_equal(_pixels(again), bare)
    with_tools = _pixels(render_state(s["dough_points"], s["tool_points"], tmp_path / "tools.png"))
    assert with_tools.shape == bare.shape
    assert (with_tools != bare).any(-1).sum() > 100, "the knife is drawn"
    moved = _pixels(render_state(s["dough_points"] + np.array([0.2, 0.0, 0.0]), {}, tmp_path / "moved.png"))
    assert (moved != bare).any(-1).sum() > 100, "the dough is drawn where it is"


def test_render_strip_writes_frames_side_by_side_and_a_gif(tmp_path):
    frames = [{**_state(i), "title": f"frame {i}"} for i in range(3)]
    png = render_strip(frames, tmp_path / "strip.png", gif_path=tmp_path / "strip.gif")
    with Image.open(png) as strip:
        assert strip.format == "PNG"
        width, height = strip.size
    assert width > height  # three columns, each a 3-D view over a top-down view
    with Image.open(tmp_path / "strip.gif") as gif:
        assert gif.format == "GIF" and gif.n_frames == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["strip.gif", "strip.png"]


def test_render_strip_accepts_observation_like_objects(tmp_path):
    class Frame:
        def __init__(self, s):
            self.dough_points = s["dough_points"]
            self.tool_points = s["tool_points"]

    png = render_strip([Frame(_state(0)), Frame(_state(1))], tmp_path / "obs.png")
    assert png.exists()
    as_mappings = render_strip([_state(0), _state(1)], tmp_path / "dicts.png")
    np.testing.assert_array_equal(_pixels(png), _pixels(as_mappings))  # objects and mappings draw alike
    swapped = render_strip([_state(1), _state(0)], tmp_path / "swapped.png")
    assert (_pixels(swapped) != _pixels(png)).any(), "each frame draws its own state"
    without_tools = render_strip([{**_state(0), "tool_points": {}}, {**_state(1), "tool_points": {}}],
                                 tmp_path / "no_tools.png")
    assert (_pixels(without_tools) != _pixels(png)).sum() > 100, "a frame draws its tools"


def test_bad_inputs_raise_and_write_nothing(tmp_path):
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        render_state(np.zeros((10, 2)), {}, tmp_path / "bad.png")
    with pytest.raises(ValueError, match="at least one frame"):
        render_strip([], tmp_path / "empty.png")
    assert list(tmp_path.iterdir()) == []
