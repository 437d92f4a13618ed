"""Trajectory storage: one compressed ``.npz`` per trajectory, a CSV index per dataset, and the split.

* ``write_trajectory`` / ``read_trajectory``: arrays plus a JSON metadata dict in one ``.npz``, written
  atomically (temp file in the same directory, fsync, ``os.replace``), so an interrupted writer never
  leaves a half file at the destination. Reading needs no pickle.
* ``validate_trajectory``: shape, range and finiteness checks for a demonstration; errors name the
  array, the first bad step and the bad value.
* ``DatasetIndex``: one row per trajectory (pandas), saved as CSV atomically; ``missing`` tells a
  resumed flow what is left to generate.
* ``split_by_configuration``: a seeded permutation into train and test ids, like the official 90/10
  split (env_spec §3.4).

Array conventions of a demonstration (T states, T - 1 actions; env_spec §3):

==================  ===============  ====================================================
key                 shape            meaning
==================  ===============  ====================================================
``dough_points``    ``(T, P, 3)``    dough observation (the first P particles), world frame
``tool_states``     ``(T, K, 8)``    per tool: position 3, quaternion wxyz 4, gap or 0
``tool_points``     ``(T, Q, 3)``    tool surface points (100 per actuated tool)
``actions``         ``(T - 1, A)``   normalised actions in [-1, 1], inactive tools zero
``labels``          ``(T, P)``       DBSCAN entity label of each dough point (>= 0)
``target_points``   ``(P2, 3)``      the goal cloud
==================  ===============  ====================================================

Other arrays (rewards, EMDs, masks) may be stored alongside and are not checked.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
import pandas as pd

__all__ = [
    "METADATA_KEY",
    "REQUIRED_ARRAYS",
    "DatasetError",
    "DatasetIndex",
    "read_trajectory",
    "split_by_configuration",
    "validate_trajectory",
    "write_trajectory",
]

METADATA_KEY = "__metadata__"
REQUIRED_ARRAYS = ("dough_points", "tool_states", "tool_points", "actions", "labels", "target_points")


class DatasetError(ValueError):
    """A dataset file is missing, unreadable or invalid. The message names the file when known.

    Attributes ``path``, ``key``, ``step`` and ``value`` hold what is known about the fault.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | os.PathLike | None = None,
        key: str | None = None,
        step: int | None = None,
        value: Any = None,
    ) -> None:
        super().__init__(message)
        self.path = None if path is None else Path(path)
        self.key = key
        self.step = step
        self.value = value


# --------------------------------------------------------------------------------------------------
# atomic writes


def atomic_write_bytes(path: str | os.PathLike, write: Callable[[IO[bytes]], None]) -> Path:
    """Write a file atomically: ``write(handle)`` into a temp file beside ``path``, fsync, rename.

    On any exception the temp file is removed and the destination is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            os.fchmod(handle.fileno(), 0o644)  # mkstemp makes 0o600 files
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise
    _fsync_directory(path.parent)
    return path


def _fsync_directory(directory: Path) -> None:
    """Make the rename durable; a no-op where directories cannot be opened (Windows)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# --------------------------------------------------------------------------------------------------
# one trajectory


def write_trajectory(
    path: str | os.PathLike, arrays: Mapping[str, np.ndarray], metadata: Mapping[str, Any]
) -> Path:
    """Write one trajectory as a compressed ``.npz`` atomically; returns the path.

    Args:
        path: destination, written exactly as given (no suffix is added).
        arrays: name -> array; names must not be ``METADATA_KEY``; object arrays are refused (they
            would need pickle to read).
        metadata: a JSON-serialisable dict, stored as a 0-d string array under ``METADATA_KEY``.
    """
    payload: dict[str, np.ndarray] = {}
    for key, value in arrays.items():
        if not isinstance(key, str) or not key or key == METADATA_KEY or "/" in key:
            raise ValueError(f"invalid array name {key!r}")
        arr = np.asarray(value)
        if arr.dtype.hasobject:
            raise ValueError(f"array {key!r} has object dtype; store numbers or strings")
        payload[key] = arr
    if not isinstance(metadata, Mapping):
        raise TypeError(f"metadata must be a mapping, got {type(metadata).__name__}")
    payload[METADATA_KEY] = np.array(json.dumps(dict(metadata), sort_keys=True))
    return atomic_write_bytes(path, lambda handle: np.savez_compressed(handle, **payload))


