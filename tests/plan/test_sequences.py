from __future__ import annotations

import pytest

from pasta.plan import NoSkillSequenceError, SkillSpec, enumerate_sequences, resolve_sequence, set_sizes
from pasta.plan.from_bundle import _task_skills


def _skills(task: str) -> tuple[SkillSpec, ...]:
    return _task_skills(task)


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


def test_gather_move_plans_from_one_two_or_three_pieces():
    skills = _skills("GatherMove")
    assert [(s.name, s.n_in, s.n_out) for s in skills] == [("gather", 1, 1), ("gather", 2, 1), ("gather", 3, 1),
                                                           ("move", 1, 1)]
    g1, g2, g3, move = ("gather", 1), ("gather", 2), ("gather", 3), ("move", 1)
    expected = {
        1: {(g1, g1), (g1, move), (move, g1), (move, move)},
        2: {(g2, g1), (g2, move), (g1, g2), (move, g2)},  # one piece may be acted on before the gather
        3: {(g3, g1), (g3, move), (g1, g3), (move, g3), (g2, g2)},
    }
    for k_obs, want in expected.items():
        sequences = enumerate_sequences(skills, 2, k_obs, 1)
        assert {tuple((s.name, s.n_in) for s in seq) for seq in sequences} == want
    with pytest.raises(NoSkillSequenceError, match=r"takes 6 entities to 1.*gather \(3->1\)"):
        enumerate_sequences(skills, 2, 6, 1)  # two gathers of 3 leave 2


def test_resolving_a_skill_with_several_arities_takes_every_piece_it_can():
    skills = _skills("GatherMove")
    assert [s.n_in for s in resolve_sequence(skills, ("gather", "move"), 2)] == [2, 1]
    assert [s.n_in for s in resolve_sequence(skills, ("gather", "gather"), 3)] == [3, 1]
    assert [s.n_in for s in resolve_sequence(skills, ("move", "gather"), 5)] == [1, 3]
    with pytest.raises(ValueError, match="needs the observed entity count"):
        resolve_sequence(skills, ("gather",))
    cut, merge = SkillSpec("cut", 1, 2), SkillSpec("merge", 2, 1)
    with pytest.raises(ValueError, match=r"step 1 \(merge\) takes at least 2 entities but the set then holds 1"):
        resolve_sequence((cut, merge, SkillSpec("merge", 3, 1)), ("merge",), 1)
