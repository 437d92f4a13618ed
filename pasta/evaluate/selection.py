"""Which dough a plan step acts on: the observation components behind the attended latents.

model_spec §5.6 step 3: at the first step the attended entity indices are DBSCAN component indices of
the observation the plan was encoded from; at later steps the plan's entities no longer correspond to
components by index, so each attended entity takes the component whose mean is nearest its planned
centre ``t``. Attended entities take distinct components while there are enough of them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["attended_mask", "nearest_components"]


def nearest_components(points: np.ndarray, labels: np.ndarray, centres: np.ndarray) -> tuple[int, ...]:
    """For each planned centre ``(A, 3)`` in order, the label of the nearest unused component mean.

    Once every component is used, later centres may reuse one. Returns ``A`` labels.
    """
    pts = np.asarray(points, dtype=np.float64)
    lab = np.asarray(labels)
    want = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    ids = np.unique(lab)
    means = np.stack([pts[lab == k].mean(axis=0) for k in ids])
    chosen: list[int] = []
    for centre in want:
        distance = np.linalg.norm(means - centre, axis=1)
        free = ~np.isin(ids, chosen)
        if free.any():
            distance = np.where(free, distance, np.inf)
        chosen.append(int(ids[int(np.argmin(distance))]))
    return tuple(chosen)


def attended_mask(points: np.ndarray, labels: np.ndarray, attention: Sequence[int],
                  planned_centres: np.ndarray | None = None) -> np.ndarray:
    """``(P,)`` bool mask of the observation points the step acts on.

    Args:
        points: ``(P, 3)`` current observation points.
        labels: ``(P,)`` their DBSCAN component labels.
        attention: the plan's attended entity indices for this step.
        planned_centres: ``(A, 3)`` planned centres ``t`` of the attended entities; ``None`` at the first
            step, where ``attention`` indexes the components directly.
    """
    lab = np.asarray(labels)
    if planned_centres is None:
        n_components = int(lab.max()) + 1
        bad = [i for i in attention if not 0 <= int(i) < n_components]
        if bad:
            raise ValueError(f"attended entities {bad} do not exist: the observation has {n_components} components")
        chosen: Sequence[int] = [int(i) for i in attention]
    else:
        centres = np.asarray(planned_centres, dtype=np.float64).reshape(-1, 3)
        if len(centres) != len(attention):
            raise ValueError(f"{len(attention)} attended entities but {len(centres)} planned centres")
        chosen = nearest_components(points, lab, centres)
    return np.isin(lab, np.asarray(chosen, dtype=lab.dtype))
