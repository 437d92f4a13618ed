"""Trajectory files (atomic, validated), the dataset index and the seeded split."""

from __future__ import annotations

import os

import numpy as np
import pandas as pd
import pytest

from pasta.data import storage
from pasta.data.storage import (
    DatasetError,
    DatasetIndex,
    read_trajectory,
    split_by_configuration,
    validate_trajectory,
    write_trajectory,
)


def demo(n_steps: int = 4, n_points: int = 20, n_tools: int = 2, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "dough_points": rng.random((n_steps, n_points, 3)).astype(np.float32),
        "tool_states": rng.random((n_steps, n_tools, 8)),
        "tool_points": rng.random((n_steps, 100 * n_tools, 3)).astype(np.float32),
        "actions": rng.uniform(-1, 1, (n_steps - 1, 12)).astype(np.float32),
        "labels": rng.integers(0, 2, (n_steps, n_points)).astype(np.int16),
        "target_points": rng.random((30, 3)).astype(np.float32),
    }


def test_round_trip_is_bit_exact(tmp_path):
    arrays = demo()
    arrays["rewards"] = np.array([np.nan, -np.inf, 1e-300, -0.0], dtype=np.float64)
    arrays["mask"] = np.array([True, False, True])
    metadata = {"task": "LiftSpread", "config_id": 17, "skills": ["lift", "spread"], "emd": 0.1 + 0.2}
    path = write_trajectory(tmp_path / "traj_000017.npz", arrays, metadata)
    assert path == tmp_path / "traj_000017.npz" and path.is_file()
    got, got_meta = read_trajectory(path)
    assert got_meta == metadata
    assert set(got) == set(arrays)
    for key, value in arrays.items():
        assert got[key].dtype == value.dtype and got[key].shape == value.shape, key
        assert got[key].tobytes() == value.tobytes(), key
    assert os.listdir(tmp_path) == ["traj_000017.npz"]  # no temp file left behind
    assert validate_trajectory(got, source=path) == 4


@pytest.mark.parametrize("fail_at", ["savez", "replace"])
def test_interrupted_write_leaves_nothing_readable(tmp_path, monkeypatch, fail_at):
    target = tmp_path / "traj.npz"

    def half_write(handle, **arrays):
        handle.write(b"PK\x03\x04 half a zip file")
        raise KeyboardInterrupt("killed half way")

    def failing_replace(src, dst):
        assert os.path.exists(src)  # the complete temp file exists when the rename fails
        raise OSError("rename failed")

    if fail_at == "savez":
        monkeypatch.setattr(storage.np, "savez_compressed", half_write)
        expected = KeyboardInterrupt
    else:
        monkeypatch.setattr(storage.os, "replace", failing_replace)
        expected = OSError
    with pytest.raises(expected):
        write_trajectory(target, demo(), {"i": 1})
    assert os.listdir(tmp_path) == []
    with pytest.raises(DatasetError, match="not found"):
        read_trajectory(target)


def test_interrupted_overwrite_keeps_previous_version(tmp_path, monkeypatch):
    target = tmp_path / "traj.npz"
    write_trajectory(target, {"x": np.arange(3)}, {"version": 1})

    def boom(handle, **arrays):
        handle.write(b"garbage")
        raise RuntimeError("disk full")

    monkeypatch.setattr(storage.np, "savez_compressed", boom)
    with pytest.raises(RuntimeError):
        write_trajectory(target, {"x": np.arange(5)}, {"version": 2})
    arrays, metadata = read_trajectory(target)
    assert metadata == {"version": 1} and arrays["x"].tolist() == [0, 1, 2]
    assert os.listdir(tmp_path) == ["traj.npz"]