def read_trajectory(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a trajectory written by ``write_trajectory``: ``(arrays, metadata)``.

    Raises:
        DatasetError: naming the file, when it is missing, truncated, corrupt, or has no metadata.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: trajectory file not found", path=path)
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise ValueError("not an .npz archive")
        with loaded:
            arrays = {key: loaded[key] for key in loaded.files}
    except MemoryError:
        raise
    except Exception as exc:  # zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, ...
        raise DatasetError(
            f"{path}: unreadable or corrupt trajectory file ({type(exc).__name__}: {exc})", path=path
        ) from exc
    raw = arrays.pop(METADATA_KEY, None)
    if raw is None:
        raise DatasetError(f"{path}: no {METADATA_KEY} entry; not written by write_trajectory", path=path)
    try:
        metadata = json.loads(str(raw[()]))
    except (ValueError, IndexError) as exc:
        raise DatasetError(f"{path}: metadata is not valid JSON ({exc})", path=path) from exc
    if not isinstance(metadata, dict):
        raise DatasetError(f"{path}: metadata is a {type(metadata).__name__}, not a dict", path=path)
    return arrays, metadata


def _first_bad(key: str, arr: np.ndarray, bad: np.ndarray, reason: str, prefix: str, step_axis: bool = True):
    index = tuple(int(i) for i in np.argwhere(bad)[0])
    value = arr[index].item()
    where = f"step {index[0]}" if step_axis else f"point {index[0]}"
    return DatasetError(
        f"{prefix}{key}: {where} (index {index}) has value {value!r}: {reason}",
        key=key,
        step=index[0] if step_axis else None,
        value=value,
    )


def validate_trajectory(arrays: Mapping[str, np.ndarray], *, source: str | os.PathLike | None = None) -> int:
    """Check a demonstration's required arrays (see the module table); returns ``T``.

    Args:
        arrays: name -> array, as from ``read_trajectory``.
        source: a file name to put in error messages.

    Raises:
        DatasetError: naming the key, and for bad values the first bad step, its index and the value.
    """
    prefix = f"{source}: " if source is not None else ""

    def fail(message: str, key: str) -> DatasetError:
        return DatasetError(prefix + message, path=source, key=key)

    missing = [key for key in REQUIRED_ARRAYS if key not in arrays]
    if missing:
        raise fail(f"missing required arrays {missing}", missing[0])
    arr = {key: np.asarray(arrays[key]) for key in REQUIRED_ARRAYS}

    dough = arr["dough_points"]
    if dough.ndim != 3 or dough.shape[2] != 3 or dough.shape[0] < 1 or dough.shape[1] < 1:
        message = f"dough_points: expected shape (T, P, 3) with T, P >= 1, got {dough.shape}"
        raise fail(message, "dough_points")
    n_steps, n_points = dough.shape[:2]
    expected = {
        "tool_states": ("(T, K, 8)", lambda s: len(s) == 3 and s[0] == n_steps and s[2] == 8),
        "tool_points": ("(T, Q, 3)", lambda s: len(s) == 3 and s[0] == n_steps and s[2] == 3),
        "actions": ("(T - 1, A)", lambda s: len(s) == 2 and s[0] == n_steps - 1),
        "labels": ("(T, P)", lambda s: s == (n_steps, n_points)),
        "target_points": ("(P2, 3)", lambda s: len(s) == 2 and s[0] >= 1 and s[1] == 3),
    }
    for key, (pattern, ok) in expected.items():
        if not ok(arr[key].shape):
            message = f"{key}: expected shape {pattern} with T={n_steps}, P={n_points}, got {arr[key].shape}"
            raise fail(message, key)

    for key in ("dough_points", "tool_states", "tool_points", "actions", "target_points"):
        a = arr[key]
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise fail(f"{key}: expected a numeric array, got dtype {a.dtype}", key)
        bad = ~np.isfinite(a)
        if bad.any():
            raise _first_bad(key, a, bad, "not finite", prefix, step_axis=key != "target_points")
    actions = arr["actions"]
    out_of_range = np.abs(actions) > 1.0
    if out_of_range.any():
        raise _first_bad("actions", actions, out_of_range, "outside [-1, 1]", prefix)
    labels = arr["labels"]
    if not np.issubdtype(labels.dtype, np.integer):
        raise fail(f"labels: expected an integer array, got dtype {labels.dtype}", "labels")
    negative = labels < 0
    if negative.any():
        raise _first_bad("labels", labels, negative, "negative entity label", prefix)
    return int(n_steps)


# --------------------------------------------------------------------------------------------------
# dataset index

_INT_COLUMNS = ("trajectory_id", "configuration_id")
_STR_COLUMNS = ("skill", "file_name", "split")
_FLOAT_COLUMNS = ("final_shape_distance", "normalised_performance")
# pandas >= 3 parses floats exactly by default and deprecates the argument; pandas 2 needs it.
_ROUND_TRIP = {"float_precision": "round_trip"} if int(pd.__version__.split(".")[0]) < 3 else {}
INDEX_COLUMNS = (
    "trajectory_id",
    "configuration_id",
    "skill",
    "file_name",
    "split",
    "final_shape_distance",
    "normalised_performance",
)


def _coerce_index(frame: pd.DataFrame) -> pd.DataFrame:
    absent = [c for c in INDEX_COLUMNS if c not in frame.columns]
    if absent:
        raise ValueError(f"index is missing columns {absent}")
    out = frame.loc[:, list(INDEX_COLUMNS)].copy()
    for column in _INT_COLUMNS:
        out[column] = out[column].astype("int64")
    for column in _STR_COLUMNS:
        out[column] = out[column].astype(str)
    for column in _FLOAT_COLUMNS:
        out[column] = out[column].astype("float64")
    if out["trajectory_id"].duplicated().any():
        dupes = sorted(set(out.loc[out["trajectory_id"].duplicated(), "trajectory_id"].tolist()))
        raise ValueError(f"duplicate trajectory ids {dupes}")
    return out.sort_values("trajectory_id", kind="stable").reset_index(drop=True)


class DatasetIndex:
    """One row per stored trajectory, columns ``INDEX_COLUMNS``, sorted by ``trajectory_id``.

    ``final_shape_distance`` is the EMD to the goal at the end of the trajectory and
    ``normalised_performance`` its score (env_spec §4); either may be NaN when unknown.
    """

    columns = INDEX_COLUMNS

    def __init__(self, frame: pd.DataFrame | None = None) -> None:
        if frame is None:
            frame = pd.DataFrame({c: pd.Series(dtype="int64") for c in _INT_COLUMNS})
            for column in _STR_COLUMNS:
                frame[column] = pd.Series(dtype=str)
            for column in _FLOAT_COLUMNS:
                frame[column] = pd.Series(dtype="float64")
        self._frame = _coerce_index(frame)

    @property
    def frame(self) -> pd.DataFrame:
        """A copy of the table."""
        return self._frame.copy()

    def __len__(self) -> int:
        return len(self._frame)

    def __contains__(self, trajectory_id: object) -> bool:
        return bool((self._frame["trajectory_id"] == trajectory_id).any())

    def add(
        self,
        *,
        trajectory_id: int,
        configuration_id: int,
        skill: str,
        file_name: str,
        split: str,
        final_shape_distance: float = float("nan"),
        normalised_performance: float = float("nan"),
    ) -> None:
        """Add a row, replacing any row with the same ``trajectory_id`` (a regenerated trajectory)."""
        row = pd.DataFrame(
            [
                {
                    "trajectory_id": int(trajectory_id),
                    "configuration_id": int(configuration_id),
                    "skill": str(skill),
                    "file_name": str(file_name),
                    "split": str(split),
                    "final_shape_distance": float(final_shape_distance),
                    "normalised_performance": float(normalised_performance),
                }
            ]
        )
        kept = self._frame[self._frame["trajectory_id"] != int(trajectory_id)]
        self._frame = _coerce_index(pd.concat([kept, row], ignore_index=True) if len(kept) else row)

    def missing(self, ids: Iterable[int]) -> list[int]:
        """The trajectory ids of ``ids`` that have no row, in the given order."""
        present = set(self._frame["trajectory_id"].tolist())
        return [i for i in ids if int(i) not in present]

    def save(self, path: str | os.PathLike) -> Path:
        """Write the table as CSV atomically; returns the path."""
        text = self._frame.to_csv(index=False, na_rep="nan")
        return atomic_write_bytes(path, lambda handle: handle.write(text.encode("utf-8")))

    @classmethod
    def load(cls, path: str | os.PathLike, *, missing_ok: bool = False) -> DatasetIndex:
        """Read a CSV written by ``save``; an absent file gives an empty index when ``missing_ok``.

        Raises:
            DatasetError: naming the file, when it is absent (and not ``missing_ok``) or malformed.
        """
        path = Path(path)
        if not path.is_file():
            if missing_ok:
                return cls()
            raise DatasetError(f"{path}: dataset index not found", path=path)
        try:
            frame = pd.read_csv(
                path,
                dtype={column: str for column in _STR_COLUMNS},
                keep_default_na=False,
                na_values={column: ["", "nan", "NaN"] for column in _FLOAT_COLUMNS},
                **_ROUND_TRIP,
            )
            return cls(frame)
        except MemoryError:
            raise
        except Exception as exc:
            message = f"{path}: malformed dataset index ({type(exc).__name__}: {exc})"
            raise DatasetError(message, path=path) from exc


def split_by_configuration(
    config_ids: Iterable[int], test_fraction: float = 0.1, seed: int = 42
) -> tuple[list[int], list[int]]:
    """Split configuration ids into train and test ids by a seeded random permutation.

    Like the official ``generate_train_eval_split`` (env_spec §3.4): ``RandomState(seed).permutation``
    of the (deduplicated, first-seen order) ids; the first ``int(n * (1 - test_fraction))`` are train.
    With ``config_ids = range(n)``, ``seed=42`` and ``test_fraction=0.1`` it reproduces the official
    index sets. Every trajectory of one configuration therefore lands on the same side.

    Returns:
        ``(train_ids, test_ids)``, each sorted; disjoint, and together every id once.
    """
    if not 0.0 <= test_fraction < 1.0:
        raise ValueError(f"test_fraction must be in [0, 1), got {test_fraction}")
    unique = list(dict.fromkeys(int(i) for i in config_ids))
    n_train = int(round(len(unique) * (1.0 - test_fraction), 9))  # round off 6.9999999 -> 7
    order = np.random.RandomState(seed).permutation(len(unique))
    train = sorted(unique[i] for i in order[:n_train])
    test = sorted(unique[i] for i in order[n_train:])
    return train, test
