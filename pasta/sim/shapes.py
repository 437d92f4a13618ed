"""Seeded particle samplers for dough shapes (env_spec section 1.7).

Every sampler takes an explicit :class:`numpy.random.Generator`; nothing here
touches global random state. Shapes return ``(N, 3)`` float32 positions in the
simulator's world frame (unit cube, y up).

* :func:`sample_box`: i.i.d. uniform in an axis-aligned box (centre, half extents).
* :func:`sample_sphere`: i.i.d. uniform in a ball (Gaussian direction, radius ``R u^(1/3)``).
* :func:`sample_scattered`: GatherMove's "scatter" dough, seed points plus noisy copies.
* :func:`split_budget`: a particle budget split between pieces in proportion to volume.
* Piece classes (:class:`BoxPiece`, :class:`SpherePiece`, :class:`ScatterPiece`) bundle a
  shape's parameters with its volume and bounds; :func:`sample_pieces` samples several at once
  and :func:`place_distractors` finds room for extra small pieces on the floor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pasta.config.schema import SimConfig

Vec3 = tuple[float, float, float]

# The original shape maker's density: n = volume / 0.1^3 * 30000 (30 particles per 1e-6).
NATIVE_PARTICLES_PER_VOLUME = 30000 / 0.1**3


def floor_height(sim: SimConfig) -> float:
    """Height of the floor the dough rests on: ``boundary_cells * dx``.

    Grid nodes below ``boundary_cells`` stop downward motion, so a dough placed with its
    bottom here rests (it sinks by a fraction of a cell, e.g. to 0.089 at n_grid 32). At
    the paper grid (80) this is 0.0375, a little above the original's 0.0269.
    """
    return sim.boundary_cells / sim.n_grid


def cell_middle(x: float, n_grid: int) -> float:
    """The middle of the grid cell holding coordinate ``x`` (cells are ``1 / n_grid`` wide)."""
    dx = 1.0 / n_grid
    return (math.floor(x / dx) + 0.5) * dx


def _as_vec3(value: Sequence[float], what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ValueError(f"{what} must be 3 finite numbers, got {value!r}")
    return arr


def _check_count(n: int) -> int:
    if int(n) != n or n < 0:
        raise ValueError(f"particle count must be a non-negative integer, got {n!r}")
    return int(n)


def sample_box(
    rng: np.random.Generator, n: int, centre: Sequence[float], half_extents: Sequence[float]
) -> np.ndarray:
    """``n`` points i.i.d. uniform in the box ``centre +- half_extents``: (n, 3) float32."""
    n = _check_count(n)
    c = _as_vec3(centre, "centre")
    h = _as_vec3(half_extents, "half_extents")
    if (h <= 0).any():
        raise ValueError(f"half_extents must be positive, got {tuple(h)}")
    return (c + rng.uniform(-1.0, 1.0, size=(n, 3)) * h).astype(np.float32)


def sample_sphere(rng: np.random.Generator, n: int, centre: Sequence[float], radius: float) -> np.ndarray:
    """``n`` points i.i.d. uniform in the ball of ``radius`` around ``centre``: (n, 3) float32."""
    n = _check_count(n)
    c = _as_vec3(centre, "centre")
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    direction = rng.normal(size=(n, 3))
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    r = radius * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1.0 / 3.0)
    return (c + direction * r).astype(np.float32)


def sample_scattered(
    rng: np.random.Generator,
    n: int = 2000,
    seed_low: Sequence[float] = (0.64, 0.02, 0.38),
    seed_high: Sequence[float] = (0.76, 0.035, 0.62),
    n_seeds: int = 40,
    sigma: float = 0.004,
    y_sigma_factor: float = 0.2,
    y_offset: float = 0.1,
) -> np.ndarray:
    """GatherMove's scattered dough (env_spec 1.7): ``n_seeds`` seed points, each with noisy copies.

    Seeds are uniform in ``[seed_low, seed_high]``; every copy adds N(0, sigma) in x and z and
    ``N(0, sigma * y_sigma_factor) + y_offset`` in y, so the blobs start ``y_offset`` higher and
    drop. ``n`` is split as evenly as possible between the seeds (the original: 40 x 50 = 2000).
    Returns (n, 3) float32.
    """
    n = _check_count(n)
    if n_seeds < 1:
        raise ValueError(f"n_seeds must be >= 1, got {n_seeds}")
    lo, hi = _as_vec3(seed_low, "seed_low"), _as_vec3(seed_high, "seed_high")
    if (lo > hi).any():
        raise ValueError(f"seed_low {tuple(lo)} exceeds seed_high {tuple(hi)}")
    seeds = rng.uniform(lo, hi, size=(n_seeds, 3))
    per_seed = np.full(n_seeds, n // n_seeds)
    per_seed[: n % n_seeds] += 1
    owner = np.repeat(np.arange(n_seeds), per_seed)
    noise = rng.normal(size=(n, 3)) * np.array([sigma, sigma * y_sigma_factor, sigma])
    noise[:, 1] += y_offset
    return (seeds[owner] + noise).astype(np.float32)


def split_budget(n_total: int, volumes: Sequence[float], min_per_piece: int = 1) -> list[int]:
    """Split ``n_total`` particles between pieces in proportion to ``volumes``.

    Largest-remainder rounding, so the counts sum to ``n_total`` exactly; every piece gets at
    least ``min_per_piece``.
    """
    n_total = _check_count(n_total)
    vol = np.asarray(volumes, dtype=np.float64).reshape(-1)
    if vol.size == 0:
        raise ValueError("split_budget needs at least one volume")
    if not np.isfinite(vol).all() or (vol <= 0).any():
        raise ValueError(f"volumes must be finite and positive, got {list(vol)}")
    if n_total < min_per_piece * vol.size:
        raise ValueError(
            f"cannot give {vol.size} pieces at least {min_per_piece} particles each "
            f"from a budget of {n_total}"
        )
    share = n_total * vol / vol.sum()
    counts = np.floor(share).astype(np.int64)
    order = np.argsort(-(share - counts), kind="stable")
    counts[order[: n_total - int(counts.sum())]] += 1
    for i in np.flatnonzero(counts < min_per_piece):  # top up tiny pieces from the largest one
        need = min_per_piece - counts[i]
        counts[i] += need
        counts[int(np.argmax(counts))] -= need
    return [int(c) for c in counts]


# ------------------------------------------------------------------ pieces
@dataclass(frozen=True)
class BoxPiece:
    """An axis-aligned box of dough."""

    centre: Vec3
    half_extents: Vec3

    @property
    def volume(self) -> float:
        hx, hy, hz = self.half_extents
        return 8.0 * hx * hy * hz

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        c, h = np.asarray(self.centre), np.asarray(self.half_extents)
        return c - h, c + h

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return sample_box(rng, n, self.centre, self.half_extents)


@dataclass(frozen=True)
class SpherePiece:
    """A ball of dough."""

    centre: Vec3
    radius: float

    @property
    def volume(self) -> float:
        return 4.0 / 3.0 * math.pi * self.radius**3

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.centre)
        return c - self.radius, c + self.radius

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return sample_sphere(rng, n, self.centre, self.radius)


@dataclass(frozen=True)
class ScatterPiece:
    """GatherMove's scattered dough (see :func:`sample_scattered`).

    Its ``volume`` (used only to split a particle budget) is that of the original 2000 particles
    at the original shape maker's density, 2000 / 3e7 = 6.7e-5.
    """

    seed_low: Vec3 = (0.64, 0.02, 0.38)
    seed_high: Vec3 = (0.76, 0.035, 0.62)
    n_seeds: int = 40
    sigma: float = 0.004
    y_sigma_factor: float = 0.2
    y_offset: float = 0.1
    nominal_volume: float = 2000 / NATIVE_PARTICLES_PER_VOLUME

    @property
    def volume(self) -> float:
        return self.nominal_volume

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        spread = 3.0 * self.sigma * np.array([1.0, self.y_sigma_factor, 1.0])
        lift = np.array([0.0, self.y_offset, 0.0])
        lo = np.minimum(np.asarray(self.seed_low), np.asarray(self.seed_low) + lift) - spread
        hi = np.maximum(np.asarray(self.seed_high), np.asarray(self.seed_high) + lift) + spread
        return lo, hi

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return sample_scattered(rng, n, self.seed_low, self.seed_high, self.n_seeds, self.sigma,
                                self.y_sigma_factor, self.y_offset)


Piece = BoxPiece | SpherePiece | ScatterPiece


def sample_pieces(
    rng: np.random.Generator, pieces: Sequence[Piece], n_total: int, shuffle: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Sample every piece with its share of ``n_total`` particles (by volume).

    Returns ``(points (n_total, 3) float32, labels (n_total,) int32)`` where ``labels[i]`` is the
    index of the piece particle i belongs to. With ``shuffle`` the particles are randomly
    permuted, so any prefix of the array (the observation's first 1000 particles, env_spec 3.1)
    is a uniform random subset of all pieces together.
    """
    if not pieces:
        raise ValueError("sample_pieces needs at least one piece")
    counts = split_budget(n_total, [p.volume for p in pieces])
    points = np.concatenate([p.sample(rng, c) for p, c in zip(pieces, counts, strict=True)], axis=0)
    labels = np.repeat(np.arange(len(pieces), dtype=np.int32), counts)
    if shuffle:
        order = rng.permutation(n_total)
        points, labels = points[order], labels[order]
    return np.ascontiguousarray(points, dtype=np.float32), labels


