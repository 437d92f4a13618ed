"""An aim: where a scripted skill is told its destination is, relative to where it really is.

A scripted skill is open loop, and some of its errors are systematic for a given scene: a pushed
piece stops short as it compresses, a pressed piece springs back, a cut throws its halves. Aiming
the skill at a destination moved or stretched a little (about the destination's own centre) lets
it end nearer the real one; :mod:`pasta.data.aim_search` finds such an aim by trying a few in the
simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Aim:
    """A shift ``(dx, dy, dz)`` and per-axis scales ``(sx, sy, sz)`` of the destination about its centre.

    ``Aim()`` is the identity: the skill aims at the destination itself.
    """

    shift: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        if len(self.shift) != 3 or len(self.scale) != 3:
            raise ValueError(f"an aim needs 3 shifts and 3 scales, got {self.shift} and {self.scale}")
        if not all(np.isfinite(self.shift)) or not all(s > 0 and np.isfinite(s) for s in self.scale):
            raise ValueError(f"an aim needs finite shifts and positive scales, got {self.shift}, {self.scale}")

    @property
    def is_identity(self) -> bool:
        return self.shift == (0.0, 0.0, 0.0) and self.scale == (1.0, 1.0, 1.0)

    def apply(self, pieces: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
        """The destination pieces ``(P_k, 3)`` moved together: scaled about their joint centre, then shifted.

        Scaling the pieces together also scales the gaps between them (a cut's two pieces move apart
        when ``sx > 1``).
        """
        if not pieces or self.is_identity:
            return pieces
        centre = np.concatenate(pieces).mean(axis=0)
        scale, shift = np.asarray(self.scale), np.asarray(self.shift)
        return tuple(centre + (p - centre) * scale + shift for p in pieces)
