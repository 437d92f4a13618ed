"""The image strip of an executed plan: initial, each decoded subgoal set, reached, target."""

from __future__ import annotations

import os
from pathlib import Path

from pasta.evaluate.problem import EvaluationResult
from pasta.sim.render import render_strip

__all__ = ["render_result_strip"]


def render_result_strip(result: EvaluationResult, path: str | os.PathLike[str]) -> Path:
    """Write ``result.frames`` side by side as one PNG (3-D views over top-down views); returns the path."""
    return render_strip(result.frames, path)