def _overlaps(
    lo: np.ndarray, hi: np.ndarray, boxes: Sequence[tuple[np.ndarray, np.ndarray]], margin: float
) -> bool:
    for b_lo, b_hi in boxes:
        if np.all(lo - margin < b_hi) and np.all(hi + margin > b_lo):
            return True
    return False


def place_distractors(
    rng: np.random.Generator,
    count: int,
    occupied_xz: Sequence[tuple[Sequence[float], Sequence[float]]],
    floor_y: float,
    main_volume: float,
    region_xz: tuple[tuple[float, float], tuple[float, float]] = ((0.1, 0.1), (0.9, 0.9)),
    volume_fraction: tuple[float, float] = (0.1, 0.2),
    margin: float = 0.05,
    max_tries: int = 2000,
) -> list[BoxPiece]:
    """``count`` small box pieces resting on the floor, clear of everything in ``occupied_xz``.

    Each distractor has a volume of U(volume_fraction) x ``main_volume``, a height of its cube
    root clipped to [0.03, 0.06] and a square footprint; its x-z rectangle keeps at least
    ``margin`` from every occupied rectangle (``(lo_xz, hi_xz)`` pairs) and from the other
    distractors, and lies inside ``region_xz``. Raises ``RuntimeError`` if there is no room.
    """
    count = _check_count(count)
    boxes = [(np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)) for lo, hi in occupied_xz]
    r_lo, r_hi = np.asarray(region_xz[0], dtype=np.float64), np.asarray(region_xz[1], dtype=np.float64)
    pieces: list[BoxPiece] = []
    for i in range(count):
        volume = float(rng.uniform(*volume_fraction)) * main_volume
        height = float(np.clip(volume ** (1.0 / 3.0), 0.03, 0.06))
        half_side = 0.5 * math.sqrt(volume / height)
        half_xz = np.array([half_side, half_side])
        if np.any(r_hi - r_lo <= 2 * half_xz):
            raise RuntimeError(
                f"distractor {i} ({2 * half_side:.3f} wide) does not fit into region {region_xz}"
            )
        for _ in range(max_tries):
            centre = rng.uniform(r_lo + half_xz, r_hi - half_xz)
            lo, hi = centre - half_xz, centre + half_xz
            if not _overlaps(lo, hi, boxes, margin):
                break
        else:
            raise RuntimeError(f"no room for distractor {i} of {count} after {max_tries} tries")
        boxes.append((lo, hi))
        pieces.append(
            BoxPiece(
                centre=(float(centre[0]), floor_y + 0.5 * height, float(centre[1])),
                half_extents=(half_side, 0.5 * height, half_side),
            )
        )
    return pieces
