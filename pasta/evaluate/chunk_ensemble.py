"""Temporal ensembling of action chunks (Zhao et al., 2023, "ACT").

A chunking policy asked at every step predicts, at step ``s``, the actions of steps ``s .. s + H - 1``. The
action acted at step ``k`` is the weighted mean of every prediction made for ``k`` so far: a prediction
made ``a`` steps before ``k`` (its position in its chunk) weighs ``exp(-decay * a)``. ``decay`` > 0 trusts
the newest predictions most, ``decay`` < 0 the oldest (ACT's choice), 0 weighs them all alike.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ChunkEnsemble"]


class ChunkEnsemble:
    """Running weighted sums of the chunks' predictions for each of ``n_steps`` steps of ``action_dim``."""

    def __init__(self, n_steps: int, action_dim: int, decay: float) -> None:
        self.decay = decay
        self._sums = np.zeros((n_steps, action_dim))
        self._weights = np.zeros(n_steps)

    def add(self, step: int, chunk: np.ndarray) -> None:
        """Record the ``(H, action_dim)`` chunk predicted at ``step`` (actions of ``step .. step + H - 1``;
        those past the last step are dropped)."""
        chunk = np.asarray(chunk, dtype=np.float64)[: len(self._weights) - step]
        weights = np.exp(-self.decay * np.arange(len(chunk)))
        self._sums[step : step + len(chunk)] += weights[:, None] * chunk
        self._weights[step : step + len(chunk)] += weights

    def action(self, step: int) -> np.ndarray:
        """The ``(action_dim,)`` weighted mean of the predictions made for ``step``."""
        if self._weights[step] == 0.0:
            raise ValueError(f"no chunk has predicted an action for step {step} yet")
        return self._sums[step] / self._weights[step]