def test_truncated_corrupt_and_foreign_files_raise_naming_the_file(tmp_path):
    good = write_trajectory(tmp_path / "good.npz", demo(n_points=500), {"a": 1})
    data = good.read_bytes()

    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(data[: len(data) // 2])
    corrupt = tmp_path / "corrupt.npz"
    middle = len(data) // 2
    corrupt.write_bytes(
        data[:middle] + bytes(b ^ 0xFF for b in data[middle : middle + 64]) + data[middle + 64 :]
    )
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not an npz file at all")
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    no_meta = tmp_path / "no_meta.npz"
    np.savez_compressed(no_meta, x=np.arange(3))

    for path in (truncated, corrupt, garbage, empty, no_meta, tmp_path / "absent.npz"):
        with pytest.raises(DatasetError) as info:
            read_trajectory(path)
        assert str(path) in str(info.value), path
        assert info.value.path == path
    assert isinstance(DatasetError("x"), ValueError)


def test_write_refuses_reserved_names_and_object_arrays(tmp_path):
    with pytest.raises(ValueError, match="invalid array name"):
        write_trajectory(tmp_path / "a.npz", {storage.METADATA_KEY: np.zeros(1)}, {})
    with pytest.raises(ValueError, match="object dtype"):
        write_trajectory(tmp_path / "b.npz", {"x": np.array([{}, 1], dtype=object)}, {})
    with pytest.raises(TypeError):
        write_trajectory(tmp_path / "c.npz", {"x": np.zeros(1)}, {"bad": object()})
    assert os.listdir(tmp_path) == []


def _validation_error(arrays, **kwargs) -> DatasetError:
    with pytest.raises(DatasetError) as info:
        validate_trajectory(arrays, **kwargs)
    return info.value


def test_validation_names_key_step_and_value():
    arrays = demo()
    arrays["actions"][2, 5] = 1.5
    err = _validation_error(arrays, source="traj_3.npz")
    assert (err.key, err.step, err.value) == ("actions", 2, 1.5)
    assert "traj_3.npz" in str(err) and "actions" in str(err) and "step 2" in str(err) and "1.5" in str(err)

    arrays = demo()
    arrays["dough_points"][3, 7, 1] = np.nan
    arrays["dough_points"][1, 0, 0] = np.inf  # an earlier step is reported first
    err = _validation_error(arrays)
    assert (err.key, err.step) == ("dough_points", 1) and err.value == np.inf and "inf" in str(err)

    arrays = demo()
    arrays["labels"][2, 4] = -1
    err = _validation_error(arrays)
    assert (err.key, err.step, err.value) == ("labels", 2, -1)

    arrays = demo()
    arrays["target_points"][11, 2] = np.nan
    err = _validation_error(arrays)
    assert err.key == "target_points" and "point 11" in str(err) and "nan" in str(err)


@pytest.mark.parametrize(
    ("key", "bad"),
    [
        ("dough_points", np.zeros((4, 20, 2))),
        ("tool_states", np.zeros((4, 2, 7))),
        ("tool_points", np.zeros((3, 200, 3))),
        ("actions", np.zeros((4, 12))),
        ("labels", np.zeros((4, 19), dtype=np.int64)),
        ("labels", np.zeros((4, 20), dtype=np.float32)),
        ("target_points", np.zeros((30, 2))),
    ],
)
def test_validation_rejects_bad_shapes(key, bad):
    arrays = demo()
    arrays[key] = bad
    err = _validation_error(arrays)
    assert err.key == key and key in str(err)


def test_validation_missing_key():
    arrays = demo()
    del arrays["tool_points"]
    err = _validation_error(arrays)
    assert err.key == "tool_points" and "tool_points" in str(err)
    assert validate_trajectory(demo(n_steps=1)) == 1  # a single state and no actions is a valid demo


def test_index_round_trip_missing_and_replace(tmp_path):
    index = DatasetIndex()
    assert len(index) == 0 and index.missing([1, 2]) == [1, 2]
    index.add(
        trajectory_id=5,
        configuration_id=2,
        skill="cut",
        file_name="t5.npz",
        split="train",
        final_shape_distance=0.1 + 0.2,
        normalised_performance=0.875,
    )
    index.add(trajectory_id=1, configuration_id=0, skill="", file_name="t1.npz", split="test")
    index.add(
        trajectory_id=3,
        configuration_id=2,
        skill="spread",
        file_name="t3.npz",
        split="train",
        final_shape_distance=1 / 3,
        normalised_performance=-0.25,
    )
    index.add(
        trajectory_id=3,
        configuration_id=2,
        skill="spread",
        file_name="t3b.npz",
        split="train",
        final_shape_distance=2 / 3,
        normalised_performance=0.5,
    )  # replaces the row with id 3
    assert len(index) == 3 and 3 in index and 4 not in index
    assert index.frame["trajectory_id"].tolist() == [1, 3, 5]
    assert index.frame.loc[1, "file_name"] == "t3b.npz"
    assert index.missing([0, 1, 2, 3, 4, 5, 6]) == [0, 2, 4, 6]

    path = index.save(tmp_path / "sub" / "index.csv")
    assert os.listdir(path.parent) == ["index.csv"]
    loaded = DatasetIndex.load(path)
    pd.testing.assert_frame_equal(loaded.frame, index.frame)
    assert loaded.frame.loc[2, "final_shape_distance"] == 0.1 + 0.2  # floats round-trip exactly
    assert np.isnan(loaded.frame.loc[0, "normalised_performance"]) and loaded.frame.loc[0, "skill"] == ""
    assert loaded.missing(range(7)) == [0, 2, 4, 6]


def test_index_load_errors(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        DatasetIndex.load(tmp_path / "none.csv")
    assert len(DatasetIndex.load(tmp_path / "none.csv", missing_ok=True)) == 0
    bad = tmp_path / "bad.csv"
    bad.write_text("trajectory_id,skill\n1,cut\n")
    with pytest.raises(DatasetError) as info:
        DatasetIndex.load(bad)
    assert str(bad) in str(info.value)


def test_split_is_seeded_disjoint_and_official():
    ids = list(range(100, 140))
    train, test = split_by_configuration(ids, test_fraction=0.1, seed=42)
    assert (len(train), len(test)) == (36, 4)
    assert set(train).isdisjoint(test) and set(train) | set(test) == set(ids)
    assert (train, test) == split_by_configuration(ids, 0.1, 42)
    assert split_by_configuration(ids, 0.1, 43) != (train, test)
    assert split_by_configuration(ids + ids[:5], 0.1, 42) == (train, test)  # duplicates count once

    # the official split: np.random.seed(42); permutation(n); first int(0.9 n) are train
    state = np.random.get_state()
    try:
        np.random.seed(42)
        order = np.random.permutation(2000)
    finally:
        np.random.set_state(state)
    train, test = split_by_configuration(range(2000), 0.1, 42)
    assert (len(train), len(test)) == (1800, 200)
    assert train == sorted(order[:1800].tolist()) and test == sorted(order[1800:].tolist())
    assert [len(part) for part in split_by_configuration(range(15), 0.1, 0)] == [13, 2]  # int(13.5) train
    with pytest.raises(ValueError):
        split_by_configuration(ids, 1.0, 0)
