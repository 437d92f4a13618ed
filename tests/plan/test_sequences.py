from __future__ import annotations

import pytest

from pasta.config import load
from pasta.plan import NoSkillSequenceError, SkillSpec, enumerate_sequences, resolve_sequence, set_sizes


def _skills(task: str) -> tuple[SkillSpec, ...]:
    return tuple(SkillSpec(s.name, s.entities_in, s.entities_out) for s in load(task, "smoke").skills)


def test_cut_rearrange_has_three_sequences_with_one_cut():
    sequences = enumerate_sequences(_skills("CutRearrange"), 3, 1, 2)
    names = [tuple(s.name for s in seq) for seq in sequences]
    assert names == [("cut", "rearrange", "rearrange"), ("rearrange", "cut", "rearrange"),
                     ("rearrange", "rearrange", "cut")]


def test_crs_has_twelve_sequences():
    sequences = enumerate_sequences(_skills("CRS"), 3, 1, 2)
    assert len(sequences) == 12
    assert all(sum(s.name == "cut" for s in seq) == 1 for seq in sequences)


def test_sequences_that_run_out_of_entities_are_left_out():
    skills = (SkillSpec("merge", 2, 1), SkillSpec("cut", 1, 2))
    # From 1 entity, net 0 over 2 steps: (cut, merge) works, (merge, cut) needs 2 entities at step 1.
    names = [tuple(s.name for s in seq) for seq in enumerate_sequences(skills, 2, 1, 1)]
    assert names == [("cut", "merge")]


def test_no_matching_sequence_names_the_counts():
    with pytest.raises(NoSkillSequenceError, match=r"takes 1 entities to 5 \(net change \+4\).*cut \(1->2\)"):
        enumerate_sequences(_skills("CutRearrange"), 3, 1, 5)


def test_set_sizes_and_bad_sequences():
    cut, merge = SkillSpec("cut", 1, 2), SkillSpec("merge", 2, 1)
    assert set_sizes((cut, cut, merge), 1) == (1, 2, 3, 2)
    with pytest.raises(ValueError, match="takes 2 entities but U\\^0 holds 1"):
        set_sizes((merge,), 1)
    with pytest.raises(KeyError, match="'spread'"):
        resolve_sequence((cut, merge), ("cut", "spread"))
    with pytest.raises(ValueError, match="n_in, n_out >= 1, got 0 -> 1"):
        SkillSpec("bad", 0, 1)
    with pytest.raises(ValueError, match="horizon must be >= 1, got 0"):
        enumerate_sequences((cut,), 0, 1, 2)
